//! `msnerf import poses --from metashape` (issue 20, item 2, Metashape part): the simulated `ci-small` cameras
//! written as a Metashape camera XML by a writer in this test, with a chunk transform (scale 2.5) and a component
//! transform (scale 0.8) that must compose as `x = s R x_local + t`, an initial calibration that must not be used
//! next to the adjusted one, Metashape's p1/p2 order, a disabled camera and an unaligned one; then a georeferenced
//! chunk (ECEF) whose relative geometry must survive the conversion to east-north-up metres.

// Matrices are compared element by element, indexed as written.
#![allow(clippy::needless_range_loop)]

mod common;
mod poses_support;

use std::path::Path;

use common::TempDir;
use glam::{DMat3, DMat4, DVec3};
use msnerf::poses::apply_poses;
use msnerf::poses::metashape::read_cameras_xml;
use poses_support::{copy_dataset, stem, truth, Truth};
use serde_json::Value;

/// OpenGL camera-to-world -> the OpenCV-axes 4x4 Metashape stores (y and z camera axes negated).
fn opencv(c2w: &[[f64; 4]; 4]) -> DMat4 {
    let mut m = DMat4::IDENTITY;
    for i in 0..3 {
        for j in 0..4 {
            let v = if j == 1 || j == 2 { -c2w[i][j] } else { c2w[i][j] };
            m.col_mut(j)[i] = v;
        }
    }
    m
}

fn sim(r: DMat3, t: DVec3, s: f64) -> DMat4 {
    let m = r * s;
    DMat4::from_cols(m.x_axis.extend(0.0), m.y_axis.extend(0.0), m.z_axis.extend(0.0), t.extend(1.0))
}

fn transform_xml(r: DMat3, t: DVec3, s: f64) -> String {
    let rr: Vec<String> = (0..3).flat_map(|i| (0..3).map(move |j| format!("{:e}", r.col(j)[i]))).collect();
    format!(
        "<transform><rotation>{}</rotation><translation>{:e} {:e} {:e}</translation><scale>{s:e}</scale></transform>",
        rr.join(" "),
        t.x,
        t.y,
        t.z
    )
}

/// The XML: `world_of` maps the truth's world to the file's world (identity, or into ECEF).
fn write_xml(path: &Path, t: &Truth, world_of: DMat4, georef: bool) {
    let (w, h) = (t.size.0 as f64, t.size.1 as f64);
    let [fx, fy, cx, cy] = t.cam;
    let chunk = (DMat3::from_rotation_z(0.3) * DMat3::from_rotation_x(-0.2), DVec3::new(10.0, -4.0, 2.0), 2.5);
    let comp = (DMat3::from_rotation_y(0.7), DVec3::new(-1.5, 0.25, 3.0), 0.8);
    let outer = sim(chunk.0, chunk.1, chunk.2) * sim(comp.0, comp.1, comp.2);
    let mut cams = String::new();
    for (i, n) in t.names.iter().enumerate() {
        let label = stem(n);
        if i == 2 {
            cams += &format!("<camera id=\"{i}\" sensor_id=\"0\" component_id=\"0\" label=\"{label}\"/>\n"); // not aligned
            continue;
        }
        let local = outer.inverse() * world_of * opencv(&t.c2w[i]);
        let rm = local.transpose().to_cols_array(); // row-major
        let enabled = if i == 5 { " enabled=\"false\"" } else { "" };
        cams += &format!(
            "<camera id=\"{i}\" sensor_id=\"0\" component_id=\"0\" label=\"{label}\"{enabled}><transform>{}</transform></camera>\n",
            rm.iter().map(|v| format!("{v:e}")).collect::<Vec<_>>().join(" ")
        );
    }
    let reference =
        if georef { "<reference>GEOGCS[\"WGS 84\",DATUM[\"World Geodetic System 1984\"]]</reference>" } else { "" };
    let xml = format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<document version="1.5.0"><chunk label="Chunk 1" enabled="true">
<sensors next_id="1"><sensor id="0" label="MS" type="frame"><resolution width="{w}" height="{h}"/>
<calibration type="frame" class="initial"><resolution width="{w}" height="{h}"/><f>999</f></calibration>
<calibration type="frame" class="adjusted"><resolution width="{w}" height="{h}"/><f>{fy:e}</f><cx>{:e}</cx><cy>{:e}</cy><b1>{:e}</b1><k1>0.01</k1><k2>-0.002</k2><p1>0.0002</p1><p2>0.0005</p2></calibration>
</sensor></sensors>
<components next_id="1" active_id="0"><component id="0" label="Component 1">{}</component></components>
<cameras next_id="{}" next_group_id="0">
{cams}</cameras>
{}
{reference}
</chunk></document>"#,
        cx - w / 2.0,
        cy - h / 2.0,
        fx - fy,
        transform_xml(comp.0, comp.1, comp.2),
        t.names.len(),
        transform_xml(chunk.0, chunk.1, chunk.2),
    );
    std::fs::write(path, xml).unwrap();
}

