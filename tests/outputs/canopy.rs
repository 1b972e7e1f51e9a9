//! Terrain, canopy and tree products (`products::canopy`, `products::trees`, `export dtm|chm|trees`,
//! `compare-trees`) and the simulator's truth for them:
//!
//! - trees on a synthetic canopy: one top per crown (two crowns touching, a low and a tall one), each height
//!   within 5 cm (the top cell's centre lies beside the apex), crown areas within 20% of the true discs, the crowns
//!   split at the valley between them, and the tops on a flat roof set apart by the crown's NDVI from an
//!   orthomosaic whose red and NIR bands say "not vegetation";
//! - `compare-trees`' matching: one found top per known tree, nearest first, within the crown's radius; false trees
//!   on open ground told apart by the class raster;
//! - the chain as a user runs it on the simulated campus: `export dtm` on the truth DSM, `export chm`, `export
//!   trees` with the true orthomosaic, `compare-trees` against `truth/trees.geojson`: all 30 trees found, heights
//!   within 0.5 m, no false tree on open ground, roofs set apart; GDAL reads the DTM and CHM as COGs in the scene's
//!   CRS; the truth's CHM is its DSM minus its DTM and its tree table has every tree of the scene;
//! - a DSM's field-only cells (quality 3) are not ground candidates: an invented surface 0.3 m above the ground
//!   raises the DTM only when `--use-field-heights` asks for it;
//! - bad input is named and leaves nothing: an all-nodata DSM, a DSM whose quality raster has no measured cell,
//!   rasters on different grids, a wrong extension, a bad SMRF parameter.

use std::path::Path;

use msnerf::output::image::band;
use msnerf::output::raster::{write_geotiff, GeoReference, GeoTiffOptions};
use msnerf::output::SpectralImage;
use msnerf::products::canopy::{make_chm, make_dtm, make_trees};
use msnerf::products::terrain::{HeightGrid, SmrfParams};
use msnerf::products::trees::{describe_trees, find_tops, grow_crowns, CrownParams, TopParams, TreeBands};

use super::common::{msnerf, TempDir};
use super::geo_support;

const BIN: &str = env!("CARGO_BIN_EXE_msnerf");

/// Crowns (x, y, radius, height) as half-ellipsoid domes on a CHM of `gsd` cells over 60 x 40 m, and a 12 x 8 m flat
/// roof 6 m high with 2 cm noise at (45..57, 5..13).
/// A crown: x, y, radius, height.
type Crown = (f64, f64, f64, f64);

fn canopy(gsd: f64) -> (HeightGrid, [Crown; 4], Vec<bool>) {
    let crowns = [(10.0, 30.0, 3.0, 8.0), (15.5, 30.0, 3.0, 12.0), (30.0, 12.0, 4.0, 18.0), (40.0, 32.0, 2.0, 4.0)];
    let (w, h) = ((60.0 / gsd) as usize, (40.0 / gsd) as usize);
    let mut g = HeightGrid::empty(w, h, gsd);
    let mut roof = vec![false; w * h];
    let mut rng = super::common::rng(2);
    use rand::Rng;
    for r in 0..h {
        for c in 0..w {
            let (x, y) = ((c as f64 + 0.5) * gsd, 40.0 - (r as f64 + 0.5) * gsd);
            let mut z = 0.0f64;
            for &(cx, cy, cr, ch) in &crowns {
                let d2 = ((x - cx).powi(2) + (y - cy).powi(2)) / (cr * cr);
                if d2 < 1.0 {
                    z = z.max(ch - 0.4 * ch * (1.0 - (1.0 - d2).sqrt()) - 0.3 * ch * d2);
                }
            }
            if (45.0..57.0).contains(&x) && (5.0..13.0).contains(&y) {
                z = 6.0 + rng.random_range(-0.02..0.02);
                roof[r * w + c] = true;
            }
            g.z[r * w + c] = z as f32;
        }
    }
    (g, crowns, roof)
}

