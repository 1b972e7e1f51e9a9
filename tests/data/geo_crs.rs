//! The CRS chain (issue 20): `crs` spellings, GPS and ECEF projected as GDAL/PROJ's `gdaltransform` projects them,
//! a dataset's `crs` checked and carried into LAS (WKT record that GDAL identifies), PLY (comments) and GeoTIFF
//! (EPSG that `gdalinfo` prints), from a simulated scene through training to `msnerf export pointcloud`.

use crate::common;
use crate::geo_support;
use common::{gpu, TempDir};
use geo_support::{gdalinfo, gdalsrsinfo, gdalsrsinfo_epsg, gdaltransform, las_wkt};
use msnerf::geo::{utm_epsg, Crs, CrsKind, Projector};

#[test]
fn crs_spellings_parse_to_one_crs() {
    let want = Crs::from_epsg(32650).unwrap();
    assert_eq!(want.name, "WGS 84 / UTM zone 50N");
    assert_eq!(want.kind, CrsKind::Projected);
    for s in ["EPSG:32650", "epsg:32650", " urn:ogc:def:crs:EPSG::32650 ", "32650", "WGS84 UTM 50N"] {
        assert_eq!(Crs::parse(s).unwrap(), want, "{s}");
    }
    // GDAL's own WKT1 and WKT2 of another zone: kept as given, the EPSG code found at the top level (not the
    // datum's or the ellipsoid's).
    for fmt in ["wkt1", "wkt2"] {
        let wkt = gdalsrsinfo(fmt, "EPSG:32733");
        let c = Crs::parse(&wkt).unwrap();
        assert_eq!(c.epsg, Some(32733), "{fmt}: {wkt}");
        assert_eq!(c.wkt, wkt);
        assert_eq!(c.kind, CrsKind::Projected);
        assert_eq!(c.key(), "EPSG:32733");
    }
    let local = r#"LOCAL_CS["site grid",LOCAL_DATUM["x",0],UNIT["metre",1]]"#;
    assert!(Crs::parse(local).is_err(), "LOCAL_CS is not a WKT root msnerf accepts");
    let geog = Crs::parse(&gdalsrsinfo("wkt1", "EPSG:4326")).unwrap();
    assert_eq!((geog.epsg, geog.kind), (Some(4326), CrsKind::Geographic));
    let ecef = Crs::parse("EPSG:4978").unwrap();
    assert_eq!(ecef.kind, CrsKind::Geocentric);
    assert_eq!(gdalsrsinfo_epsg(&ecef.wkt), "EPSG:4978", "msnerf's own WKT of EPSG:4978 is GDAL's");
    for (bad, says) in [
        ("EPSG:1", "EPSG table"),
        ("EPSG:abc", "not an EPSG code number"),
        ("WGS84 UTM 61N", "not an EPSG code"),
        ("PROJCS[\"x\",GEOGCS[", "brackets"),
        ("", "empty"),
        // WKT whose structure is not a usable CRS: no name, no parts, a vertical CRS alone, a compound without a
        // horizontal part, and a projected CRS carrying a geographic EPSG code (it would pass the geographic
        // refusal and project nothing).
        ("PROJCS[]", "has no name"),
        ("PROJCS[\"a\",UNIT[\"metre\",1]]", "no base geographic CRS"),
        ("VERT_CS[\"x\"]", "vertical CRS alone"),
        ("COMPD_CS[\"x\",VERT_CS[\"h\",VERT_DATUM[\"d\",2005]]]", "no horizontal CRS"),
        ("PROJCS[\"a\",AUTHORITY[\"EPSG\",\"4326\"]]", "no base geographic CRS"),
        ("GEOGCS[\"x\"] trailing", "after the WKT's closing bracket"),
    ] {
        let e = Crs::parse(bad).unwrap_err().to_string();
        assert!(e.contains(says), "{bad:?}: {e}");
    }
    let mut projected_4326 = gdalsrsinfo("wkt1", "EPSG:32650");
    let at = projected_4326.rfind("AUTHORITY[\"EPSG\",\"32650\"]").expect("GDAL's top-level authority");
    projected_4326.replace_range(at.., "AUTHORITY[\"EPSG\",\"4326\"]]");
    let e = Crs::parse(&projected_4326).unwrap_err().to_string();
    assert!(e.contains("describes a projected CRS but its EPSG code 4326 is geographic"), "{e}");
    // ESRI's .prj form of a CRS with heights: two top-level elements, the second vertical.
    let esri = format!(
        "{},VERTCS[\"EGM96_Geoid\",VDATUM[\"EGM96_Geoid\"],UNIT[\"Meter\",1.0]]",
        gdalsrsinfo("wkt_esri", "EPSG:32650")
    );
    let c = Crs::parse(&esri).unwrap_or_else(|e| panic!("{esri}: {e}"));
    assert_eq!(c.kind, CrsKind::Projected);
    // GDAL's compound CRSs (UTM or geographic + EGM96 height): the kind of their horizontal part.
    for (def, kind) in [("EPSG:32650+5773", CrsKind::Projected), ("EPSG:4326+5773", CrsKind::Geographic)] {
        for fmt in ["wkt1", "wkt2"] {
            let wkt = gdalsrsinfo(fmt, def);
            let c = Crs::parse(&wkt).unwrap_or_else(|e| panic!("{def} {fmt}: {e}"));
            assert_eq!(c.kind, kind, "{def} {fmt}: {wkt}");
        }
    }
}

