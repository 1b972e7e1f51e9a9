//! Point clouds: PLY read back by ply-rs-bw (an independent parser) and by our reader, LAS read back by the
//! `las` crate's reader with the Extra Bytes descriptors unpacked by hand, UTM-sized coordinates, filters, and
//! per-point scalar attributes (validation, PLY/LAS round trips, kept aligned by every filter).

use crate::output_support;
use std::f64::consts::FRAC_PI_2;

use msnerf::data::PoseTransform;
use msnerf::output::image::{band, ms600pro_bands};
use msnerf::output::pointcloud::kdtree::{dist2, KdTree};
use msnerf::output::pointcloud::las::ExtraBytesDescriptor;
use msnerf::output::pointcloud::{
    crop, read_las, read_ply, remove_statistical_outliers, subsample, write_las, write_ply, Aabb, LasOptions,
    OrientedBox, PlyCoords, PlyOptions, PointCloud, ScalarField,
};
use output_support::{scratch, Rng};
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property, PropertyType, ScalarType};

/// A 6-band cloud around UTM 50N coordinates (5e5, 4e6), with odd sub-millimetre fractions.
fn utm_cloud(n: usize, seed: u64) -> PointCloud {
    let mut rng = Rng(seed);
    let positions: Vec<[f64; 3]> = (0..n)
        .map(|_| [500000.0 + rng.f64() * 200.0, 4000000.0 + rng.f64() * 200.0, 30.0 + rng.f64() * 20.0])
        .collect();
    let values: Vec<f32> = (0..n * 6).map(|_| rng.f64() as f32 * 0.7).collect();
    let mut c = PointCloud::new(positions, ms600pro_bands(), values).unwrap();
    c.normals = Some((0..n).map(|i| [0.0, (i as f32).sin(), (i as f32).cos()]).collect());
    c
}

fn as_f64(p: &Property) -> f64 {
    match *p {
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        Property::UChar(v) => v as f64,
        _ => panic!("unexpected property {p:?}"),
    }
}

#[test]
fn ply_round_trips_through_an_independent_parser() {
    let dir = scratch("ply");
    let cloud = utm_cloud(500, 3);
    let path = dir.join("cloud.ply");
    write_ply(&path, &cloud, &PlyOptions::default()).unwrap();

    let mut f = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
    let ply = Parser::<DefaultElement>::new().read_ply(&mut f).unwrap();
    let vdef = &ply.header.elements["vertex"];
    assert_eq!(vdef.count, 500);
    assert_eq!(vdef.properties["x"].data_type, PropertyType::Scalar(ScalarType::Double));
    assert_eq!(vdef.properties["red"].data_type, PropertyType::Scalar(ScalarType::UChar));
    let names = ["refl_450", "refl_555", "refl_660", "refl_720", "refl_750", "refl_840"];
    for n in names {
        assert_eq!(vdef.properties[n].data_type, PropertyType::Scalar(ScalarType::Float), "{n}");
    }
    assert!(
        ply.header.comments.iter().any(|c| c == "band 5 refl_840 center_nm 840 fwhm_nm 35 name NIR"),
        "{:?}",
        ply.header.comments
    );
    let verts = &ply.payload["vertex"];
    let display = cloud.display_rgb(Default::default());
    for (i, v) in verts.iter().enumerate() {
        for (a, k) in ["x", "y", "z"].iter().enumerate() {
            assert_eq!(as_f64(&v[*k]), cloud.positions[i][a], "point {i} {k}");
        }
        for (b, n) in names.iter().enumerate() {
            assert_eq!((as_f64(&v[*n]) as f32).to_bits(), cloud.point_values(i)[b].to_bits());
        }
        assert_eq!(as_f64(&v["ny"]) as f32, cloud.normals.as_ref().unwrap()[i][1]);
        assert_eq!(as_f64(&v["red"]) as u8, display[i][0]);
    }

    // Our reader restores everything, including band metadata.
    let back = read_ply(&path).unwrap();
    assert_eq!(back.positions, cloud.positions);
    assert_eq!(back.values, cloud.values);
    assert_eq!(back.normals, cloud.normals);
    assert_eq!(back.rgb.as_ref().unwrap(), &display);
    for (a, b) in back.bands.iter().zip(&cloud.bands) {
        assert_eq!((&a.name, a.center_nm, a.fwhm_nm), (&b.name, b.center_nm, b.fwhm_nm));
    }
}

#[test]
fn ply_float_coordinates_with_offset_keep_millimetres() {
    let dir = scratch("ply_f32");
    let cloud = utm_cloud(300, 5);
    let path = dir.join("f32.ply");
    let opts = PlyOptions { coords: PlyCoords::F32 { offset: [500000.0, 4000000.0, 0.0] }, ..Default::default() };
    write_ply(&path, &cloud, &opts).unwrap();
    let back = read_ply(&path).unwrap();
    for (a, b) in back.positions.iter().zip(&cloud.positions) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-4, "{} vs {}", a[k], b[k]);
        }
    }
    // Without the offset, f32 cannot hold UTM coordinates to a millimetre: that is why double is the default.
    assert!(((4000000.123f64 as f32) as f64 - 4000000.123).abs() > 1e-3);
}