#[test]
fn trees_on_a_synthetic_canopy() {
    let gsd = 0.2;
    let (chm, crowns, roof) = canopy(gsd);
    let tops = find_tops(&chm, &TopParams::default());
    let labels = grow_crowns(&chm, &tops, &CrownParams::default());
    // Red 668 nm and NIR 842 nm: crowns 0.04 / 0.45 (NDVI 0.84), the roof 0.25 / 0.30 (0.09).
    let n = chm.cells();
    let mut data = vec![0.0f32; 2 * n];
    for i in 0..n {
        let (red, nir) = if roof[i] { (0.25, 0.30) } else { (0.04, 0.45) };
        data[i] = red;
        data[n + i] = nir;
    }
    let bands = TreeBands { bands: vec![band("red", Some(668.0), None), band("nir", Some(842.0), None)], data };
    let trees = describe_trees(&chm, None, [0.0, 40.0], (&tops, &labels), Some(&bands), None);
    let (veg, other): (Vec<_>, Vec<_>) = trees.iter().partition(|t| t.is_vegetation());
    assert_eq!(veg.len(), crowns.len(), "one top per crown: {veg:?}");
    assert!(!other.is_empty() && other.iter().all(|t| (45.0..57.0).contains(&t.x)), "the roof's tops: {other:?}");
    assert!(other.iter().all(|t| t.ndvi.unwrap() < 0.2), "{other:?}");
    for &(cx, cy, cr, ch) in &crowns {
        let t = veg.iter().find(|t| (t.x - cx).hypot(t.y - cy) < 0.5).unwrap_or_else(|| panic!("no top at {cx},{cy}"));
        assert!((t.height - ch).abs() < 0.05, "tree at {cx},{cy}: height {} vs {ch}", t.height);
        assert!((t.ndvi.unwrap() - 0.8367).abs() < 1e-3, "NDVI {:?}", t.ndvi);
        let disc = std::f64::consts::PI * cr * cr;
        // The two touching crowns share the valley; each keeps most of its disc.
        assert!(
            t.crown_area > 0.6 * disc && t.crown_area < 1.2 * disc,
            "crown at {cx},{cy}: {} vs {disc}",
            t.crown_area
        );
    }
    // Below the minimum height nothing is a top; the low tree (4 m) is found, its crown's rim (< 2 m) is not crown.
    let rim = labels.iter().zip(&chm.z).filter(|(l, z)| **l != 0 && (**z as f64) < 2.0).count();
    assert_eq!(rim, 0, "crown cells below 2 m");
}

fn write_height(path: &Path, g: &HeightGrid, origin: [f64; 2], epsg: Option<u16>) {
    let img = SpectralImage::single(g.width, g.height, band("height", None, None), g.z.clone()).unwrap();
    let georef = GeoReference { origin, pixel_size: [g.gsd, g.gsd], epsg };
    let opts = GeoTiffOptions { nodata: Some(f64::NAN), georef: Some(georef), ..Default::default() };
    write_geotiff(path, &img, &opts).unwrap();
}

fn write_quality(path: &Path, q: &[f32], g: &HeightGrid, origin: [f64; 2]) {
    let img = SpectralImage::single(g.width, g.height, band("quality", None, None), q.to_vec()).unwrap();
    let georef = GeoReference { origin, pixel_size: [g.gsd, g.gsd], epsg: Some(32632) };
    write_geotiff(path, &img, &GeoTiffOptions { nodata: Some(0.0), georef: Some(georef), ..Default::default() })
        .unwrap();
}

fn read_band(path: &Path) -> Vec<f32> {
    let r = msnerf::output::raster::geotiff_read::read_geotiff(path).unwrap();
    r.data.iter().map(|&v| if r.is_nodata(v) { f32::NAN } else { v }).collect()
}

