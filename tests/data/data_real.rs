//! Real sensor files from tests/fixtures/real: MicaSense RedEdge rig TIFFs (XMP bands, black level) and a
//! 5-band float GeoTIFF.

use crate::rig_support;
use msnerf::data::reader::read_image_file;
use msnerf::data::{load_dataset, LoadOptions, SampleType};
use rig_support::real_dir;

#[test]
fn micasense_band_files_have_xmp_bands_and_black_level() {
    let dir = real_dir();
    let m = dir.join("micasense-rededge");
    let expect = [
        ("Blue", 475.0, 20.0),
        ("Green", 560.0, 20.0),
        ("Red", 668.0, 10.0),
        ("NIR", 840.0, 40.0),
        ("Red edge", 717.0, 10.0),
    ];
    for (i, (name, c, w)) in expect.iter().enumerate() {
        let path = m.join(format!("0000SET_IMG_0001_{}.tif", i + 1));
        let d = read_image_file(&path, 1 << 30).unwrap();
        let x = d.meta.xmp.clone().unwrap();
        assert_eq!(x.name.as_deref(), Some(*name));
        assert_eq!(x.center_nm, Some(*c));
        assert_eq!(x.fwhm_nm, Some(*w));
        assert_eq!(d.meta.black_level, Some(4800.0));
        let r = &d.raster;
        assert_eq!((r.width, r.height, r.bands), (1280, 960, 1));
        assert_eq!(r.sample_type(), SampleType::U16);
        // 12-bit DN shifted by 4: every value is a multiple of 16 and at most 65520.
        let mut max = 0.0f64;
        for p in 0..(1280 * 960) {
            let v = r.samples.raw(p);
            assert_eq!(v % 16.0, 0.0);
            max = max.max(v);
        }
        assert!(max <= 65520.0 && max > 4800.0);
    }
}

#[test]
fn micasense_capture_loads_as_a_dataset_with_bands_from_xmp() {
    let dir = real_dir();
    let m = dir.join("micasense-rededge");
    let tmp = std::env::temp_dir().join(format!("msnerf_data_real_{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    // Band files in suffix order (not wavelength order); two captures as two frames.
    let frame = |cap: u32, x: f64| {
        let files: Vec<String> =
            (1..=5).map(|b| m.join(format!("0000SET_IMG_000{cap}_{b}.tif")).display().to_string()).collect();
        serde_json::json!({"band_files": files, "split": "train",
            "transform_matrix": [[1,0,0,x],[0,1,0,0],[0,0,1,0],[0,0,0,1]]})
    };
    let j = serde_json::json!({"fl_x": 1449.36, "fl_y": 1449.36, "cx": 640, "cy": 480,
        "w": 1280, "h": 960, "frames": [frame(0, 0.0), frame(1, 1.0)]});
    std::fs::write(tmp.join("transforms.json"), j.to_string()).unwrap();
    let ds = load_dataset(&tmp, &LoadOptions::default()).unwrap();
    let names: Vec<&str> = ds.bands.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(names, ["Blue", "Green", "Red", "NIR", "Red edge"]);
    assert_eq!(ds.bands[3].center_nm, Some(840.0));
    assert_eq!(ds.bands[4].fwhm_nm, Some(10.0));
    let r = ds.read_frame(1).unwrap();
    assert_eq!(r.bands, 5);
    assert_eq!(r.scaling[0].black, 4800.0);
    assert_eq!(r.scaling[0].scale, 65535.0);
    let raw = r.raw(100, 200, 3);
    assert_eq!(r.get(100, 200, 3), ((raw - 4800.0) / 65535.0) as f32);
    std::fs::remove_dir_all(&tmp).unwrap();
}

#[test]
fn geotiff_five_band_float_loads() {
    let dir = real_dir();
    let d = read_image_file(&dir.join("plantcv-geospatial/615.tif"), 1 << 30).unwrap();
    let r = &d.raster;
    assert_eq!((r.width, r.height, r.bands), (161, 177, 5));
    assert_eq!(r.sample_type(), SampleType::F32);
    let mut valid = 0usize;
    for p in 0..r.samples.len() {
        let v = r.samples.raw(p);
        assert!(v.is_finite());
        if v != -10000.0 {
            valid += 1;
            assert!((-1.0..=2.0).contains(&v), "reflectance out of range: {v}");
        }
    }
    // A crop of an orthomosaic edge: mostly nodata, but real reflectances inside.
    assert!(valid > 1000, "only {valid} valid samples");
}