#[test]
fn ply_reader_accepts_ascii_and_foreign_properties() {
    let dir = scratch("ply_ascii");
    let path = dir.join("ascii.ply");
    let text = "ply\nformat ascii 1.0\ncomment from somewhere else\nelement vertex 3\nproperty float x\nproperty float y\n\
                property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nproperty float refl_840\n\
                property float scalar_Intensity\nproperty list uchar int extra\nproperty int views\n\
                property double dev.x\nproperty uchar Views\nelement face 0\n\
                property list uchar int vertex_indices\nend_header\n\
                0 0 0 255 0 0 0.5 12 2 1 2 3 0.5 1\n1 0 0 0 255 0 0.25 13 0 4 -1.25 0\n0 1 2.5 0 0 255 0.125 14 1 7 5 1e-3 1\n";
    std::fs::write(&path, text).unwrap();
    let c = read_ply(&path).unwrap();
    assert_eq!(c.len(), 3);
    assert_eq!(c.positions[2], [0.0, 1.0, 2.5]);
    // A foreign file: `refl_*` properties are bands, other scalars attributes (CloudCompare's scalar fields).
    assert_eq!(c.bands.len(), 1);
    assert_eq!(c.bands[0].center_nm, Some(840.0));
    assert_eq!(c.point_values(1), &[0.25]);
    assert_eq!(c.rgb.as_ref().unwrap()[1], [0, 255, 0]);
    let names: Vec<&str> = c.attributes.iter().map(|a| a.name.as_str()).collect();
    // `dev.x` is not a valid attribute name; `Views` clashes with `views` (names ignore case).
    assert_eq!(names, ["scalar_Intensity", "views", "dev_x", "Views_2"]);
    assert_eq!(c.attributes[0].values, [12.0, 13.0, 14.0]);
    assert_eq!(c.attributes[1].values, [3.0, 4.0, 5.0]);
    assert_eq!(c.attributes[2].values, [0.5, -1.25, 1e-3]);
    assert_eq!(c.attributes[3].values, [1.0, 0.0, 1.0]);
    assert!(c.attributes.iter().all(|a| a.description.is_empty()));
    c.validate().unwrap();

    std::fs::write(&path, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n2\n").unwrap();
    let e = read_ply(&path).unwrap_err().to_string();
    assert!(e.contains("ascii.ply") && e.contains("x, y or z"), "{e}");
    std::fs::write(&path, "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0").unwrap();
    let e = read_ply(&path).unwrap_err().to_string();
    assert!(e.contains("ends inside"), "{e}");
}

#[test]
fn las_pdrf8_with_extra_bytes_round_trips() {
    let dir = scratch("las");
    let mut cloud = utm_cloud(400, 9);
    cloud.normals = None; // normals add three Extra Bytes: see las_normals_are_extra_bytes_named_normal_xyz_and_read_back
    let cloud = cloud;
    let path = dir.join("cloud.las");
    write_las(&path, &cloud, &LasOptions::default()).unwrap();

    // The las crate's reader: format 8, LAS 1.4, extra bytes for RE1 and RE2 as f32.
    let mut r = las::Reader::from_path(&path).unwrap();
    let h = r.header().clone();
    assert_eq!(h.version(), las::Version::new(1, 4));
    assert_eq!(h.point_format().to_u8().unwrap(), 8);
    assert_eq!(h.point_format().extra_bytes, 8);
    assert_eq!(h.number_of_points(), 400);
    let vlr = h.all_vlrs().find(|v| v.user_id == "LASF_Spec" && v.record_id == 4).unwrap();
    assert_eq!(vlr.data.len(), 2 * 192);
    // Descriptor fields at their spec offsets, read by hand.
    let d0 = &vlr.data[..192];
    assert_eq!(d0[2], 9, "data_type float");
    assert_eq!(&d0[4..12], b"refl_720");
    assert_eq!(&d0[160..174], b"RedEdge1 720nm");
    assert_eq!(ExtraBytesDescriptor::unpack(&vlr.data[192..]).name, "refl_750");
    let t = h.transforms();
    assert_eq!((t.x.scale, t.x.offset, t.y.offset), (0.001, 500000.0, 4000000.0));
    let data = r.read_all().unwrap();
    for (i, p) in data.points().enumerate() {
        let p = p.unwrap();
        let q = cloud.positions[i];
        assert!(
            (p.x - q[0]).abs() <= 0.0005 + 1e-9
                && (p.y - q[1]).abs() <= 0.0005 + 1e-9
                && (p.z - q[2]).abs() <= 0.0005 + 1e-9
        );
        let v = cloud.point_values(i);
        let u16v = |x: f32| ((x as f64).clamp(0.0, 1.0) * 65535.0).round() as u16;
        let c = p.color.unwrap();
        assert_eq!((c.red, c.green, c.blue), (u16v(v[2]), u16v(v[1]), u16v(v[0])));
        assert_eq!(p.nir.unwrap(), u16v(v[5]));
        assert_eq!(p.extra_bytes.len(), 8);
        assert_eq!(f32::from_le_bytes(p.extra_bytes[0..4].try_into().unwrap()).to_bits(), v[3].to_bits());
        assert_eq!(f32::from_le_bytes(p.extra_bytes[4..8].try_into().unwrap()).to_bits(), v[4].to_bits());
    }

    // Our reader: bands restored in order; RGB/NIR within the u16 quantum, extra bytes exact.
    let back = read_las(&path).unwrap();
    assert_eq!(back.bands.len(), 6);
    assert_eq!(back.bands[5].center_nm, Some(840.0));
    for i in 0..400 {
        let (a, b) = (back.point_values(i), cloud.point_values(i));
        for k in [0, 1, 2, 5] {
            assert!((a[k] - b[k]).abs() <= 0.5 / 65535.0 + 1e-7, "band {k}: {} vs {}", a[k], b[k]);
        }
        assert_eq!((a[3], a[4]), (b[3], b[4]));
    }

    // All bands as extra bytes: every value exact; a WKT VLR sets the WKT bit.
    let p2 = dir.join("all.las");
    let opts = LasOptions {
        all_bands_as_extra_bytes: true,
        wkt: Some("PROJCS[\"WGS 84 / UTM zone 50N\"]".into()),
        ..Default::default()
    };
    write_las(&p2, &cloud, &opts).unwrap();
    let back = read_las(&p2).unwrap();
    assert_eq!(back.values, cloud.values);
    assert!(las::Reader::from_path(&p2).unwrap().header().has_wkt_crs());

    // Coordinates that do not fit the i32 records: an error naming the axis.
    let mut far = cloud.clone();
    far.positions[0][2] = 1e8;
    let e = write_las(
        &dir.join("far.las"),
        &far,
        &LasOptions { offset: Some([500000.0, 4000000.0, 0.0]), ..Default::default() },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("z = "), "{e}");
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2, "failed write left no file");
}

