//! The survey exports' building blocks without a trained model:
//! - the DSM hillshade against `gdaldem hillshade` itself (GDAL is the peer; gdal-bin, tools/setup-debian.sh);
//! - `SurveyGrid::covering`: edges snapped outward to whole cells, absurd and empty grids refused with numbers;
//! - `compare_rasters` against statistics computed here in f64 from the definitions, on grids that are offset from
//!   each other, with nodata on both sides and per-class interior cells.

use crate::common;
use common::TempDir;
use msnerf::nerf::survey::SurveyGrid;
use msnerf::output::compare_raster::{compare_rasters, QualityLayer, RasterCompareOptions};
use msnerf::output::image::band;
use msnerf::output::raster::geotiff_read::read_geotiff;
use msnerf::output::raster::hillshade::{hillshade, Sun};
use msnerf::output::raster::{write_geotiff, GeoReference, GeoTiffOptions};
use msnerf::output::SpectralImage;

fn write(path: &std::path::Path, w: usize, h: usize, origin: [f64; 2], gsd: f64, name: &str, data: Vec<f32>) {
    let img = SpectralImage::from_planar(w, h, vec![band(name, None, None)], data).expect("image");
    let opts = GeoTiffOptions {
        nodata: Some(-9999.0),
        georef: Some(GeoReference { origin, pixel_size: [gsd, gsd], epsg: Some(32650) }),
        ..Default::default()
    };
    write_geotiff(path, &img, &opts).expect("write");
}

#[test]
fn hillshade_matches_gdaldem() {
    let tmp = TempDir::new("hillshade");
    // A dome, a ramp and a box on a slope: every aspect, flat, steep and shadowed cells; one nodata cell.
    let (w, h, gsd) = (64usize, 48usize, 0.5);
    let mut z = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let (fx, fy) = (x as f64 * gsd, y as f64 * gsd);
            let mut v = 0.05 * fx + 0.02 * fy;
            let r2 = (fx - 10.0).powi(2) + (fy - 12.0).powi(2);
            if r2 < 49.0 {
                v += (49.0 - r2).sqrt();
            }
            if (40..52).contains(&x) && (10..30).contains(&y) {
                v += 4.0;
            }
            z[y * w + x] = v as f32;
        }
    }
    z[30 * w + 20] = -9999.0;
    let dem = tmp.path().join("dem.tif");
    write(&dem, w, h, [500_000.0, 4_000_000.0], gsd, "height", z.clone());
    let shade = tmp.path().join("shade.tif");
    let out = std::process::Command::new("gdaldem")
        .args(["hillshade", "-az", "315", "-alt", "45", "-z", "1"])
        .arg(&dem)
        .arg(&shade)
        .output()
        .expect("gdaldem (apt-get install gdal-bin; tools/setup-debian.sh does)");
    assert!(out.status.success(), "gdaldem: {}", String::from_utf8_lossy(&out.stderr));
    let peer = read_geotiff(&shade).expect("gdaldem output");
    let zn: Vec<f32> = z.iter().map(|&v| if v == -9999.0 { f32::NAN } else { v }).collect();
    let ours = hillshade(&zn, w, h, gsd, Sun::default());
    let mut worst = 0i32;
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (ours[y * w + x] as i32, peer.value(0, x, y) as i32);
            worst = worst.max((a - b).abs());
            assert!((a - b).abs() <= 1, "cell ({x}, {y}): ours {a}, gdaldem {b}");
        }
    }
    // Both leave the border and the nodata cell's neighbours at 0, and the scene has lit and shadowed slopes.
    assert_eq!(ours[30 * w + 21], 0);
    assert!(ours.iter().any(|&v| v > 200) && ours.iter().any(|&v| (1..60).contains(&v)));
    eprintln!("hillshade: largest difference from gdaldem {worst} grey level(s)");
}

