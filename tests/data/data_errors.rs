//! Every bad input of dataset.md gets an error naming the file and the key or frame; nothing panics and the
//! user's files are not modified.

use crate::data_support;
use data_support::*;
use msnerf::data::{check_dataset, load_dataset, DataError, LoadOptions};
use serde_json::json;

/// A valid 3-frame, 2-band u16 dataset; `edit` changes the JSON before it is written.
fn dataset(edit: impl FnOnce(&mut serde_json::Value)) -> TempDir {
    let td = TempDir::new("err");
    for n in ["a", "b", "c"] {
        std::fs::write(td.path().join(format!("{n}.tif")), tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::U16))).unwrap();
    }
    write_transforms(
        td.path(),
        8,
        6,
        json!({"bands": bands_json(2)}),
        vec![frame("a.tif", 0.0, "train"), frame("b.tif", 1.0, "train"), frame("c.tif", 2.0, "eval")],
    );
    let p = td.path().join("transforms.json");
    let mut j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    edit(&mut j);
    std::fs::write(&p, j.to_string()).unwrap();
    td
}

fn load_err(td: &TempDir) -> DataError {
    load_dataset(td.path(), &LoadOptions::default()).expect_err("should fail")
}

fn assert_names(e: &DataError, parts: &[&str]) {
    let s = e.to_string();
    for p in parts {
        assert!(s.contains(p), "error `{s}` does not name `{p}`");
    }
}

#[test]
fn valid_dataset_loads_and_checks_ok() {
    let td = dataset(|_| {});
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 3);
    let rep = check_dataset(td.path(), 1 << 20);
    assert!(rep.is_ok(), "{rep}");
    assert_eq!((rep.train, rep.eval), (2, 1));
    assert_eq!(rep.full_load_bytes, 3 * 8 * 6 * 2 * 2);
    assert_eq!(rep.bands[0].max, Some((tiff_max(0) / 65535.0) as f32));
    assert!(rep.to_json().contains("\"n_resident\": 2"));
}

fn tiff_max(b: usize) -> f64 {
    (0..6).flat_map(|r| (0..8).map(move |c| value(Kind::U16, b, r, c))).fold(0.0, f64::max)
}

#[test]
fn missing_image_file() {
    let td = dataset(|_| {});
    std::fs::remove_file(td.path().join("b.tif")).unwrap();
    let e = load_err(&td);
    assert!(matches!(e, DataError::MissingFile { .. }));
    assert_names(&e, &["b.tif", "file_path", "frame 1"]);
}

#[test]
fn unreadable_image_file() {
    let td = dataset(|_| {});
    std::fs::write(td.path().join("c.tif"), b"II*\0garbage").unwrap();
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    let e = ds.read_frame(2).unwrap_err();
    assert!(matches!(e, DataError::Decode { .. }));
    assert_names(&e, &["c.tif", "frame 2"]);
}

#[test]
fn invalid_json() {
    let td = dataset(|_| {});
    std::fs::write(td.path().join("transforms.json"), "{\"frames\": [").unwrap();
    let e = load_err(&td);
    assert!(matches!(e, DataError::Json { .. }));
    assert_names(&e, &["transforms.json"]);
}

#[test]
fn band_count_mismatch() {
    let td = dataset(|j| j["bands"] = bands_json(3));
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    let e = ds.read_frame(0).unwrap_err();
    assert!(matches!(e, DataError::BandCount { expected: 3, found: 2, .. }), "{e}");
    assert_names(&e, &["a.tif", "file_path", "frame 0"]);
}

#[test]
fn image_size_mismatch() {
    let td = dataset(|j| j["w"] = json!(9));
    let e = load_err(&td);
    assert!(matches!(e, DataError::ImageSize { .. }), "{e}");
    assert_names(&e, &["a.tif", "9x6", "8x6"]);
}