#[test]
fn utm_zones_follow_the_plain_zone_formula() {
    for (lat, lon, epsg) in [
        (32.105, 118.91, 32650), // the campus scene
        (-33.87, 151.21, 32756), // Sydney
        (51.5, -0.12, 32630),    // London
        (0.0, -180.0, 32601),    // zone 1 starts at the antimeridian
        (0.0, 179.999, 32660),   // zone 60 ends there
        (-0.001, 6.0, 32732),    // a zone edge belongs to the zone east of it
        (60.0, 5.0, 32631),      // no Norway exception (ODM and pyproj's utm_crs do not apply it either)
    ] {
        assert_eq!(utm_epsg(lat, lon), Some(epsg), "{lat}, {lon}");
    }
    assert_eq!(utm_epsg(84.5, 0.0), None);
    assert_eq!(utm_epsg(f64::NAN, 0.0), None);
    assert!(Crs::utm_for(-81.0, 0.0).unwrap_err().to_string().contains("outside UTM"));
}

#[test]
fn gps_and_ecef_project_as_gdal_projects_them() {
    // Positions across hemispheres, zone centres and zone edges, with heights.
    let gps = [
        (32.105, 118.91, 30.0, 32650),
        (45.0, 7.0, 300.0, 32632),
        (-33.87, 151.21, 58.0, 32756),
        (64.1, -21.9, 10.0, 32627),
        (-3.2, -60.5, 40.0, 32720),
        (0.01, 12.0 + 2.999, 0.0, 32633),
    ];
    let mut worst: f64 = 0.0;
    for (lat, lon, h, epsg) in gps {
        let crs = Crs::utm_for(lat, lon).unwrap();
        assert_eq!(crs.epsg, Some(epsg));
        let p = Projector::new(&crs).unwrap();
        let got = p.from_geodetic(lat, lon, h).unwrap();
        // gdaltransform reads geographic coordinates as longitude, latitude (GIS order).
        let want = gdaltransform("EPSG:4326", &format!("EPSG:{epsg}"), &[[lon, lat, h]])[0];
        for k in 0..3 {
            worst = worst.max((got[k] - want[k]).abs());
        }
        // ECEF of the same point, through GDAL, projects to the same place.
        let ecef = gdaltransform("EPSG:4979", "EPSG:4978", &[[lon, lat, h]])[0];
        let from_ecef = p.from_ecef(ecef).unwrap();
        let want_e = gdaltransform("EPSG:4978", &format!("EPSG:{epsg}"), &[ecef])[0];
        for k in 0..3 {
            worst = worst.max((from_ecef[k] - want_e[k]).abs());
        }
        // Meridian convergence: the direction of true north on the grid, from two GDAL points 20 m apart.
        let ns = gdaltransform("EPSG:4326", &format!("EPSG:{epsg}"), &[[lon, lat - 9e-5, 0.0], [lon, lat + 9e-5, 0.0]]);
        let want_c = (-(ns[1][0] - ns[0][0])).atan2(ns[1][1] - ns[0][1]).to_degrees();
        let got_c = p.convergence_deg(lat, lon).unwrap();
        assert!((got_c - want_c).abs() < 1e-6, "convergence at {lat}, {lon}: {got_c} against GDAL's {want_c}");
    }
    eprintln!("largest difference from gdaltransform: {worst:.3e} m");
    assert!(worst < 1e-3, "{worst} m");
    // Not a projected CRS, or not one msnerf can project into: named.
    let e = Projector::new(&Crs::from_epsg(4326).unwrap()).unwrap_err().to_string();
    assert!(e.contains("EPSG:4326") && e.contains("projected"), "{e}");
    let wkt_only = Crs::parse(r#"PROJCS["my grid",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],UNIT["metre",1]]"#).unwrap();
    assert_eq!(wkt_only.epsg, None);
    let e = Projector::new(&wkt_only).unwrap_err().to_string();
    assert!(e.contains("my grid") && e.contains("EPSG"), "{e}");
}

/// A small cloud at UTM-sized coordinates with two bands.
fn cloud() -> msnerf::output::pointcloud::PointCloud {
    let bands = vec![
        msnerf::output::image::band("Red", Some(660.0), Some(20.0)),
        msnerf::output::image::band("NIR", Some(840.0), Some(40.0)),
    ];
    let xyz: Vec<[f64; 3]> =
        (0..50).map(|i| [680100.0 + i as f64 * 0.37, 3553000.0 + (i % 7) as f64, 30.0 + 0.01 * i as f64]).collect();
    let refl: Vec<f32> = (0..100).map(|i| 0.01 * (i % 50) as f32).collect();
    msnerf::output::pointcloud::PointCloud::new(xyz, bands, refl).unwrap()
}

#[test]
fn clouds_and_rasters_carry_the_crs_where_gdal_reads_it() {
    let tmp = TempDir::new("geo-outputs");
    let crs = Crs::parse("EPSG:32650").unwrap();
    let las = tmp.path().join("c.las");
    msnerf::products::cloud::write_cloud(&cloud(), &las, Some(&crs)).unwrap();
    let (wkt, bit) = las_wkt(&las);
    let wkt = wkt.expect("a LASF_Projection/2112 WKT record");
    assert!(bit, "the header's global encoding has the WKT bit set");
    assert!(wkt.starts_with("PROJCS["), "OGC WKT1: {wkt}");
    assert_eq!(gdalsrsinfo_epsg(&wkt), "EPSG:32650", "GDAL identifies the LAS's CRS");
    // The same cloud without a CRS has no WKT record.
    let plain = tmp.path().join("plain.las");
    msnerf::products::cloud::write_cloud(&cloud(), &plain, None).unwrap();
    assert_eq!(las_wkt(&plain).0, None);

    let ply = tmp.path().join("c.ply");
    msnerf::products::cloud::write_cloud(&cloud(), &ply, Some(&crs)).unwrap();
    let bytes = std::fs::read(&ply).unwrap();
    let end = bytes.windows(10).position(|w| w == b"end_header").unwrap();
    let header = String::from_utf8_lossy(&bytes[..end]);
    assert!(header.lines().any(|l| l == "comment crs EPSG:32650"), "{header}");
    let wkt_line = header.lines().find_map(|l| l.strip_prefix("comment crs_wkt ")).expect("crs_wkt comment");
    assert_eq!(gdalsrsinfo_epsg(wkt_line), "EPSG:32650");
    // The PLY still reads back (the comments do not disturb the reader).
    assert_eq!(msnerf::output::pointcloud::read_ply(&ply).unwrap().len(), 50);

    use msnerf::output::raster::{write_geotiff, GeoReference, GeoTiffOptions};
    let img = msnerf::output::SpectralImage::from_interleaved(4, 3, cloud().bands.clone(), &[0.25f32; 24]).unwrap();
    let tif = tmp.path().join("r.tif");
    let georef = GeoReference::in_crs([680100.0, 3553010.0], [0.5, 0.5], Some(&crs)).unwrap();
    write_geotiff(&tif, &img, &GeoTiffOptions { georef: Some(georef), ..Default::default() }).unwrap();
    let info = gdalinfo(&tif);
    assert!(info.contains("ID[\"EPSG\",32650]"), "gdalinfo prints the EPSG code:\n{info}");
    assert!(info.contains("Origin = (680100.000000000000000,3553010.000000000000000)"), "{info}");
    let wkt_only = Crs { epsg: None, ..crs.clone() };
    let e = GeoReference::in_crs([0.0, 0.0], [1.0, 1.0], Some(&wkt_only)).unwrap_err().to_string();
    assert!(e.contains("EPSG code"), "{e}");
}

fn write_transforms(dir: &std::path::Path, crs: Option<&str>) {
    let src = tmp_sim();
    for e in std::fs::read_dir(src.path().join("sim")).unwrap() {
        let e = e.unwrap();
        let to = dir.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            std::fs::create_dir_all(&to).unwrap();
            for f in std::fs::read_dir(e.path()).unwrap() {
                let f = f.unwrap();
                std::fs::copy(f.path(), to.join(f.file_name())).unwrap();
            }
        } else {
            std::fs::copy(e.path(), &to).unwrap();
        }
    }
    let p = dir.join("transforms.json");
    let mut t: serde_json::Value = serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap();
    match crs {
        Some(c) => t["crs"] = serde_json::json!(c),
        None => {
            t.as_object_mut().unwrap().remove("crs");
        }
    }
    std::fs::write(&p, serde_json::to_string(&t).unwrap()).unwrap();
}