#[test]
fn survey_grids_snap_to_whole_cells_and_refuse_absurd_sizes() {
    let g = SurveyGrid::covering([100.3, 200.2, 110.1, 205.0], 0.5, 1_000_000).expect("grid");
    assert_eq!(g.origin, [100.0, 205.0]);
    assert_eq!((g.width, g.height), (21, 10));
    assert_eq!(g.bounds(), [100.0, 200.0, 110.5, 205.0]);
    assert_eq!(g.centre(0, 0), [100.25, 204.75]);
    // Bounds already on the cell edges stay there.
    let g = SurveyGrid::covering([100.0, 200.0, 110.0, 205.0], 0.5, 1_000_000).expect("grid");
    assert_eq!((g.width, g.height), (20, 10));
    let err = SurveyGrid::covering([0.0, 0.0, 10_000.0, 10_000.0], 0.01, 200_000_000).unwrap_err().to_string();
    assert!(err.contains("1000000 x 1000000") && err.contains("200000000"), "{err}");
    for (b, gsd) in [([5.0, 0.0, 5.0, 1.0], 1.0), ([0.0, 3.0, 1.0, 2.0], 1.0), ([0.0, 0.0, 1.0, 1.0], 0.0)] {
        let err = SurveyGrid::covering(b, gsd, 1000).unwrap_err().to_string();
        assert!(err.contains("empty") || err.contains("gsd"), "{b:?} {gsd}: {err}");
    }
    assert!(SurveyGrid::covering([0.0, 0.0, 1.0, f64::NAN], 0.1, 1000).is_err());
}