#[test]
fn nan_pixels_are_counted() {
    let td = dataset(|j| j["frames"][1]["file_path"] = json!("f.tif"));
    let mut bytes = tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::F32));
    bytes[8..12].copy_from_slice(&f32::NAN.to_le_bytes());
    bytes[12..16].copy_from_slice(&f32::INFINITY.to_le_bytes());
    std::fs::write(td.path().join("f.tif"), bytes).unwrap();
    std::fs::write(td.path().join("a.tif"), tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::F32))).unwrap();
    std::fs::write(td.path().join("c.tif"), tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::F32))).unwrap();
    let rep = check_dataset(td.path(), 1 << 20);
    assert!(!rep.is_ok());
    assert!(matches!(rep.problems[0], DataError::NonFinite { count: 2, .. }), "{rep}");
    assert_names(&rep.problems[0], &["f.tif", "frame 1", "2 NaN/Inf"]);
}

#[test]
fn rotation_not_orthonormal() {
    let td = dataset(|j| j["frames"][2]["transform_matrix"][0][0] = json!(1.5));
    let e = load_err(&td);
    assert!(matches!(e, DataError::NotOrthonormal { .. }), "{e}");
    assert_names(&e, &["transforms.json", "transform_matrix", "frame 2 (c.tif)"]);
}

#[test]
fn non_positive_focal_length() {
    let td = dataset(|j| j["frames"][1]["fl_y"] = json!(-3.0));
    let e = load_err(&td);
    assert!(matches!(e, DataError::NonPositiveFocal { .. }), "{e}");
    assert_names(&e, &["transforms.json", "fl_y", "frame 1 (b.tif)"]);
}

#[test]
fn empty_train_split() {
    let td = dataset(|j| {
        for f in j["frames"].as_array_mut().unwrap() {
            f["split"] = json!("eval");
        }
    });
    let e = load_err(&td);
    assert!(matches!(e, DataError::EmptyTrainSplit { .. }), "{e}");
    assert_names(&e, &["transforms.json", "split"]);
}

#[test]
fn duplicate_file_names() {
    let td = dataset(|j| j["frames"][2]["file_path"] = json!("./a.tif"));
    let e = load_err(&td);
    assert!(matches!(e, DataError::DuplicateFileName { .. }), "{e}");
    assert_names(&e, &["transforms.json", "file_path", "a.tif"]);
}

#[test]
fn missing_intrinsics_and_bands_key() {
    let td = dataset(|j| {
        j.as_object_mut().unwrap().remove("cx");
    });
    let e = load_err(&td);
    assert_names(&e, &["missing key `cx`", "frame 0"]);
    // 2-band images without `bands`.
    let td = dataset(|j| {
        j.as_object_mut().unwrap().remove("bands");
    });
    let e = load_err(&td);
    assert!(matches!(e, DataError::MissingKey { .. }), "{e}");
    assert_names(&e, &["`bands`", "2 channels"]);
}

#[test]
fn all_errors_are_collected_and_unknown_keys_ignored() {
    let td = dataset(|j| {
        j["frames"][0]["fl_x"] = json!(0.0);
        j["frames"][1]["transform_matrix"][1][1] = json!(2.0);
        j["some_future_key"] = json!({"x": 1});
        j["frames"][2]["colmap_im_id"] = json!(3);
    });
    let before = std::fs::read(td.path().join("transforms.json")).unwrap();
    let e = load_err(&td);
    let all = e.flatten();
    assert_eq!(all.len(), 2, "{all:?}");
    let rep = check_dataset(td.path(), 1 << 20);
    assert_eq!(rep.errors.len(), 2);
    // Nothing was modified.
    assert_eq!(std::fs::read(td.path().join("transforms.json")).unwrap(), before);
}