#[test]
fn canopy_products_from_the_simulated_campus() {
    let tmp = TempDir::new("canopy-campus");
    let data = tmp.path().join("sim");
    let scene = msnerf::sim::SceneDesc::load("campus").unwrap();
    let opts = msnerf::sim::SimOptions { width: Some(128), points: 50_000, ..Default::default() };
    msnerf::sim::simulate(&scene, &opts, &data).unwrap();
    let t = data.join("truth");
    // The truth: CHM = DSM - DTM; every tree of the scene in the table.
    let (dsm, dtm, chm) = (read_band(&t.join("dsm.tif")), read_band(&t.join("dtm.tif")), read_band(&t.join("chm.tif")));
    for i in 0..dsm.len() {
        assert!(dsm[i].is_nan() && chm[i].is_nan() || (dsm[i] - dtm[i] - chm[i]).abs() < 1e-4, "cell {i}");
    }
    let known = msnerf::products::trees::compare::read_tree_table(&t.join("trees.geojson")).unwrap();
    assert_eq!(known.len(), scene.trees.len(), "every tree stands inside the truth grid");
    let p = |name: &str| tmp.path().join(name).display().to_string();
    let s = |path: &Path| path.display().to_string();
    let out = msnerf(BIN, &["export", "dtm", "--dsm", &s(&t.join("dsm.tif")), "--out", &p("dtm.tif")]);
    assert!(out.contains("ground") && out.contains("dtm_quality.tif"), "{out}");
    msnerf(BIN, &["export", "chm", "--dsm", &s(&t.join("dsm.tif")), "--dtm", &p("dtm.tif"), "--out", &p("chm.tif")]);
    let out = msnerf(
        BIN,
        &[
            "export",
            "trees",
            "--chm",
            &p("chm.tif"),
            "--dtm",
            &p("dtm.tif"),
            "--ortho",
            &s(&t.join("ortho.tif")),
            "--out",
            &p("trees.geojson"),
        ],
    );
    assert!(out.contains("trees: 30 found") && !out.contains(" 0 tops set apart"), "{out}");
    for f in ["dtm.tif", "chm.tif"] {
        geo_support::validate_cog(&tmp.path().join(f));
        let info = geo_support::gdalinfo(&tmp.path().join(f));
        assert!(info.contains("ID[\"EPSG\",32650]") && info.contains("NoData Value=-9999"), "{f}: {info}");
    }
    let dtm_err: Vec<f32> = read_band(&tmp.path().join("dtm.tif"))
        .iter()
        .zip(&dtm)
        .filter(|(a, _)| a.is_finite())
        .map(|(a, b)| (a - b).abs())
        .collect();
    assert!(
        dtm_err.iter().all(|e| *e < 0.05),
        "the DTM of a flat campus is flat: worst {}",
        dtm_err.iter().fold(0.0f32, |a, &b| a.max(b))
    );
    let cmp = msnerf(
        BIN,
        &[
            "compare-trees",
            "--pred",
            &p("trees.geojson"),
            "--truth",
            &s(&t.join("trees.geojson")),
            "--classes",
            &s(&t.join("classes.tif")),
            "--json",
        ],
    );
    let v: serde_json::Value = serde_json::from_str(cmp.lines().last().unwrap()).unwrap();
    assert_eq!(v["known"], 30, "{v}");
    assert_eq!(v["matched"], 30, "{v}");
    assert_eq!(v["false_on_ground"], 0, "{v}");
    assert!(v["within_tolerance"].as_f64().unwrap() >= 0.9, "{v}");
    let csv = std::fs::read_to_string(tmp.path().join("trees.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    assert!(
        header.starts_with("id,x,y,height_m,ground_z,top_z,crown_area_m2") && header.contains("mean_nir"),
        "{header}"
    );
    assert_eq!(csv.lines().count(), 31);
    let mut rd = csv::Reader::from_reader(csv.as_bytes());
    let n = rd.headers().unwrap().len();
    for row in rd.records() {
        assert_eq!(row.unwrap().len(), n, "every row has a value or an empty field per column");
    }
}

#[test]
fn field_only_cells_are_not_ground() {
    let tmp = TempDir::new("canopy-field");
    // Flat ground at 50 m; a 20 x 20 m patch where the DSM holds the field's invented height 0.3 m above it.
    let gsd = 0.5;
    let (w, h) = (120, 100);
    let mut g = HeightGrid::empty(w, h, gsd);
    let mut q = vec![1.0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let patch = (40..80).contains(&c) && (30..70).contains(&r);
            g.z[r * w + c] = if patch { 50.3 } else { 50.0 };
            if patch {
                q[r * w + c] = 3.0;
            }
        }
    }
    let origin = [500_000.0, 5_000_000.0];
    let dsm = tmp.path().join("dsm.tif");
    write_height(&dsm, &g, origin, Some(32632));
    write_quality(&tmp.path().join("dsm_quality.tif"), &q, &g, origin);
    let p = SmrfParams::default();
    let out = tmp.path().join("dtm.tif");
    let s = make_dtm(&dsm, &out, &p, false).unwrap();
    assert_eq!(s.candidates, w * h - 40 * 40, "field-only cells are not candidates");
    let centre = read_band(&out)[50 * w + 60];
    assert!((centre - 50.0).abs() < 0.01, "under the invented patch the DTM is the ground around it: {centre}");
    let s2 = make_dtm(&dsm, &out, &p, true).unwrap();
    assert_eq!(s2.candidates, w * h);
    let centre = read_band(&out)[50 * w + 60];
    assert!((centre - 50.3).abs() < 0.01, "with --use-field-heights the patch is ground: {centre}");
}