#[test]
fn las_without_visible_bands_uses_display_colour() {
    let dir = scratch("las_nir");
    let bands = vec![band("RE", Some(720.0), None), band("NIR", Some(840.0), None)];
    let c = PointCloud::new(vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], bands, vec![0.1, 0.5, 0.2, 0.6]).unwrap();
    let p = dir.join("two.las");
    write_las(&p, &c, &LasOptions::default()).unwrap();
    let back = read_las(&p).unwrap();
    assert_eq!(back.positions, c.positions);
    assert_eq!(back.bands[0].name, "RE");
    assert_eq!(back.point_values(1)[0], 0.2);
    assert!((back.point_values(1)[1] - 0.6).abs() < 1e-5);
}

#[test]
fn kdtree_matches_brute_force() {
    let mut rng = Rng(17);
    // Many points share coordinates (grid) plus duplicates.
    let mut pts: Vec<[f64; 3]> =
        (0..900).map(|i| [(i % 10) as f64, ((i / 10) % 10) as f64, (i / 100) as f64]).collect();
    pts.extend((0..300).map(|_| [rng.f64() * 10.0, rng.f64() * 10.0, 0.0]));
    pts.extend_from_slice(&[[3.0, 3.0, 3.0]; 40]);
    let tree = KdTree::new(&pts);
    for _ in 0..200 {
        let q = [rng.f64() * 12.0 - 1.0, rng.f64() * 12.0 - 1.0, rng.f64() * 10.0 - 1.0];
        let (i, d) = tree.nearest(&q).unwrap();
        let best = pts.iter().map(|p| dist2(&q, p)).fold(f64::INFINITY, f64::min);
        assert_eq!(d, best);
        assert_eq!(dist2(&q, &pts[i]), d);
        let k = tree.knn(&q, 7);
        let mut all: Vec<f64> = pts.iter().map(|p| dist2(&q, p)).collect();
        all.sort_by(f64::total_cmp);
        assert_eq!(k.iter().map(|x| x.1).collect::<Vec<_>>(), all[..7].to_vec());
    }
    assert!(KdTree::new(&[]).nearest(&[0.0; 3]).is_none());
}

#[test]
fn statistical_outlier_removal_matches_open3d_rules() {
    // A 10x10x1 grid with spacing 1 and two far outliers.
    let mut pos: Vec<[f64; 3]> = (0..100).map(|i| [(i % 10) as f64, (i / 10) as f64, 0.0]).collect();
    pos.push([50.0, 50.0, 50.0]);
    pos.push([-40.0, 0.0, 0.0]);
    let n = pos.len();
    let c = PointCloud::new(pos.clone(), vec![band("b", None, None)], (0..n).map(|i| i as f32).collect()).unwrap();
    let (kept, idx) = remove_statistical_outliers(&c, 5, 2.0).unwrap();
    assert_eq!(idx, (0..100).collect::<Vec<_>>());
    assert_eq!(kept.len(), 100);
    assert_eq!(kept.point_values(99), &[99.0]);

    // The threshold by hand (k includes the point itself at distance 0; sample std).
    let tree = KdTree::new(&pos);
    let avg: Vec<f64> = pos.iter().map(|p| tree.knn(p, 5).iter().map(|x| x.1.sqrt()).sum::<f64>() / 5.0).collect();
    let mean = avg.iter().sum::<f64>() / n as f64;
    let std = (avg.iter().map(|d| (d - mean) * (d - mean)).sum::<f64>() / (n as f64 - 1.0)).sqrt();
    let want: Vec<usize> = (0..n).filter(|&i| avg[i] < mean + 2.0 * std).collect();
    assert_eq!(idx, want);

    // Open3D drops a point whose k neighbours all coincide with it (mean distance 0).
    let mut dup = pos.clone();
    dup.extend_from_slice(&[[100.0, 0.0, 0.0]; 6]);
    let c = PointCloud::new(dup, vec![], vec![]).unwrap();
    let (_, idx) = remove_statistical_outliers(&c, 5, 10.0).unwrap();
    assert!(idx.iter().all(|&i| i < 102));
    assert!(remove_statistical_outliers(&c, 0, 1.0).is_err());
}

