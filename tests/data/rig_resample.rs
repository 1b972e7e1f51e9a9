//! The importer's bicubic resampling (`rig::plane::Plane::sample_cubic`, Keys 1981 with a = -0.5) against an
//! independent implementation of Keys' kernel written here from the paper (f64, separable, the kernel evaluated by
//! distance), on a random image; exact on a quadratic surface (Keys' kernel reproduces polynomials up to degree 2);
//! bilinear at the border and next to a NaN, never a NaN from a finite neighbourhood.

use msnerf::rig::plane::Plane;

/// Keys' kernel W(d), a = -0.5 (eq. 15 of Keys 1981).
fn keys(d: f64) -> f64 {
    let a = -0.5;
    let d = d.abs();
    if d <= 1.0 {
        (a + 2.0) * d.powi(3) - (a + 3.0) * d.powi(2) + 1.0
    } else if d < 2.0 {
        a * d.powi(3) - 5.0 * a * d.powi(2) + 8.0 * a * d - 4.0 * a
    } else {
        0.0
    }
}

fn reference(p: &Plane, x: f64, y: f64) -> f64 {
    let (x0, y0) = (x.floor() as i64, y.floor() as i64);
    let mut v = 0.0;
    for j in y0 - 1..=y0 + 2 {
        for i in x0 - 1..=x0 + 2 {
            v += keys(x - i as f64) * keys(y - j as f64) * p.at(i as usize, j as usize) as f64;
        }
    }
    v
}

fn lcg(s: &mut u64) -> f64 {
    *s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (*s >> 11) as f64 / (1u64 << 53) as f64
}

#[test]
fn bicubic_matches_keys_kernel_and_is_exact_on_quadratics() {
    let (w, h) = (24usize, 17usize);
    let mut s = 7u64;
    let random = Plane::new(w, h, (0..w * h).map(|_| lcg(&mut s) as f32).collect());
    let quad = |x: f64, y: f64| 0.2 + 0.03 * x - 0.02 * y + 0.004 * x * x + 0.003 * x * y - 0.002 * y * y;
    let quadratic = Plane::new(w, h, (0..w * h).map(|i| quad((i % w) as f64, (i / w) as f64) as f32).collect());
    let mut worst_ref: f64 = 0.0;
    let mut worst_quad: f64 = 0.0;
    for _ in 0..2000 {
        let (x, y) = (1.0 + lcg(&mut s) * (w as f64 - 3.0001), 1.0 + lcg(&mut s) * (h as f64 - 3.0001));
        let got = random.sample_cubic(x, y).unwrap() as f64;
        worst_ref = worst_ref.max((got - reference(&random, x, y)).abs());
        let q = quadratic.sample_cubic(x, y).unwrap() as f64;
        worst_quad = worst_quad.max((q - quad(x, y)).abs());
    }
    assert!(worst_ref < 1e-6, "against Keys' kernel: {worst_ref}");
    assert!(worst_quad < 1e-5, "on a quadratic: {worst_quad}");
    // At a sample it is the sample.
    assert_eq!(random.sample_cubic(5.0, 6.0), Some(random.at(5, 6)));
}

#[test]
fn bicubic_falls_back_to_bilinear_at_the_border_and_next_to_nan() {
    let (w, h) = (8usize, 8usize);
    let mut data: Vec<f32> = (0..w * h).map(|i| (i % 7) as f32 * 0.1).collect();
    let p = Plane::new(w, h, data.clone());
    for (x, y) in [(0.3, 4.2), (6.5, 3.3), (3.2, 0.0), (4.4, 6.9)] {
        assert_eq!(p.sample_cubic(x, y), p.sample(x, y), "({x}, {y})");
    }
    assert_eq!(p.sample_cubic(-0.1, 3.0), None);
    // A NaN two pixels away is inside the cubic's support but not the bilinear's: the value stays finite.
    data[4 * w + 2] = f32::NAN;
    let q = Plane::new(w, h, data);
    let v = q.sample_cubic(3.5, 4.5).expect("bilinear away from the NaN");
    assert!(v.is_finite());
    assert_eq!(Some(v), q.sample(3.5, 4.5));
}