fn imported(d: &Path) -> Vec<(String, [[f64; 4]; 4], Value)> {
    let tj: Value = serde_json::from_str(&std::fs::read_to_string(d.join("transforms.json")).unwrap()).unwrap();
    tj["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            let m: [[f64; 4]; 4] =
                std::array::from_fn(|i| std::array::from_fn(|j| f["transform_matrix"][i][j].as_f64().unwrap()));
            (f["file_path"].as_str().unwrap().to_string(), m, f.clone())
        })
        .collect()
}

#[test]
fn metashape_chunk_and_component_transforms_compose_and_adjusted_calibration_wins() {
    let tmp = TempDir::new("poses-ms");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let t = truth(&data);
    let xml = tmp.path().join("cameras.xml");
    write_xml(&xml, &t, DMat4::IDENTITY, false);
    let d = tmp.path().join("data");
    copy_dataset(&data, &d);
    let m = read_cameras_xml(&xml).unwrap();
    let rep = apply_poses(&m, &xml, &d).unwrap();
    assert_eq!(rep.registered, t.names.len() - 2);
    assert_eq!(rep.unregistered.len(), 2, "the unaligned and the disabled camera: {rep:?}");
    let mut worst: f64 = 0.0;
    for (name, c2w, f) in imported(&d) {
        let i = t.names.iter().position(|n| *n == name).unwrap();
        for r in 0..4 {
            for c in 0..4 {
                worst = worst.max((c2w[r][c] - t.c2w[i][r][c]).abs() / t.c2w[i][r][c].abs().max(1.0));
            }
        }
        for (k, want) in ["fl_x", "fl_y", "cx", "cy"].iter().zip(t.cam) {
            assert!(
                (f[*k].as_f64().unwrap() - want).abs() < 1e-9 * want.max(1.0),
                "{k}: {} against {want} (the adjusted calibration)",
                f[*k]
            );
        }
        assert_eq!(
            (f["p1"].as_f64(), f["p2"].as_f64()),
            (Some(0.0005), Some(0.0002)),
            "Metashape's P1/P2 are OpenCV's p2/p1"
        );
        assert_eq!(f["k1"].as_f64(), Some(0.01));
    }
    eprintln!("largest relative pose difference: {worst:e}");
    assert!(worst < 1e-6, "{worst:e}");
    msnerf::data::load_dataset(&d, &msnerf::data::LoadOptions::default()).unwrap();
}