#[test]
fn crop_boxes_and_subsampling() {
    let pos: Vec<[f64; 3]> = (0..1000).map(|i| [(i % 10) as f64, ((i / 10) % 10) as f64, (i / 100) as f64]).collect();
    let c = PointCloud::new(pos, vec![], vec![]).unwrap();
    let aabb = Aabb { min: [2.0, 2.0, 2.0], max: [4.0, 4.0, 4.0] };
    let (a, _) = crop(&c, |p| aabb.contains(p)).unwrap();
    assert_eq!(a.len(), 27, "inclusive bounds");
    // nerfstudio OBB: strict bounds; a 90° yaw swaps the x and y extents.
    let obb = OrientedBox::from_rpy([4.5, 4.5, 4.5], [0.0, 0.0, FRAC_PI_2], [2.0, 6.0, 10.0]);
    let (o, _) = crop(&c, |p| obb.contains(p)).unwrap();
    // Box x-axis (2 m) lies along world y, box y-axis (6 m) along world x: x in (1.5, 7.5), y in (3.5, 5.5).
    assert_eq!(o.len(), 6 * 2 * 10);
    assert!(o.positions.iter().all(|p| p[0] > 1.5 && p[0] < 7.5 && p[1] > 3.5 && p[1] < 5.5));
    let r = OrientedBox::from_rpy([0.0; 3], [0.3, -0.2, 1.1], [1.0; 3]).rotation;
    for i in 0..3 {
        for j in 0..3 {
            let d: f64 = (0..3).map(|k| r[k][i] * r[k][j]).sum();
            assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
        }
    }

    let (s1, i1) = subsample(&c, 100, 42).unwrap();
    let (_, i2) = subsample(&c, 100, 42).unwrap();
    let (_, i3) = subsample(&c, 100, 43).unwrap();
    assert_eq!(s1.len(), 100);
    assert_eq!(i1, i2, "same seed, same subset");
    assert_ne!(i1, i3);
    assert!(i1.windows(2).all(|w| w[0] < w[1]), "original order");
    assert_eq!(subsample(&c, 5000, 1).unwrap().0.len(), 1000);
    // A hand-built inconsistent cloud is an error, not a panic.
    let bad = PointCloud { values: vec![1.0], bands: vec![band("b", None, None)], ..c.clone() };
    let e = subsample(&bad, 10, 1).unwrap_err().to_string();
    assert!(e.contains("1 values for 1000 points"), "{e}");
}

#[test]
fn to_world_undoes_the_pose_normalisation() {
    let t =
        PoseTransform { transform: [[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0]], scale: 0.5 };
    let world = [[10.0, 20.0, 30.0], [-5.0, 0.5, 2.0]];
    let normed: Vec<[f64; 3]> = world.iter().map(|p| t.to_normalized(*p)).collect();
    let mut c = PointCloud::new(normed, vec![], vec![]).unwrap();
    c.normals = Some(vec![[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]);
    c.to_world(&t);
    for (a, b) in c.positions.iter().zip(&world) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-9);
        }
    }
    // Normal (1,0,0) in the normalised frame is Rᵀ·(1,0,0) = (0,-1,0) in the world.
    assert_eq!(c.normals.unwrap()[0], [0.0, -1.0, 0.0]);
}

#[test]
fn las_normals_are_extra_bytes_named_normal_xyz_and_read_back() {
    let dir = scratch("las_normals");
    let mut cloud = utm_cloud(50, 11);
    let normals: Vec<[f32; 3]> = (0..cloud.len())
        .map(|i| {
            let a = i as f32 * 0.3;
            [a.cos() * 0.6, a.sin() * 0.6, 0.8]
        })
        .collect();
    cloud.normals = Some(normals.clone());
    let path = dir.join("normals.las");
    write_las(&path, &cloud, &LasOptions::default()).unwrap();
    // The las crate's view: two band extras (RE1, RE2) then NormalX/Y/Z, 5 x f32 per point.
    let r = las::Reader::from_path(&path).unwrap();
    let h = r.header().clone();
    assert_eq!(h.point_format().extra_bytes, 20);
    let vlr = h.all_vlrs().find(|v| v.user_id == "LASF_Spec" && v.record_id == 4).unwrap();
    let names: Vec<String> = vlr.data.chunks_exact(192).map(|d| ExtraBytesDescriptor::unpack(d).name).collect();
    assert_eq!(names, ["refl_720", "refl_750", "NormalX", "NormalY", "NormalZ"]);
    let back = read_las(&path).unwrap();
    assert_eq!(back.bands.len(), 6, "normals are not bands");
    assert_eq!(back.normals.as_deref(), Some(&normals[..]), "f32 normals round-trip exactly");
    // PLY carries them as nx ny nz (CloudCompare's names).
    let ply = dir.join("normals.ply");
    write_ply(&ply, &cloud, &PlyOptions::default()).unwrap();
    assert_eq!(read_ply(&ply).unwrap().normals.as_deref(), Some(&normals[..]));
    // Without normals, nothing is added.
    cloud.normals = None;
    write_las(&path, &cloud, &LasOptions::default()).unwrap();
    assert!(read_las(&path).unwrap().normals.is_none());
}

