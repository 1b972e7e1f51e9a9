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

/// GDAL's float nodata value (-3.4e38) or a value that large: refused by name, with the count and the extreme, not
/// trained into a loss whose squares overflow (every step would be skipped).
#[test]
fn implausibly_large_float_pixels_are_refused() {
    let td = dataset(|j| j["frames"][1]["file_path"] = json!("f.tif"));
    let mut bytes = tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::F32));
    bytes[8..12].copy_from_slice(&f32::MIN.to_le_bytes());
    bytes[12..16].copy_from_slice(&2.0e6f32.to_le_bytes());
    bytes[16..20].copy_from_slice(&9.9e5f32.to_le_bytes()); // inside ±1e6: kept
    std::fs::write(td.path().join("f.tif"), bytes).unwrap();
    std::fs::write(td.path().join("a.tif"), tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::F32))).unwrap();
    std::fs::write(td.path().join("c.tif"), tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::F32))).unwrap();
    let rep = check_dataset(td.path(), 1 << 20);
    assert_eq!(rep.problems.len(), 1, "{rep}");
    assert!(matches!(rep.problems[0], DataError::OutOfRange { count: 2, .. }), "{rep}");
    assert_names(&rep.problems[0], &["f.tif", "frame 1", "2 pixel values beyond", "-3.40282346"]);
    // Asked to mask bad values, the loader masks these pixels instead.
    let opts = LoadOptions { mask_non_finite: true, ..Default::default() };
    let ds = load_dataset(td.path(), &opts).unwrap();
    let f = ds.frames.iter().position(|f| f.name == "f.tif").expect("f.tif");
    let r = ds.read_frame(f).unwrap();
    let mask = r.mask.as_ref().expect("mask");
    assert_eq!(mask.iter().filter(|&&m| m == 0).count(), 1, "the pixel holding both values is masked, no other");
    // A nodata pixel under the frame's own mask (`mask_path`, 0 = left out) is not checked: the dataset loads.
    let mut keep = vec![255u8; 8 * 6];
    keep[0] = 0;
    let file = std::fs::File::create(td.path().join("f_mask.tif")).unwrap();
    tiff::encoder::TiffEncoder::new(file).unwrap().write_image::<tiff::encoder::colortype::Gray8>(8, 6, &keep).unwrap();
    let tf = td.path().join("transforms.json");
    let mut j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&tf).unwrap()).unwrap();
    j["frames"][1]["mask_path"] = json!("f_mask.tif");
    std::fs::write(&tf, j.to_string()).unwrap();
    let rep = check_dataset(td.path(), 1 << 20);
    assert!(rep.is_ok(), "masked nodata is no problem: {rep}");
    let low = rep.bands[0].min.expect("band 0 range");
    assert!(low > -1e6, "the reported range leaves the masked nodata out: {low}");
}

/// Integer data whose scaling maps it beyond ±1e6 (a pixel_scale of 1e-300): the key is named, per band.
#[test]
fn degenerate_pixel_scale_is_refused() {
    for (edit, band) in [
        ((|j: &mut serde_json::Value| j["pixel_scale"] = json!(1e-300)) as fn(&mut serde_json::Value), "band 0"),
        (|j| j["bands"][1]["pixel_scale"] = json!(1e-3), "band 1"),
        (|j| j["black_level"] = json!(1e12), "band 0"),
    ] {
        let td = dataset(edit);
        let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
        let e = ds.read_frame(0).unwrap_err();
        assert!(matches!(e, DataError::InvalidValue { .. }), "{e}");
        assert_names(&e, &["transforms.json", "pixel_scale", "frame 0", band, "beyond ±1e6"]);
    }
    // 12-bit data scaled by 4095 stays well inside.
    let td = dataset(|j| j["pixel_scale"] = json!(4095.0));
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    ds.read_frame(0).expect("a plausible pixel_scale loads");
}