#[test]
fn raster_comparison_matches_the_definitions() {
    let tmp = TempDir::new("compare_raster");
    // Reference: 0.5 m cells; prediction: 1 m cells offset by half a reference cell, so each prediction centre
    // falls inside one reference cell.
    let (rw, rh) = (40usize, 30usize);
    let rorigin = [1000.0, 2000.0];
    let reference: Vec<f32> = (0..rw * rh).map(|i| if i % 97 == 5 { -9999.0 } else { (i % rw) as f32 * 0.1 }).collect();
    let classes: Vec<f32> = (0..rw * rh).map(|i| if (i % rw) < 20 { 1.0 } else { 2.0 }).collect();
    let (pw, ph) = (19usize, 14usize);
    let porigin = [1000.25, 1999.75];
    let pred: Vec<f32> = (0..pw * ph)
        .map(|i| {
            let (c, r) = (i % pw, i / pw);
            if (c + r) % 11 == 0 {
                -9999.0
            } else {
                ((c * 2 + 1) as f32) * 0.1 + 0.05 * ((c + 2 * r) % 3) as f32
            }
        })
        .collect();
    let (rp, pp, cp) = (tmp.path().join("ref.tif"), tmp.path().join("pred.tif"), tmp.path().join("classes.tif"));
    write(&rp, rw, rh, rorigin, 0.5, "height", reference.clone());
    write(&pp, pw, ph, porigin, 1.0, "height", pred.clone());
    write(&cp, rw, rh, rorigin, 0.5, "classes 1=left 2=right 3=absent", classes.clone());
    let (rr, pr, cr) = (read_geotiff(&rp).unwrap(), read_geotiff(&pp).unwrap(), read_geotiff(&cp).unwrap());
    let opts = RasterCompareOptions { within: vec![0.04, 0.06], peak: Some(4.0) };
    let rep = compare_rasters(&pr, &rr, Some(&cr), None, &opts).expect("compare");

    // Independently: prediction cell (c, r) centre = (1000.25 + c + 0.5, 1999.75 - r - 0.5) lies in reference cell
    // (2c + 1, 2r + 1).
    let (mut d, mut left) = (Vec::new(), Vec::new());
    let (mut ref_cells, mut pred_cells) = (0, 0);
    for r in 0..ph {
        for c in 0..pw {
            let p = pred[r * pw + c];
            pred_cells += usize::from(p != -9999.0);
            let (rc, rrow) = (2 * c + 1, 2 * r + 1);
            let q = reference[rrow * rw + rc];
            if q == -9999.0 {
                continue;
            }
            ref_cells += 1;
            if p == -9999.0 {
                continue;
            }
            let e = p as f64 - q as f64;
            d.push(e);
            // Interior of class 1: all 3x3 neighbours in columns < 20, away from the raster border.
            if rc >= 1 && rc + 1 < 20 && rrow >= 1 && rrow + 1 < rh {
                left.push(e);
            }
        }
    }
    let n = d.len() as f64;
    let bias = d.iter().sum::<f64>() / n;
    let rmse = (d.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    let mut abs: Vec<f64> = d.iter().map(|e| e.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let med_abs =
        if abs.len() % 2 == 1 { abs[abs.len() / 2] } else { 0.5 * (abs[abs.len() / 2 - 1] + abs[abs.len() / 2]) };
    let within = abs.iter().filter(|&&a| a <= 0.06).count() as f64 / n;
    assert_eq!((rep.pred_cells, rep.ref_cells, rep.compared), (pred_cells, ref_cells, d.len()));
    let b = &rep.bands[0];
    assert!((b.bias - bias).abs() < 1e-6 && (b.rmse - rmse).abs() < 1e-6, "{b:?} vs bias {bias} rmse {rmse}");
    assert!((b.median_abs - med_abs).abs() < 1e-6, "{} vs {med_abs}", b.median_abs);
    assert!((b.within[1].1 - within).abs() < 1e-12);
    assert!((b.psnr_db.unwrap() - 10.0 * (16.0 / (rmse * rmse)).log10()).abs() < 1e-4);
    assert_eq!(rep.classes.len(), 3);
    assert_eq!((rep.classes[0].code, rep.classes[0].name.as_str()), (1, "left"));
    assert_eq!(rep.classes[0].bands[0].cells, left.len());
    // A named class with no cells stays in the JSON with 0 cells; the table only names it.
    assert_eq!((rep.classes[2].name.as_str(), rep.classes[2].bands[0].cells), ("absent", 0));
    let table = rep.table();
    assert!(table.contains("[left interior] ") && table.contains("[right interior] "), "{table}");
    assert!(
        !table.contains("[absent interior]") && table.contains("classes without interior cells: absent"),
        "{table}"
    );
    // Per code of the prediction's quality raster, over every cell (no interior rule): code 1 on even columns,
    // 3 on odd ones, against the errors collected here by column.
    let qp = tmp.path().join("pred_quality.tif");
    write(&qp, pw, ph, porigin, 1.0, "quality", (0..pw * ph).map(|i| if i % 2 == 0 { 1.0 } else { 3.0 }).collect());
    let qr = read_geotiff(&qp).unwrap();
    let names = vec![(1, "measured".to_string()), (2, "interpolated".to_string()), (3, "field only".to_string())];
    let layer = QualityLayer { raster: &qr, names };
    let rq = compare_rasters(&pr, &rr, None, Some(&layer), &opts).expect("compare with quality");
    let (mut even, mut odd) = (Vec::new(), Vec::new());
    for r in 0..ph {
        for c in 0..pw {
            let (p, q) = (pred[r * pw + c], reference[(2 * r + 1) * rw + 2 * c + 1]);
            if p != -9999.0 && q != -9999.0 {
                let e = p as f64 - q as f64;
                if (r * pw + c) % 2 == 0 {
                    even.push(e)
                } else {
                    odd.push(e)
                }
            }
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert_eq!((rq.quality[0].bands[0].cells, rq.quality[1].bands[0].cells), (even.len(), 0));
    assert_eq!(rq.quality[2].bands[0].cells, odd.len());
    assert!(
        (rq.quality[0].bands[0].bias - mean(&even)).abs() < 1e-6
            && (rq.quality[2].bands[0].bias - mean(&odd)).abs() < 1e-6
    );
    let table = rq.table();
    assert!(
        table.contains("[measured] ") && table.contains("[field only] ") && !table.contains("[interpolated]"),
        "{table}"
    );
    // A quality raster on another grid is not the prediction's.
    let err = compare_rasters(&pr, &rr, None, Some(&QualityLayer { raster: &rr, names: vec![] }), &opts).unwrap_err();
    assert!(err.to_string().contains("not its quality raster"), "{err}");
    // A different CRS or band count is refused by name.
    let other = tmp.path().join("other.tif");
    let img =
        SpectralImage::from_planar(2, 2, vec![band("a", None, None), band("b", None, None)], vec![0.0; 8]).unwrap();
    write_geotiff(
        &other,
        &img,
        &GeoTiffOptions {
            georef: Some(GeoReference { origin: rorigin, pixel_size: [1.0, 1.0], epsg: Some(32650) }),
            ..Default::default()
        },
    )
    .unwrap();
    let err = compare_rasters(&pr, &read_geotiff(&other).unwrap(), None, None, &opts).unwrap_err().to_string();
    assert!(err.contains("2 bands"), "{err}");
    // Rasters that do not overlap: refused, saying so, instead of NaN statistics and exit 0.
    let far = tmp.path().join("far.tif");
    write(&far, rw, rh, [rorigin[0] + 1.0e5, rorigin[1]], 0.5, "height", reference.clone());
    let err = compare_rasters(&pr, &read_geotiff(&far).unwrap(), None, None, &opts).unwrap_err().to_string();
    assert!(err.contains("no cell to compare") && err.contains("0 reference cells"), "{err}");
}