/// `utm_cloud` with two attributes: `accumulation` (odd fractions, a subnormal, a negative zero) and
/// `agreeing_views` (small integers), with a description longer than a LAS descriptor holds.
fn cloud_with_attributes(n: usize, seed: u64) -> PointCloud {
    let mut c = utm_cloud(n, seed);
    let mut rng = Rng(seed ^ 0x5eed);
    let mut acc: Vec<f32> = (0..n).map(|_| rng.f64() as f32).collect();
    acc[0] = 1e-40;
    acc[1] = -0.0;
    acc[2] = 0.1;
    c.add_attribute("accumulation", "ray opacity", acc).unwrap();
    c.add_attribute(
        "agreeing_views",
        "training views whose depth agrees with the point",
        (0..n).map(|i| (i % 7) as f32).collect(),
    )
    .unwrap();
    c
}

fn assert_same_attributes(back: &[ScalarField], want: &[ScalarField]) {
    let names = |a: &[ScalarField]| a.iter().map(|f| f.name.clone()).collect::<Vec<_>>();
    assert_eq!(names(back), names(want), "names and order");
    for (a, b) in back.iter().zip(want) {
        assert_eq!(a.description, b.description, "{}", a.name);
        assert_eq!(a.values.len(), b.values.len(), "{}", a.name);
        for (i, (x, y)) in a.values.iter().zip(&b.values).enumerate() {
            assert_eq!(x.to_bits(), y.to_bits(), "{} point {i}: {x} vs {y}", a.name);
        }
    }
}

#[test]
fn ply_attributes_round_trip_binary_and_ascii() {
    let dir = scratch("ply_attr");
    let cloud = cloud_with_attributes(300, 21);
    let path = dir.join("attr.ply");
    write_ply(&path, &cloud, &PlyOptions::default()).unwrap();

    // ply-rs-bw: `property float <name>` after every other property, values exact, descriptions in comments.
    let mut f = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
    let ply = Parser::<DefaultElement>::new().read_ply(&mut f).unwrap();
    let vdef = &ply.header.elements["vertex"];
    let props: Vec<&str> = vdef.properties.keys().map(|k| k.as_str()).collect();
    assert_eq!(props[props.len() - 2..], ["accumulation", "agreeing_views"], "{props:?}");
    assert_eq!(props[props.len() - 3], "refl_840", "{props:?}");
    for n in ["accumulation", "agreeing_views"] {
        assert_eq!(vdef.properties[n].data_type, PropertyType::Scalar(ScalarType::Float), "{n}");
    }
    assert!(ply.header.comments.iter().any(|c| c == "attribute accumulation ray opacity"), "{:?}", ply.header.comments);
    for (i, v) in ply.payload["vertex"].iter().enumerate() {
        for a in &cloud.attributes {
            match v[&a.name] {
                Property::Float(x) => assert_eq!(x.to_bits(), a.values[i].to_bits(), "{} point {i}", a.name),
                ref p => panic!("unexpected {p:?}"),
            }
        }
    }

    // Our reader: attributes back with their names, order, descriptions and exact values; bands untouched.
    let back = read_ply(&path).unwrap();
    assert_same_attributes(&back.attributes, &cloud.attributes);
    assert_eq!(back.bands.len(), 6);
    assert_eq!(back.values, cloud.values);
    assert_eq!(back.normals, cloud.normals);

    // The same cloud as ascii PLY (the reader's other path), written here with the same header.
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = String::from_utf8(bytes[..end].to_vec()).unwrap();
    let header = header.replace("format binary_little_endian 1.0", "format ascii 1.0");
    let rgb = cloud.display_rgb(Default::default());
    let mut text = header;
    for (i, (p, c)) in cloud.positions.iter().zip(&rgb).enumerate() {
        let mut row: Vec<String> = p.iter().map(|v| format!("{v:?}")).collect();
        row.extend(cloud.normals.as_ref().unwrap()[i].iter().map(|v| format!("{v:?}")));
        row.extend(c.iter().map(|v| v.to_string()));
        row.extend(cloud.point_values(i).iter().map(|v| format!("{v:?}")));
        row.extend(cloud.attributes.iter().map(|a| format!("{:?}", a.values[i])));
        text += &row.join(" ");
        text += "\n";
    }
    let ascii = dir.join("attr_ascii.ply");
    std::fs::write(&ascii, text).unwrap();
    let back = read_ply(&ascii).unwrap();
    assert_same_attributes(&back.attributes, &cloud.attributes);
    assert_eq!(back.positions, cloud.positions);
    assert_eq!(back.values, cloud.values);

    // Attributes without bands: the attribute comments alone mark the file as msnerf's.
    let mut bare = PointCloud::new(cloud.positions.clone(), vec![], vec![]).unwrap();
    bare.add_attribute("refl_like", "", (0..bare.len()).map(|i| i as f32).collect()).unwrap();
    write_ply(&path, &bare, &PlyOptions::default()).unwrap();
    let back = read_ply(&path).unwrap();
    assert!(back.bands.is_empty());
    assert_same_attributes(&back.attributes, &bare.attributes);
}

