//! `msnerf import poses --from metashape` (issue 20, item 2, Metashape part): the simulated `ci-small` cameras
//! written as a Metashape camera XML by a writer in this test, with a chunk transform (scale 2.5) and a component
//! transform (scale 0.8) that must compose as `x = s R x_local + t`, an initial calibration that must not be used
//! next to the adjusted one, Metashape's p1/p2 order, a disabled camera and an unaligned one; then a georeferenced
//! chunk (ECEF) whose relative geometry must survive the conversion to east-north-up metres.

// Matrices are compared element by element, indexed as written.
#![allow(clippy::needless_range_loop)]

use crate::common;
use crate::geo_support;
use crate::poses_support;
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
    let m = read_cameras_xml(&xml, None).unwrap();
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
fn georeferenced_chunk_lands_in_its_utm_zone_as_gdal_projects_it() {
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
    // The simulated world may sit at UTM-sized coordinates: centre it on the cameras first, so the cameras' mean
    // position is the tangent point (600 km away, the tangent plane would tilt by 5 degrees).
    let mean = t.c2w.iter().map(|m| DVec3::new(m[0][3], m[1][3], m[2][3])).sum::<DVec3>() / t.c2w.len() as f64;
    let enu_to_ecef = enu_to_ecef * DMat4::from_translation(-mean);
    let xml = tmp.path().join("cameras.xml");
    write_xml(&xml, &t, enu_to_ecef, true);
    let d = tmp.path().join("data");
    copy_dataset(&data, &d);
    let m = read_cameras_xml(&xml, None).unwrap();
    assert_eq!(m.crs.as_ref().and_then(|c| c.epsg), Some(32632), "7 E, 45 N is in UTM zone 32N");
    let rep = apply_poses(&m, &xml, &d).unwrap();
    assert_eq!(rep.crs.as_deref(), Some("EPSG:32632 (WGS 84 / UTM zone 32N)"));
    let tj: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(tj["crs"], "EPSG:32632");
    msnerf::data::load_dataset(&d, &msnerf::data::LoadOptions::default()).expect("the dataset loads with its crs");
    let got = imported(&d);
    let idx: Vec<usize> = got.iter().map(|g| t.names.iter().position(|n| *n == g.0).unwrap()).collect();
    // Camera centres: GDAL/PROJ projects each true ECEF centre (EPSG:4978 -> 32632); ellipsoidal heights.
    let ecef: Vec<[f64; 3]> = idx
        .iter()
        .map(|&i| enu_to_ecef.transform_point3(DVec3::new(t.c2w[i][0][3], t.c2w[i][1][3], t.c2w[i][2][3])).to_array())
        .collect();
    let want = geo_support::gdaltransform("EPSG:4978", "EPSG:32632", &ecef);
    let mut worst: f64 = 0.0;
    for (g, w) in got.iter().zip(&want) {
        for k in 0..3 {
            worst = worst.max((g.1[k][3] - w[k]).abs());
        }
    }
    eprintln!("georeferenced: camera centres within {worst:.2e} m of gdaltransform's");
    assert!(worst < 1e-3, "{worst} m");
    // Orientations: turned with the grid at the posed cameras' mean position m (camera 5 is disabled, so m is a
    // few metres from the tangent point): truth rotation -> ECEF (tangent-point ENU) -> ENU at m -> turned about
    // the vertical by the grid's convergence at m, measured on GDAL's projection of a 100 m step north centred on m.
    let m_ecef = ecef.iter().fold(DVec3::ZERO, |a, p| a + DVec3::from_array(*p)) / ecef.len() as f64;
    let geo = geo_support::gdaltransform("EPSG:4978", "EPSG:4979", &[m_ecef.to_array()])[0];
    let (mlat, mlon) = (geo[1].to_radians(), geo[0].to_radians());
    let m_east = DVec3::new(-mlon.sin(), mlon.cos(), 0.0);
    let m_north = DVec3::new(-mlat.sin() * mlon.cos(), -mlat.sin() * mlon.sin(), mlat.cos());
    let m_up = DVec3::new(mlat.cos() * mlon.cos(), mlat.cos() * mlon.sin(), mlat.sin());
    let step = geo_support::gdaltransform(
        "EPSG:4978",
        "EPSG:32632",
        &[(m_ecef - 50.0 * m_north).to_array(), (m_ecef + 50.0 * m_north).to_array()],
    );
    let gamma = (-(step[1][0] - step[0][0])).atan2(step[1][1] - step[0][1]);
    let expected = DMat3::from_rotation_z(gamma)
        * DMat3::from_cols(m_east, m_north, m_up).transpose()
        * DMat3::from_cols(east, north, up);
    let rot = |m: &[[f64; 4]; 4]| {
        DMat3::from_cols_array(&[m[0][0], m[1][0], m[2][0], m[0][1], m[1][1], m[2][1], m[0][2], m[1][2], m[2][2]])
    };
    let mut worst_r: f64 = 0.0;
    for (g, &i) in got.iter().zip(&idx) {
        let d = rot(&g.1) - expected * rot(&t.c2w[i]);
        worst_r = worst_r.max(d.to_cols_array().iter().fold(0.0, |m, v| m.max(v.abs())));
    }
    eprintln!("convergence {:.4} deg; rotations within {worst_r:.2e}", gamma.to_degrees());
    assert!(gamma.to_degrees().abs() > 1.0, "7 E is 2 degrees from zone 32's meridian: the grid turns");
    assert!(worst_r < 1e-7, "{worst_r}");
    // Another projected CRS on request; a geographic one is refused, named.
    let wgs = msnerf::geo::Crs::parse("EPSG:32631").unwrap();
    assert_eq!(read_cameras_xml(&xml, Some(&wgs)).unwrap().crs.unwrap().epsg, Some(32631));
    let e = read_cameras_xml(&xml, Some(&msnerf::geo::Crs::parse("EPSG:4326").unwrap())).unwrap_err().to_string();
    assert!(e.contains("--crs") && e.contains("EPSG:4326"), "{e}");
    // A reference without a chunk transform (never georeferenced): the local frame, no crs, and a note says why.
    let text = std::fs::read_to_string(&xml).unwrap();
    let (head, tail) = text.split_once("</cameras>\n").unwrap();
    let (chunk_transform, rest) = tail.split_once('\n').unwrap();
    assert!(chunk_transform.starts_with("<transform>"), "{chunk_transform}");
    let bare = tmp.path().join("no-chunk-transform.xml");
    std::fs::write(&bare, format!("{head}</cameras>\n{rest}")).unwrap();
    let m = read_cameras_xml(&bare, None).unwrap();
    assert!(m.crs.is_none() && m.notes.iter().any(|n| n.contains("no <transform>")), "{:?}", m.notes);
}

