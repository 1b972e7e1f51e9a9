//! The simulator's survey ground truth (issue 21, deliverable 4): `truth/dsm.tif`, `truth/ortho.tif` and
//! `truth/materials.tif` on one north-up grid. On `ci-small` the open ground is at the scene's `world_offset` height (20 m) and the box's roof at
//! 20 + 7 m, as the scene file says; the ortho holds the materials' band reflectance (`simulation.json`); GDAL
//! reads both with geotransform, nodata and the scene's CRS.

use crate::common;
use crate::geo_support;
use common::TempDir;
use msnerf::data::reader::read_image_file;
use serde_json::Value;

fn read(path: &std::path::Path) -> (usize, usize, Vec<Vec<f32>>) {
    let r = read_image_file(path, 1 << 30).unwrap().raster;
    (r.width as usize, r.height as usize, (0..r.bands).map(|b| r.band_f32(b)).collect())
}

#[test]
fn dsm_and_true_ortho_truth_match_the_scene() {
    let tmp = TempDir::new("sim-truth");
    let data = tmp.path().join("d");
    let mut scene = msnerf::sim::SceneDesc::load("ci-small").unwrap();
    scene.crs = Some("EPSG:32633".into());
    // A material name with a space and an `=`: materials.tif's band name must still parse as code=name pairs.
    let water = scene.materials.remove("water").unwrap();
    scene.materials.insert("pond water=still".into(), water);
    scene.water[0].material = "pond water=still".into();
    msnerf::sim::simulate(&scene, &msnerf::sim::SimOptions::default(), &data).unwrap();
    let (w, h, dsm) = read(&data.join("truth/dsm.tif"));
    let (w2, h2, ortho) = read(&data.join("truth/ortho.tif"));
    assert_eq!((w, h), (w2, h2), "one grid");
    assert_eq!(ortho.len(), 6);
    let info = geo_support::gdalinfo(&data.join("truth/dsm.tif"));
    assert!(info.contains("ID[\"EPSG\",32633]") && info.contains("NoData Value=nan"), "{info}");
    let origin = info.lines().find_map(|l| l.strip_prefix("Origin = (")).unwrap();
    let o: Vec<f64> = origin.trim_end_matches(')').split(',').map(|v| v.parse().unwrap()).collect();
    let px = info.lines().find_map(|l| l.strip_prefix("Pixel Size = (")).unwrap();
    let gsd: f64 = px.split(',').next().unwrap().parse().unwrap();
    assert!(gsd > 0.1 && gsd < 2.0, "{gsd}");
    let info_o = geo_support::gdalinfo(&data.join("truth/ortho.tif"));
    assert!(info_o.contains(origin) && info_o.contains("Band 6") && info_o.contains("nir"), "{info_o}");
    // Value at a world (x, y): the cell containing it.
    let at = |band: &[f32], x: f64, y: f64| {
        let col = ((x - o[0]) / gsd).floor() as usize;
        let row = ((o[1] - y) / gsd).floor() as usize;
        band[row * w + col]
    };
    let (ox, oy) = (500000.0, 4000000.0);
    let meta: Value = serde_json::from_slice(&std::fs::read(data.join("simulation.json")).unwrap()).unwrap();
    let refl = |m: &str, b: usize| meta["materials"][m]["band_reflectance"][b].as_f64().unwrap();
    // Open lawn (local (-15, 2): away from the building, the trees, the path and the pond).
    assert_eq!(at(&dsm[0], ox - 15.0, oy + 2.0), 20.0);
    // The box (centre (6, 4), 8 x 6 x 7 m, yawed 20 degrees): its roof in the middle, the lawn 1 m beyond its long
    // side's end along the box axis.
    assert!((at(&dsm[0], ox + 6.0, oy + 4.0) - 27.0).abs() < 1e-4, "{}", at(&dsm[0], ox + 6.0, oy + 4.0));
    let (c, s) = (20f64.to_radians().cos(), 20f64.to_radians().sin());
    assert_eq!(at(&dsm[0], ox + 6.0 + 5.5 * c, oy + 4.0 + 5.5 * s), 20.0);
    for (b, band) in ortho.iter().enumerate() {
        let lawn = at(band, ox - 15.0, oy + 2.0) as f64;
        assert!((lawn - refl("grass", b)).abs() < 1e-6, "band {b}: lawn {lawn} against grass {}", refl("grass", b));
        let roof = at(band, ox + 6.0, oy + 4.0) as f64;
        assert!((roof - refl("roof", b)).abs() < 1e-6, "band {b}: roof {roof} against {}", refl("roof", b));
    }
    // Cells whose vertical ray leaves the ground disc would be NaN; none here, the grid is what the cameras saw.
    assert!(dsm[0].iter().all(|v| v.is_finite() && *v >= 20.0));

    // materials.tif: on the same grid, each cell's material code, named in the band's description as GDAL reads it
    // (`classes 1=grass 2=leaves ...`, the form `compare-raster --classes` takes).
    let (w3, h3, mat) = read(&data.join("truth/materials.tif"));
    assert_eq!((w3, h3), (w, h), "one grid");
    let info_m = geo_support::gdalinfo(&data.join("truth/materials.tif"));
    assert!(info_m.contains(origin), "{info_m}");
    let desc = info_m.lines().find_map(|l| l.trim().strip_prefix("Description = classes ")).expect("band description");
    let code = |name: &str| -> f32 {
        let kv =
            desc.split_whitespace().find(|kv| kv.ends_with(&format!("={name}"))).unwrap_or_else(|| panic!("{desc}"));
        kv.split('=').next().unwrap().parse().unwrap()
    };
    for (x, y, name) in
        [(-15.0, 2.0, "grass"), (6.0, 4.0, "roof"), (-9.0, 8.0, "pond_water_still"), (0.0, -8.0, "asphalt")]
    {
        assert_eq!(at(&mat[0], ox + x, oy + y), code(name), "local ({x}, {y}) is {name} ({desc})");
    }
    assert!(mat[0].iter().all(|v| v.is_finite() && *v >= 1.0 && v.fract() == 0.0));
}