#[test]
fn bad_canopy_input_is_named_and_leaves_nothing() {
    let tmp = TempDir::new("canopy-bad");
    let origin = [500_000.0, 5_000_000.0];
    let g = HeightGrid::empty(20, 10, 1.0);
    let empty = tmp.path().join("empty.tif");
    write_height(&empty, &g, origin, Some(32632));
    let out = tmp.path().join("dtm.tif");
    let e = make_dtm(&empty, &out, &SmrfParams::default(), false).unwrap_err().to_string();
    assert!(e.contains("empty.tif") && e.contains("nodata"), "{e}");
    assert!(!out.exists());
    // Water only: every cell field-only.
    let mut flat = HeightGrid::empty(20, 10, 1.0);
    flat.z.iter_mut().for_each(|z| *z = 10.0);
    let water = tmp.path().join("water.tif");
    write_height(&water, &flat, origin, Some(32632));
    write_quality(&tmp.path().join("water_quality.tif"), &[3.0; 200], &flat, origin);
    let e = make_dtm(&water, &out, &SmrfParams::default(), false).unwrap_err().to_string();
    assert!(e.contains("water.tif") && e.contains("--use-field-heights"), "{e}");
    assert!(!out.exists());
    let e = make_dtm(&water, &out, &SmrfParams { cell: 0.0, ..SmrfParams::default() }, true).unwrap_err().to_string();
    assert!(e.contains("cell"), "{e}");
    assert!(!out.exists());
    // Another grid.
    let shifted = tmp.path().join("shifted.tif");
    write_height(&shifted, &flat, [origin[0] + 3.0, origin[1]], Some(32632));
    let chm = tmp.path().join("chm.tif");
    let e = make_chm(&water, &shifted, &chm).unwrap_err().to_string();
    assert!(e.contains("shifted.tif") && e.contains("grid"), "{e}");
    assert!(!chm.exists());
    let trees = tmp.path().join("trees.geojson");
    let e = make_trees(&water, None, Some(&shifted), &trees, &TopParams::default(), &CrownParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("shifted.tif"), "{e}");
    assert!(!trees.exists());
    // The CLI: a wrong extension and a bad parameter, named.
    let run = |args: &[&str]| {
        let o = std::process::Command::new(BIN).args(args).output().unwrap();
        assert!(!o.status.success(), "{args:?} succeeded");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let w = water.display().to_string();
    let e = run(&["export", "dtm", "--dsm", &w, "--out", &tmp.path().join("dtm.png").display().to_string()]);
    assert!(e.contains("--out") && e.contains(".tif"), "{e}");
    let e = run(&["export", "dtm", "--dsm", &w, "--out", &out.display().to_string(), "--smrf-slope=-1"]);
    assert!(e.contains("--smrf-slope"), "{e}");
    let e = run(&["export", "dtm", "--dsm", &w, "--out", &w]);
    assert!(e.contains("--dsm"), "{e}");
    assert!(!out.exists());
}

#[test]
fn tree_matching_is_one_to_one_within_the_crown() {
    use msnerf::products::trees::compare::{compare_trees, TreePoint};
    let t = |id, x, y, height, crown_diameter| TreePoint { id, x, y, height, crown_diameter };
    let known = [t(1, 0.0, 0.0, 10.0, 6.0), t(2, 10.0, 0.0, 8.0, 4.0), t(3, 30.0, 0.0, 5.0, 1.0)];
    // Two tops in tree 1's crown (the nearer matches), one in tree 2's 0.6 m low, one 1.5 m from tree 3 (outside its
    // 1 m minimum radius), one far on open ground.
    let found = [
        t(7, 0.4, 0.0, 10.1, 0.0),
        t(8, 2.0, 1.0, 9.0, 0.0),
        t(9, 10.5, 0.5, 7.4, 0.0),
        t(10, 31.5, 0.0, 5.0, 0.0),
        t(11, 50.0, 0.0, 3.0, 0.0),
    ];
    let c = compare_trees(&found, &known, None, 0.5);
    let pairs: Vec<(u64, u64)> = c.matches.iter().map(|m| (m.truth, m.found)).collect();
    assert_eq!(pairs, vec![(1, 7), (2, 9)]);
    assert_eq!(c.missed, vec![3]);
    assert_eq!(c.false_trees, vec![8, 10, 11]);
    assert!((c.within() - 1.0 / 3.0).abs() < 1e-12, "only tree 1 within 0.5 m");
    assert_eq!(c.false_on_ground, None);
    // A class raster: ground (1) everywhere but a crown class (3) around x = 0..5.
    let grid = msnerf::output::raster::geotiff_read::RasterGrid {
        origin: [-10.0, 10.0],
        pixel_size: [1.0, 1.0],
        width: 80,
        height: 20,
        bands: 1,
        nodata: None,
        epsg: None,
        descriptions: vec![],
    };
    let data = (0..80 * 20).map(|i| if (i % 80) < 15 { 3.0 } else { 1.0 }).collect();
    let classes = msnerf::output::raster::geotiff_read::GeoRaster { grid, data };
    let c = compare_trees(&found, &known, Some(&classes), 0.5);
    assert_eq!(c.false_on_ground, Some(2), "tops 10 and 11 stand on open ground, 8 in a crown");
}