#[test]
fn las_attributes_are_f32_extra_bytes_and_read_back() {
    let dir = scratch("las_attr");
    let cloud = cloud_with_attributes(250, 23);
    let path = dir.join("attr.las");
    write_las(&path, &cloud, &LasOptions::default()).unwrap();

    // The las crate's view: band extras (RE1, RE2), normals, then the attributes, 7 x f32 per point.
    let mut r = las::Reader::from_path(&path).unwrap();
    let h = r.header().clone();
    assert_eq!(h.point_format().extra_bytes, 28);
    let vlr = h.all_vlrs().find(|v| v.user_id == "LASF_Spec" && v.record_id == 4).unwrap();
    let ds: Vec<ExtraBytesDescriptor> = vlr.data.chunks_exact(192).map(ExtraBytesDescriptor::unpack).collect();
    let names: Vec<&str> = ds.iter().map(|d| d.name.as_str()).collect();
    assert_eq!(names, ["refl_720", "refl_750", "NormalX", "NormalY", "NormalZ", "accumulation", "agreeing_views"]);
    assert_eq!(vlr.data[5 * 192 + 2], 9, "data_type float");
    assert_eq!(ds[5].description, "ray opacity");
    // The descriptor holds 31 bytes of a long description (the msnerf VLR keeps all of it).
    assert_eq!(ds[6].description, &"training views whose depth agrees with the point"[..31]);
    let data = r.read_all().unwrap();
    for (i, p) in data.points().enumerate() {
        let p = p.unwrap();
        for (k, a) in cloud.attributes.iter().enumerate() {
            let at = 20 + 4 * k;
            let v = f32::from_le_bytes(p.extra_bytes[at..at + 4].try_into().unwrap());
            assert_eq!(v.to_bits(), a.values[i].to_bits(), "{} point {i}", a.name);
        }
    }

    // Our reader: names, order, full descriptions and exact values; bands and normals are not attributes.
    let back = read_las(&path).unwrap();
    assert_same_attributes(&back.attributes, &cloud.attributes);
    assert_eq!(back.bands.len(), 6);
    assert_eq!(back.normals, cloud.normals);

    // All bands as Extra Bytes: still exactly the two attributes.
    let opts = LasOptions { all_bands_as_extra_bytes: true, ..Default::default() };
    write_las(&path, &cloud, &opts).unwrap();
    let back = read_las(&path).unwrap();
    assert_same_attributes(&back.attributes, &cloud.attributes);
    assert_eq!(back.values, cloud.values);
}

#[test]
fn foreign_las_extra_bytes_are_attributes_unless_named_like_bands() {
    // A LAS written by another tool: no msnerf VLR; a `refl_800` float, a scaled u16 `Amplitude`, a float
    // `pulse width` (not a valid attribute name) and undocumented bytes.
    let dir = scratch("las_foreign");
    let path = dir.join("foreign.las");
    let mut b = las::Builder::from((1, 4));
    let mut format = las::point::Format::new(6).unwrap();
    format.extra_bytes = 4 + 2 + 4 + 3;
    b.point_format = format;
    let mut amp = ExtraBytesDescriptor::f32("Amplitude", "dB");
    (amp.data_type, amp.options, amp.scale) = (3, 8, 0.5);
    let mut undocumented = ExtraBytesDescriptor::f32("", "");
    (undocumented.data_type, undocumented.options) = (0, 3);
    let data =
        [ExtraBytesDescriptor::f32("refl_800", ""), amp, ExtraBytesDescriptor::f32("pulse width", "ns"), undocumented]
            .iter()
            .flat_map(|d| d.pack())
            .collect();
    b.vlrs.push(las::Vlr { user_id: "LASF_Spec".into(), record_id: 4, description: "Extra Bytes".into(), data });
    let mut w = las::Writer::from_path(&path, b.into_header().unwrap()).unwrap();
    for i in 0..5u16 {
        let mut eb = Vec::new();
        eb.extend_from_slice(&(0.1f32 * i as f32).to_le_bytes());
        eb.extend_from_slice(&(i * 3).to_le_bytes());
        eb.extend_from_slice(&(2.5f32 + i as f32).to_le_bytes());
        eb.extend_from_slice(&[7, 7, 7]);
        let p = las::Point { x: i as f64, y: 0.0, z: 0.0, gps_time: Some(0.0), extra_bytes: eb, ..Default::default() };
        w.write_point(p).unwrap();
    }
    w.close().unwrap();
    drop(w);

    let c = read_las(&path).unwrap();
    assert_eq!(c.bands.len(), 1);
    assert_eq!(c.bands[0].center_nm, Some(800.0));
    assert_eq!(c.point_values(3), &[0.3f32]);
    let names: Vec<&str> = c.attributes.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(names, ["Amplitude", "pulse_width"]);
    assert_eq!(c.attributes[0].values, [0.0, 1.5, 3.0, 4.5, 6.0], "scale applied");
    assert_eq!(c.attributes[0].description, "dB");
    assert_eq!(c.attributes[1].values, [2.5, 3.5, 4.5, 5.5, 6.5]);
}