#[test]
fn splits_three_ways() {
    // Explicit lists win over per-frame keys.
    let td = dataset(|j| {
        j["train_filenames"] = json!(["a.tif", "c.tif"]);
        j["val_filenames"] = json!(["b.tif"]);
    });
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    use msnerf::data::Split::*;
    let s: Vec<_> = ds.frames.iter().map(|f| f.split).collect();
    assert_eq!(s, [Train, Eval, Train]);
    // Every 8th frame (sorted by name) when nothing else says.
    let td = TempDir::new("interval");
    let mut frames = vec![];
    for i in 0..10 {
        let n = format!("img{:02}.tif", 9 - i);
        std::fs::write(td.path().join(&n), tiff_bytes(&TiffSpec::new(4, 4, 3, Kind::U8))).unwrap();
        let mut f = frame(&n, i as f64, "");
        f.as_object_mut().unwrap().remove("split");
        frames.push(f);
    }
    write_transforms(td.path(), 4, 4, json!({}), frames);
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames[0].name, "img00.tif");
    let eval: Vec<usize> = ds.split_indices(Eval);
    assert_eq!(eval, [0, 8]);
}

/// `rig_cameras` (per-band cameras of a rig): read back in band order, and every bad entry named by its key.
#[test]
fn rig_cameras_are_read_and_bad_ones_named() {
    let id = |x: f64| json!([[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
    let cam = |band: &str, x: f64| json!({"band": band, "fl_x": 9.0, "cx": 4.0, "cy": 3.0, "rig_from_band": id(x)});
    let names: Vec<String> =
        bands_json(2).as_array().unwrap().iter().map(|b| b["name"].as_str().unwrap().to_string()).collect();
    let (b0, b1) = (names[0].clone(), names[1].clone());
    // Listed out of band order: the dataset keeps file band order.
    let td = dataset(|j| j["rig_cameras"] = json!({"cameras": [cam(&b1, 0.04), cam(&b0, 0.0)]}));
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    let rig = ds.rig.as_ref().expect("rig read");
    assert_eq!((rig.cameras[0].rig_from_band[0][3], rig.cameras[1].rig_from_band[0][3]), (0.0, 0.04));
    assert_eq!(
        (rig.cameras[1].camera.fy, rig.cameras[1].camera.width),
        (9.0, 8),
        "fl_y defaults to fl_x, w to the images'"
    );
    let cases: Vec<(serde_json::Value, &[&str])> = vec![
        (json!({"cameras": [cam(&b0, 0.0)]}), &["rig_cameras.cameras", "has no camera"]),
        (json!({"cameras": [cam(&b0, 0.0), cam("thermal", 0.0)]}), &["rig_cameras.cameras[1].band", "thermal"]),
        (json!({"cameras": [cam(&b0, 0.0), cam(&b0, 0.1)]}), &["rig_cameras.cameras[1].band", "two cameras"]),
        (
            json!({"cameras": [cam(&b0, 0.0), {"band": b1, "fl_x": -2.0, "cx": 4.0, "cy": 3.0, "rig_from_band": id(0.0)}]}),
            &["rig_cameras.cameras[1].fl_x", "positive"],
        ),
        (
            json!({"cameras": [cam(&b0, 0.0), {"band": b1, "fl_x": 9.0, "cx": 4.0, "cy": 3.0,
            "rig_from_band": [[2.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]}]}),
            &["rig_cameras.cameras[1].rig_from_band", "orthonormal"],
        ),
        (
            json!({"cameras": [cam(&b0, 0.0), {"band": b1, "fl_x": 9.0, "cy": 3.0}]}),
            &["rig_cameras.cameras[1].cx", "rig_cameras.cameras[1].rig_from_band"],
        ),
        (json!({"cameras": []}), &["rig_cameras.cameras", "empty"]),
        (json!([1, 2]), &["rig_cameras", "expected an object"]),
    ];
    for (rig, parts) in cases {
        let td = dataset(|j| j["rig_cameras"] = rig.clone());
        let e = load_err(&td);
        assert_names(&e, &["transforms.json"]);
        assert_names(&e, parts);
    }
}