fn tmp_sim() -> TempDir {
    let t = TempDir::new("geo-sim");
    common::simulate_ci_small(&t.path().join("sim"));
    t
}

#[test]
fn a_dataset_crs_is_checked_and_reported() {
    let tmp = TempDir::new("geo-dataset");
    let ok = tmp.path().join("ok");
    std::fs::create_dir_all(&ok).unwrap();
    write_transforms(&ok, Some("EPSG:32650"));
    let ds = msnerf::data::load_dataset(&ok, &Default::default()).unwrap();
    assert_eq!(ds.crs.as_ref().and_then(|c| c.epsg), Some(32650));
    let rep = msnerf::data::check::check_dataset(&ok, 1 << 30);
    assert!(rep.is_ok(), "{:?}", rep.errors);
    assert!(rep.to_string().contains("crs EPSG:32650 (WGS 84 / UTM zone 50N)"), "{rep}");
    for (bad, says) in [
        ("EPSG:4326", "geographic CRS; poses need a projected CRS"),
        ("EPSG:4978", "geocentric"),
        ("EPSG:99999", "EPSG table"),
        ("somewhere", "not an EPSG code"),
    ] {
        let d = tmp.path().join(bad.replace(':', "_"));
        std::fs::create_dir_all(&d).unwrap();
        write_transforms(&d, Some(bad));
        let e = msnerf::data::load_dataset(&d, &Default::default()).unwrap_err().to_string();
        assert!(e.contains("transforms.json") && e.contains("crs") && e.contains(says), "{bad}: {e}");
    }
}