/// Positive but degenerate focal lengths (a field of view of almost 180° or 0°): refused naming the key and the
/// frame, for frames and for rig cameras.
#[test]
fn degenerate_focal_lengths_are_refused() {
    for (v, fov) in [(1e-300, "180.0000°"), (1e-3, "179.9"), (1e8, "0.0000°")] {
        let td = dataset(|j| j["frames"][2]["fl_x"] = json!(v));
        let e = load_err(&td);
        assert_names(&e, &["transforms.json", "fl_x", "frame 2 (c.tif)", "implausible", fov]);
    }
    // Just inside the bounds (8 px wide: 0.008 to 8e6 pixels) it loads.
    for v in [0.0081, 7.9e6] {
        let td = dataset(|j| j["frames"][2]["fl_x"] = json!(v));
        load_dataset(td.path(), &LoadOptions::default()).unwrap_or_else(|e| panic!("fl_x {v}: {e}"));
    }
    let rig = |fl: f64| {
        let id = json!([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
        let cams: Vec<serde_json::Value> = [100.0, fl]
            .iter()
            .enumerate()
            .map(|(b, f)| json!({"band": format!("b{b}"), "fl_x": f, "fl_y": 100.0, "cx": 4.0, "cy": 3.0, "rig_from_band": id}))
            .collect();
        json!({ "cameras": cams })
    };
    let td = dataset(|j| j["rig_cameras"] = rig(100.0));
    load_dataset(td.path(), &LoadOptions::default()).expect("a plausible rig loads");
    let td = dataset(|j| j["rig_cameras"] = rig(1e-300));
    let e = load_err(&td);
    assert_names(&e, &["transforms.json", "rig_cameras.cameras[1].fl_x", "implausible"]);
}

/// Every camera at one pose: normalisation would divide by zero (or by rounding noise), so training refuses the
/// dataset (`check_distinct_centres`, called by the trainer's loader); centres apart pass.
#[test]
fn coincident_camera_centres_are_refused() {
    let td = dataset(|j| {
        for f in j["frames"].as_array_mut().unwrap() {
            f["transform_matrix"][0][3] = json!(500000.25);
            f["transform_matrix"][1][3] = json!(4000000.5);
        }
    });
    // Tools that run before SfM still read it (a rig import without GPS writes such placeholder poses).
    let ds = load_dataset(td.path(), &LoadOptions::default()).expect("placeholder poses load");
    let e = ds.check_distinct_centres().unwrap_err();
    assert_names(&e, &["transforms.json", "transform_matrix", "all 3 cameras have one centre", "msnerf sfm"]);
    let td = dataset(|j| {
        for (i, f) in j["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
            f["transform_matrix"][0][3] = json!(500000.25 + i as f64 * 0.5);
            f["transform_matrix"][1][3] = json!(4000000.5);
        }
    });
    let ds = load_dataset(td.path(), &LoadOptions::default()).expect("dataset");
    ds.check_distinct_centres().expect("centres half a metre apart at UTM coordinates are distinct");
}

/// A run's `dataset.json` against the dataset its `data` path holds now: the same dataset passes; other band
/// names, another image size or other frames are refused naming the key (eval, render and export would otherwise
/// show the model's bands under the wrong names; `train --resume` would go on with another flight).
#[test]
fn a_run_refuses_a_dataset_that_is_not_its_own() {
    use msnerf::data::Split;
    use msnerf::nerf::run::check_run_dataset;
    let td = dataset(|_| {});
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    let info = json!({"data": td.path(), "bands": ds.bands, "width": ds.width, "height": ds.height,
        "train_frames": ds.split_indices(Split::Train), "eval_frames": ds.split_indices(Split::Eval)});
    let p = td.path().join("run/dataset.json");
    check_run_dataset(&p, &info, &ds).expect("its own dataset");
    type Edit = fn(&mut serde_json::Value);
    let cases: Vec<(Edit, &[&str])> = vec![
        (|i| i["bands"][1]["name"] = json!("nir"), &["dataset.json", "bands", "[b0, nir]", "[b0, b1]"]),
        (|i| i["bands"].as_array_mut().unwrap().truncate(1), &["bands", "[b0]"]),
        (|i| i["width"] = json!(16), &["width 16", "have 8"]),
        (|i| i["train_frames"] = json!([0]), &["train_frames", "1 frames", "2 now"]),
        (|i| i["eval_frames"] = json!([0, 2]), &["eval_frames"]),
    ];
    for (edit, parts) in cases {
        let mut i = info.clone();
        edit(&mut i);
        let e = check_run_dataset(&p, &i, &ds).unwrap_err().to_string();
        for part in parts {
            assert!(e.contains(part), "`{e}` does not name `{part}`");
        }
        assert!(e.contains("not the dataset of this run"), "{e}");
    }
}