#[test]
fn georeferenced_chunk_becomes_east_north_up_metres_with_its_geometry() {
    let tmp = TempDir::new("poses-ms-geo");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let t = truth(&data);
    // The truth's world as east-north-up about a point at 45 N, 7 E, 300 m, expressed in ECEF.
    let (lat, lon, h): (f64, f64, f64) = (45f64.to_radians(), 7f64.to_radians(), 300.0);
    let (a, f) = (6_378_137.0, 1.0 / 298.257_223_563);
    let e2 = f * (2.0 - f);
    let n = a / (1.0 - e2 * lat.sin().powi(2)).sqrt();
    let o =
        DVec3::new((n + h) * lat.cos() * lon.cos(), (n + h) * lat.cos() * lon.sin(), (n * (1.0 - e2) + h) * lat.sin());
    let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
    let north = DVec3::new(-lat.sin() * lon.cos(), -lat.sin() * lon.sin(), lat.cos());
    let up = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
    let enu_to_ecef = DMat4::from_cols(east.extend(0.0), north.extend(0.0), up.extend(0.0), o.extend(1.0));
    // The simulated world may sit at UTM-sized coordinates: centre it on the cameras first, so "up" at O is up
    // for them too (600 km away, the tangent plane would tilt by 5 degrees).
    let mean = t.c2w.iter().map(|m| DVec3::new(m[0][3], m[1][3], m[2][3])).sum::<DVec3>() / t.c2w.len() as f64;
    let enu_to_ecef = enu_to_ecef * DMat4::from_translation(-mean);
    let xml = tmp.path().join("cameras.xml");
    write_xml(&xml, &t, enu_to_ecef, true);
    let d = tmp.path().join("data");
    copy_dataset(&data, &d);
    let m = read_cameras_xml(&xml).unwrap();
    assert!(m.crs.as_deref().unwrap().contains("east-north-up"), "{:?}", m.crs);
    apply_poses(&m, &xml, &d).unwrap();
    let got = imported(&d);
    // Distances between camera centres and relative rotations are the truth's (the frame differs by a rigid
    // motion only: ENU about the cameras' mean position instead of the chosen point).
    let idx: Vec<usize> = got.iter().map(|g| t.names.iter().position(|n| *n == g.0).unwrap()).collect();
    let centre = |m: &[[f64; 4]; 4]| DVec3::new(m[0][3], m[1][3], m[2][3]);
    let rot = |m: &[[f64; 4]; 4]| {
        DMat3::from_cols_array(&[m[0][0], m[1][0], m[2][0], m[0][1], m[1][1], m[2][1], m[0][2], m[1][2], m[2][2]])
    };
    let mut worst: f64 = 0.0;
    for a in 0..got.len() {
        for b in a + 1..got.len() {
            let dg = centre(&got[a].1).distance(centre(&got[b].1));
            let dt = centre(&t.c2w[idx[a]]).distance(centre(&t.c2w[idx[b]]));
            worst = worst.max((dg - dt).abs() / dt.max(1.0));
            let rg = rot(&got[a].1).transpose() * rot(&got[b].1);
            let rt = rot(&t.c2w[idx[a]]).transpose() * rot(&t.c2w[idx[b]]);
            worst = worst.max((rg - rt).to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs())));
        }
    }
    eprintln!("georeferenced: largest relative geometry difference {worst:e}");
    assert!(worst < 1e-6, "{worst:e}");
    // Up stays up: the truth's world z was up, so the cameras' z axes agree with the truth's in the new frame.
    for (g, &i) in got.iter().zip(&idx) {
        let (zg, zt) = (rot(&g.1).z_axis.z, rot(&t.c2w[i]).z_axis.z);
        assert!((zg - zt).abs() < 1e-3, "camera z-axis height {zg} against {zt}");
    }
}

#[test]
fn bad_metashape_files_are_named() {
    let tmp = TempDir::new("poses-ms-bad");
    let p = tmp.path().join("c.xml");
    std::fs::write(&p, "<document><chunk><sensors><sensor id=\"0\" type=\"frame\"><resolution width=\"4\" height=\"3\"/><calibration type=\"spherical\" class=\"adjusted\"><f>1</f></calibration></sensor></sensors></chunk></document>").unwrap();
    let e = read_cameras_xml(&p).unwrap_err().to_string();
    assert!(e.contains("c.xml") && e.contains("sensor 0") && e.contains("spherical"), "{e}");
    std::fs::write(&p, "<document><chunk><cameras><camera label=\"A\" sensor_id=\"7\"><transform>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</transform></camera></cameras></chunk></document>").unwrap();
    let e = read_cameras_xml(&p).unwrap_err().to_string();
    assert!(e.contains("camera A") && e.contains("sensor \"7\""), "{e}");
    std::fs::write(&p, "<document><chunk>").unwrap();
    assert!(read_cameras_xml(&p).unwrap_err().to_string().contains("XML"));
}