#[test]
fn bad_metashape_files_are_named() {
    let tmp = TempDir::new("poses-ms-bad");
    let p = tmp.path().join("c.xml");
    std::fs::write(&p, "<document><chunk><sensors><sensor id=\"0\" type=\"frame\"><resolution width=\"4\" height=\"3\"/><calibration type=\"spherical\" class=\"adjusted\"><f>1</f></calibration></sensor></sensors></chunk></document>").unwrap();
    let e = read_cameras_xml(&p, None).unwrap_err().to_string();
    assert!(e.contains("c.xml") && e.contains("sensor 0") && e.contains("spherical"), "{e}");
    std::fs::write(&p, "<document><chunk><cameras><camera label=\"A\" sensor_id=\"7\"><transform>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</transform></camera></cameras></chunk></document>").unwrap();
    let e = read_cameras_xml(&p, None).unwrap_err().to_string();
    assert!(e.contains("camera A") && e.contains("sensor \"7\""), "{e}");
    std::fs::write(&p, "<document><chunk>").unwrap();
    assert!(read_cameras_xml(&p, None).unwrap_err().to_string().contains("XML"));
}

#[test]
fn multi_camera_slaves_are_posed_from_their_master_and_sensor_offset() {
    let tmp = TempDir::new("poses-ms-rig");
    // Three master cameras (camera-to-chunk, OpenCV axes) and a slave sensor 5 degrees about y, 4 cm across.
    let masters: Vec<DMat4> = (0..3)
        .map(|k| {
            DMat4::from_rotation_translation(
                glam::DQuat::from_euler(glam::EulerRot::XYZ, 3.0 + 0.1 * k as f64, 0.2, 0.05 * k as f64),
                DVec3::new(k as f64, 0.5 * k as f64, 10.0),
            )
        })
        .collect();
    let slave =
        DMat4::from_rotation_translation(glam::DQuat::from_rotation_y(5f64.to_radians()), DVec3::new(0.04, 0.0, 0.001));
    let chunk = DMat4::from_scale_rotation_translation(
        DVec3::splat(2.0),
        glam::DQuat::from_rotation_z(0.4),
        DVec3::new(100.0, 200.0, 5.0),
    );
    let rows = |m: &DMat4| {
        (0..4).flat_map(|i| (0..4).map(move |j| m.col(j)[i])).map(|v| format!("{v:e}")).collect::<Vec<_>>().join(" ")
    };
    let r3 = |m: &DMat4| {
        (0..3).flat_map(|i| (0..3).map(move |j| m.col(j)[i])).map(|v| format!("{v:e}")).collect::<Vec<_>>().join(" ")
    };
    let calib = r#"<resolution width="64" height="48"/><calibration type="frame" class="adjusted"><resolution width="64" height="48"/><f>50</f></calibration>"#;
    let mut cams = String::new();
    for (k, m) in masters.iter().enumerate() {
        cams += &format!(
            "<camera id=\"{}\" sensor_id=\"0\" label=\"m{k}\"><transform>{}</transform></camera>\n",
            2 * k,
            rows(m)
        );
        cams += &format!("<camera id=\"{}\" sensor_id=\"1\" master_id=\"{}\" label=\"s{k}\"/>\n", 2 * k + 1, 2 * k);
    }
    let xml = format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<document version="1.5.0"><chunk label="rig">
<sensors><sensor id="0" label="Green" type="frame" master_id="0">{calib}</sensor>
<sensor id="1" label="NIR" type="frame" master_id="0">{calib}<rotation>{}</rotation><location>{} {} {}</location></sensor></sensors>
<cameras><group id="0" label="captures" type="folder">{cams}</group></cameras>
<transform><rotation>{}</rotation><translation>100 200 5</translation><scale>2</scale></transform>
</chunk></document>"#,
        r3(&slave),
        slave.w_axis.x,
        slave.w_axis.y,
        slave.w_axis.z,
        r3(&DMat4::from_rotation_z(0.4)),
    );
    let path = tmp.path().join("rig.xml");
    std::fs::write(&path, xml).unwrap();
    let m = read_cameras_xml(&path, None).unwrap();
    assert_eq!(m.images.len(), 6, "masters and slaves (inside a camera group) are posed");
    assert!(m.notes.iter().any(|n| n.contains("3 slave camera(s)")), "{:?}", m.notes);
    let mut worst: f64 = 0.0;
    for (k, master) in masters.iter().enumerate() {
        for (label, local) in [(format!("m{k}"), *master), (format!("s{k}"), *master * slave)] {
            let w = chunk * local;
            // Expected OpenGL camera-to-world: scale out of the rotation, camera y and z negated.
            let rot = glam::DMat3::from_mat4(w) * 0.5;
            let im = m.images.iter().find(|i| i.name == label).unwrap();
            for i in 0..3 {
                let want = [rot.col(0)[i], -rot.col(1)[i], -rot.col(2)[i], w.w_axis[i]];
                for j in 0..4 {
                    worst = worst.max((im.c2w[i][j] - want[j]).abs() / want[j].abs().max(1.0));
                }
            }
        }
    }
    assert!(worst < 1e-9, "{worst}");
}