#[test]
fn attribute_validation_names_the_attribute() {
    let mut c = PointCloud::new(
        vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]],
        ms600pro_bands(),
        vec![0.5; 24],
    )
    .unwrap();
    c.add_attribute("accumulation", "ray opacity", vec![1.0; 4]).unwrap();
    let err = |c: &mut PointCloud, name: &str, desc: &str, n: usize| {
        let before = c.attributes.clone();
        let e = c.add_attribute(name, desc, vec![0.0; n]).unwrap_err().to_string();
        assert_eq!(c.attributes, before, "a failed add_attribute leaves the cloud unchanged");
        e
    };
    let e = err(&mut c, "depth_spread", "", 3);
    assert!(e.contains("`depth_spread`") && e.contains("3 values for 4 points"), "{e}");
    let e = err(&mut c, "depth-spread", "", 4);
    assert!(e.contains("`depth-spread`") && e.contains("'-'"), "{e}");
    let e = err(&mut c, "", "", 4);
    assert!(e.contains("attribute 1") && e.contains("empty"), "{e}");
    let e = err(&mut c, "accumulation", "", 4);
    assert!(e.contains("`accumulation`") && e.contains("duplicate"), "{e}");
    let e = err(&mut c, "Accumulation", "", 4);
    assert!(e.contains("`Accumulation`") && e.contains("duplicate"), "{e}");
    for reserved in ["x", "Z", "nx", "red", "blue", "NormalY", "alpha"] {
        let e = err(&mut c, reserved, "", 4);
        assert!(e.contains(&format!("`{reserved}`")) && e.contains("reserved"), "{e}");
    }
    let e = err(&mut c, "refl_720", "", 4);
    assert!(e.contains("`refl_720`") && e.contains("band property"), "{e}");
    let long = "a".repeat(32);
    let e = err(&mut c, &long, "", 4);
    assert!(e.contains(&long) && e.contains("32 bytes"), "{e}");
    let e = err(&mut c, "views", "two\nlines", 4);
    assert!(e.contains("`views`") && e.contains("line break"), "{e}");
    c.add_attribute("a".repeat(31), "longest name", vec![2.0; 4]).unwrap();
    c.add_attribute("views_2", "digits and underscores", vec![3.0; 4]).unwrap();
    assert_eq!(c.attribute("views_2").unwrap().values, [3.0; 4]);
    assert!(c.attribute("missing").is_none());

    // A hand-built inconsistent cloud: validate() and both writers refuse it, naming the attribute.
    let mut bad = c.clone();
    bad.attributes[0].values.pop();
    let e = bad.validate().unwrap_err().to_string();
    assert!(e.contains("`accumulation`") && e.contains("3 values for 4 points"), "{e}");
    let dir = scratch("attr_invalid");
    let e = write_ply(&dir.join("bad.ply"), &bad, &PlyOptions::default()).unwrap_err().to_string();
    assert!(e.contains("`accumulation`"), "{e}");
    let e = write_las(&dir.join("bad.las"), &bad, &LasOptions::default()).unwrap_err().to_string();
    assert!(e.contains("`accumulation`"), "{e}");
    let mut dup = c.clone();
    dup.attributes.push(dup.attributes[1].clone());
    let e = dup.validate().unwrap_err().to_string();
    assert!(e.contains("duplicate") && e.contains(&format!("`{}`", c.attributes[1].name)), "{e}");
    let e = subsample(&dup, 2, 1).unwrap_err().to_string();
    assert!(e.contains("duplicate"), "{e}");
}

#[test]
fn filters_keep_attributes_aligned_with_their_points() {
    // A 10x10x10 grid: point i sits at (i % 10, i / 10 % 10, i / 100), so a position gives back its index.
    let pos: Vec<[f64; 3]> = (0..1000).map(|i| [(i % 10) as f64, ((i / 10) % 10) as f64, (i / 100) as f64]).collect();
    let index_of = |p: &[f64; 3]| (p[0] + 10.0 * p[1] + 100.0 * p[2]) as usize;
    let mut c =
        PointCloud::new(pos.clone(), vec![band("b", None, None)], (0..1000).map(|i| i as f32).collect()).unwrap();
    c.add_attribute("index", "", (0..1000).map(|i| i as f32).collect()).unwrap();
    c.add_attribute("minus_index", "", (0..1000).map(|i| -(i as f32)).collect()).unwrap();
    let check = |what: &str, out: &PointCloud, kept: &[usize]| {
        out.validate().unwrap();
        assert_eq!(out.attributes.len(), 2, "{what}");
        assert_eq!(out.attributes[0].name, "index", "{what}");
        for (k, p) in out.positions.iter().enumerate() {
            let i = index_of(p);
            assert_eq!(kept[k], i, "{what}");
            assert_eq!(out.attributes[0].values[k], i as f32, "{what} point {k}");
            assert_eq!(out.attributes[1].values[k], -(i as f32), "{what} point {k}");
            assert_eq!(out.point_values(k), &[i as f32], "{what} point {k}");
        }
    };

    let (s, idx) = subsample(&c, 137, 7).unwrap();
    assert_eq!(s.len(), 137);
    check("subsample", &s, &idx);
    let (whole, idx) = subsample(&c, 5000, 7).unwrap();
    check("subsample (all)", &whole, &idx);

    let aabb = Aabb { min: [2.0, 3.0, 4.0], max: [5.0, 7.0, 6.0] };
    let (a, idx) = crop(&c, |p| aabb.contains(p)).unwrap();
    assert_eq!(a.len(), 4 * 5 * 3);
    check("aabb crop", &a, &idx);
    let obb = OrientedBox::from_rpy([4.5, 4.5, 4.5], [0.0, 0.0, FRAC_PI_2], [2.0, 6.0, 10.0]);
    let (o, idx) = crop(&c, |p| obb.contains(p)).unwrap();
    check("obb crop", &o, &idx);

    // Outlier removal on the grid plus two far points appended at the end.
    let mut far = pos.clone();
    far.extend_from_slice(&[[500.0, 0.0, 0.0], [0.0, -800.0, 0.0]]);
    let mut c2 = PointCloud::new(far, vec![], vec![]).unwrap();
    c2.add_attribute("index", "", (0..1002).map(|i| i as f32).collect()).unwrap();
    let (kept, idx) = remove_statistical_outliers(&c2, 6, 2.0).unwrap();
    assert!(!idx.contains(&1000) && !idx.contains(&1001), "outliers removed");
    assert_eq!(kept.attributes[0].values, idx.iter().map(|&i| i as f32).collect::<Vec<_>>());
    for (k, p) in kept.positions.iter().enumerate() {
        assert_eq!(kept.attributes[0].values[k], index_of(p) as f32);
    }
    // Chained: subsample of a crop still matches positions.
    let (sc, _) = subsample(&a, 10, 3).unwrap();
    for (k, p) in sc.positions.iter().enumerate() {
        assert_eq!(sc.attributes[0].values[k], index_of(p) as f32);
    }
}