#[test]
fn a_simulated_scene_with_a_crs_exports_a_georeferenced_las() {
    let tmp = TempDir::new("geo-e2e");
    let (data, run) = (tmp.path().join("data"), tmp.path().join("run"));
    let mut scene = msnerf::sim::SceneDesc::load("ci-small").unwrap();
    scene.crs = Some("EPSG:32650".into());
    msnerf::sim::simulate(&scene, &msnerf::sim::SimOptions::default(), &data).unwrap();
    let t: serde_json::Value = serde_json::from_slice(&std::fs::read(data.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(t["crs"], "EPSG:32650");
    let gt = String::from_utf8_lossy(&std::fs::read(data.join("ground_truth.ply")).unwrap()[..4096]).into_owned();
    assert!(gt.contains("comment crs EPSG:32650"), "the ground-truth cloud carries the crs too");
    {
        let g = gpu();
        let mut model = msnerf::nerf::config::ModelConfig::resolve("tiny").unwrap();
        model.trainer.max_steps = 30;
        model.trainer.steps_per_eval = 1000;
        model.trainer.steps_per_save = 1000;
        msnerf::nerf::trainer::train(&g, &common::train_options(&data, &run, model, 64)).unwrap();
    }
    let las = tmp.path().join("cloud.las");
    let text = common::msnerf(
        env!("CARGO_BIN_EXE_msnerf"),
        &[
            "export",
            "pointcloud",
            run.to_str().unwrap(),
            "--out",
            las.to_str().unwrap(),
            "--rays",
            "4000",
            "--check-views",
            "0",
            "--no-refine",
            "--min-accumulation",
            "0",
        ],
    );
    assert!(text.contains("crs EPSG:32650"), "{text}");
    let (wkt, bit) = las_wkt(&las);
    assert!(bit);
    assert_eq!(gdalsrsinfo_epsg(&wkt.expect("WKT record")), "EPSG:32650");
    // The points are at the scene's UTM coordinates (world_offset 500000, 4000000, 20), not normalised ones.
    let cloud = msnerf::output::pointcloud::read_las(&las).unwrap();
    let n = cloud.len();
    assert!(n > 0);
    let mut xs: Vec<f64> = cloud.positions.iter().map(|p| p[0]).collect();
    xs.sort_by(f64::total_cmp);
    assert!((xs[n / 2] - 500000.0).abs() < 100.0, "median easting {}", xs[n / 2]);
}
