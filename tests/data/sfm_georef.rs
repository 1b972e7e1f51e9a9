//! The similarity fit behind `msnerf sfm`'s geo-registration (`msnerf::maths::similarity`, Horn's quaternion
//! method) and its robust wrapper (`msnerf::sfm::georef`): a known similarity (rotation from a unit quaternion,
//! scale, UTM-sized translation) is recovered from the points it maps; degenerate input is refused; a GPS glitch is
//! left out and named.

use msnerf::maths::similarity::fit_similarity;
use msnerf::sfm::georef::robust_fit;

/// Rotation (row-major) of a unit quaternion (w, x, y, z), from the textbook formula.
fn rot(q: [f64; 4]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

fn map(r: &[[f64; 3]; 3], s: f64, t: [f64; 3], p: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| s * (r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2]) + t[i])
}

fn points(n: usize) -> Vec<[f64; 3]> {
    (0..n)
        .map(|i| {
            let a = i as f64 * 0.7;
            [3.0 * a.cos() + 0.1 * i as f64, 2.0 * a.sin(), 0.3 * (1.3 * a).sin()]
        })
        .collect()
}

#[test]
fn a_known_similarity_is_recovered() {
    for (q, s, t) in [
        ([0.9, 0.1, -0.3, 0.2], 5.97, [680100.0, 3553000.0, 30.0]),
        ([0.0, 1.0, 0.0, 0.0], 0.25, [-3.0, 2.0, 1.0]), // 180 degrees about x
        ([1.0, 0.0, 0.0, 0.0], 1.0, [0.0, 0.0, 0.0]),
    ] {
        let r = rot(q);
        let src = points(12);
        let dst: Vec<[f64; 3]> = src.iter().map(|p| map(&r, s, t, *p)).collect();
        let f = fit_similarity(&src, &dst).expect("fit");
        assert!((f.scale - s).abs() < 1e-9 * s, "scale {} against {s}", f.scale);
        for i in 0..3 {
            for j in 0..3 {
                assert!((f.rotation[i][j] - r[i][j]).abs() < 1e-9, "rotation {:?} against {r:?}", f.rotation);
            }
            assert!((f.translation[i] - t[i]).abs() < 1e-6, "translation {:?} against {t:?}", f.translation);
        }
    }
}

#[test]
fn degenerate_input_is_refused() {
    let line: Vec<[f64; 3]> = (0..6).map(|i| [i as f64, 2.0 * i as f64, 0.0]).collect();
    assert!(fit_similarity(&line, &line).is_none(), "collinear points leave the roll about the line free");
    assert!(fit_similarity(&points(2), &points(2)).is_none());
    assert!(fit_similarity(&[[1.0, 1.0, 1.0]; 5], &points(5)).is_none(), "all at one point");
    let names: Vec<String> = (0..6).map(|i| format!("f{i}")).collect();
    let e = robust_fit(&names, &line, &line, 1.0).unwrap_err();
    assert!(e.contains("on one line"), "{e}");
}

#[test]
fn a_gps_glitch_is_left_out_by_name() {
    let r = rot([0.8, -0.2, 0.1, 0.5]);
    let src = points(20);
    let mut dst: Vec<[f64; 3]> = src.iter().map(|p| map(&r, 12.0, [500000.0, 4000000.0, 80.0], *p)).collect();
    // 2 cm of deterministic noise everywhere; frame 13 is 150 m off.
    for (i, d) in dst.iter_mut().enumerate() {
        d[0] += 0.02 * ((i * 7 % 5) as f64 - 2.0) / 2.0;
        d[2] += 0.02 * ((i * 3 % 4) as f64 - 1.5) / 1.5;
    }
    dst[13][1] += 150.0;
    let names: Vec<String> = (0..20).map(|i| format!("img_{i:03}")).collect();
    let fit = robust_fit(&names, &src, &dst, 0.05).unwrap();
    assert_eq!(fit.rejected, vec!["img_013".to_string()]);
    assert_eq!(fit.pairs, 19);
    assert!(fit.rms_m < 0.03 && (fit.scale - 12.0).abs() < 1e-2, "{fit:?}");
}