/// `--gsd` thinning keeps one point per cube, the one with the most agreeing views, then the least spread; ties go
/// to the lowest index; clouds without those fields keep the first point of each cube.
#[test]
fn thinning_keeps_the_most_confident_point_of_each_cube() {
    use msnerf::output::pointcloud::thin::thin_to_grid;
    let positions = vec![
        [0.1, 0.1, 0.1],  // cube (0,0,0)
        [0.2, 0.3, 0.4],  // cube (0,0,0): more agreeing views
        [0.9, 0.9, 0.9],  // cube (0,0,0): as many, but more spread
        [1.5, 0.2, 0.2],  // cube (1,0,0)
        [-0.5, 0.0, 0.0], // cube (-1,0,0)
    ];
    let mut c = PointCloud::new(positions, vec![band("b", None, None)], vec![0.0; 5]).expect("cloud");
    let (plain, keep) = thin_to_grid(&c, 1.0, &["agreeing_views"], &["depth_spread"]).expect("thin");
    assert_eq!(keep, vec![0, 3, 4], "without confidence fields: the first point of each cube");
    assert_eq!(plain.len(), 3);
    c.add_attribute("agreeing_views", "", vec![2.0, 5.0, 5.0, 3.0, 2.0]).expect("attr");
    c.add_attribute("depth_spread", "", vec![0.1, 0.4, 0.9, 0.1, 0.1]).expect("attr");
    let (t, keep) = thin_to_grid(&c, 1.0, &["agreeing_views"], &["depth_spread"]).expect("thin");
    assert_eq!(keep, vec![1, 3, 4]);
    assert_eq!(t.attribute("agreeing_views").expect("kept").values, vec![5.0, 3.0, 2.0]);
    assert!(thin_to_grid(&c, 0.0, &[], &[]).is_err(), "a zero cell is refused");
}

/// Bad `export pointcloud` flags are refused before anything is loaded, naming the flag.
#[test]
fn export_flags_are_checked_and_named() {
    let dir = scratch("export_flags");
    let out = dir.join("c.ply");
    for (flags, name) in [
        (&["--min-agree", "9"][..], "--min-agree"),
        (&["--agree-tolerance", "0"][..], "--agree-tolerance"),
        (&["--max-spread-cells=-1"][..], "--max-spread-cells"),
        (&["--gsd", "0"][..], "--gsd"),
        (&["--rays", "0"][..], "--rays"),
    ] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf"))
            .args(["export", "pointcloud", "/nonexistent-run", "--out", out.to_str().expect("utf-8")])
            .args(flags)
            .output()
            .expect("run msnerf");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(name), "{flags:?}: {err}");
        assert!(!out.exists(), "nothing written");
    }
}

/// A LAS header whose point count the file cannot hold (a damaged or truncated file): refused by name before
/// anything is allocated for it (before, 3 billion points asked for a 300 GB buffer and the process aborted).
#[test]
fn las_with_a_point_count_beyond_its_size_is_refused() {
    let dir = scratch("las-count");
    let path = dir.join("cloud.las");
    write_las(&path, &utm_cloud(50, 3), &LasOptions::default()).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    // LAS 1.4 counts points twice: the legacy 32-bit field at byte 107 and the 64-bit one at byte 247.
    assert_eq!(u64::from_le_bytes(bytes[247..255].try_into().unwrap()), 50, "the field this test patches");
    bytes[107..111].copy_from_slice(&u32::MAX.to_le_bytes());
    bytes[247..255].copy_from_slice(&u64::from(u32::MAX).to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let e = read_las(&path).unwrap_err().to_string();
    assert!(e.contains("cloud.las") && e.contains("4294967295 points") && e.contains("more than the file"), "{e}");
}
