//! The streamed Cloud-Optimized GeoTIFF writer (`output::raster::cog`), checked by GDAL: its COG validator with the
//! full check (layout, leaders, trailers), `gdalinfo` (size, overviews, grid, CRS, nodata, band descriptions) and
//! `gdallocationinfo` for pixel values at full resolution and in the overviews, against values computed here.

use crate::common;
use crate::geo_support;
use msnerf::output::image::band;
use msnerf::output::raster::cog::{CogOptions, CogWriter, TILE};
use msnerf::output::raster::{GeoReference, GeoTiffOptions};

const NODATA: f64 = -9999.0;

/// A smooth, position-coded test value of band `b` at (x, y); nodata in a block.
fn value(x: usize, y: usize, b: usize) -> f32 {
    if (300..340).contains(&x) && (100..180).contains(&y) {
        return NODATA as f32;
    }
    (x as f32) * 0.5 + (y as f32) * 0.25 + b as f32 * 1000.0
}

fn write(
    path: &std::path::Path,
    w: usize,
    h: usize,
    rows_per_push: usize,
) -> Option<msnerf::output::raster::cog::CogPreview> {
    let bands =
        vec![band("Red", Some(660.0), Some(22.0)), band("RedEdge", Some(720.0), None), band("NIR", Some(840.0), None)];
    let opts = CogOptions {
        geotiff: GeoTiffOptions {
            nodata: Some(NODATA),
            georef: Some(GeoReference {
                origin: [500_000.0, 4_400_000.0],
                pixel_size: [0.25, 0.25],
                epsg: Some(32650),
            }),
            metadata: vec![("product".into(), "test".into())],
            ..Default::default()
        },
        preview_max: 256,
    };
    let mut cog = CogWriter::create(path, w, h, bands, &opts).expect("create");
    let mut y = 0;
    while y < h {
        let n = rows_per_push.min(h - y);
        let rows: Vec<f32> =
            (y..y + n).flat_map(|yy| (0..w).flat_map(move |x| (0..3).map(move |b| value(x, yy, b)))).collect();
        cog.push_rows(&rows).expect("push");
        y += n;
    }
    cog.finish().expect("finish")
}

/// The 2^k x 2^k block mean of band b at overview pixel (x, y), nodata skipped (GDAL's AVERAGE, level by level).
fn overview_value(w: usize, h: usize, k: usize, x: usize, y: usize, b: usize) -> f64 {
    if k == 0 {
        let v = value(x, y, b) as f64;
        return v;
    }
    // Level k pixel = mean of the valid level k-1 pixels under it.
    let (wp, hp) = (0..k - 1).fold((w, h), |(a, c), _| (a.div_ceil(2), c.div_ceil(2)));
    let (mut s, mut n) = (0.0, 0);
    for (xx, yy) in [(2 * x, 2 * y), (2 * x + 1, 2 * y), (2 * x, 2 * y + 1), (2 * x + 1, 2 * y + 1)] {
        if xx < wp && yy < hp {
            let v = overview_value(w, h, k - 1, xx, yy, b);
            if v != NODATA {
                s += v;
                n += 1;
            }
        }
    }
    if n == 0 {
        NODATA
    } else {
        s / n as f64
    }
}

#[test]
fn a_streamed_cog_is_valid_and_gdal_reads_its_pixels_and_overviews() {
    let dir = common::TempDir::new("cog");
    let path = dir.path().join("raster.tif");
    // 700 x 601: two partial tile columns and rows at full resolution, odd sizes down the overviews.
    let (w, h) = (700, 601);
    let preview = write(&path, w, h, 37).expect("a preview level");
    geo_support::validate_cog(&path);
    let info = geo_support::gdalinfo_json(&path);
    assert_eq!(info["size"], serde_json::json!([w, h]));
    assert_eq!(info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"], "COG", "{}", info["metadata"]);
    assert_eq!(info["geoTransform"], serde_json::json!([500000.0, 0.25, 0.0, 4400000.0, 0.0, -0.25]));
    assert!(info["coordinateSystem"]["wkt"].as_str().unwrap().contains("UTM zone 50N"));
    let b0 = &info["bands"][0];
    assert_eq!(b0["noDataValue"], serde_json::json!(NODATA));
    assert_eq!(b0["description"], "Red 660nm", "{b0}");
    assert_eq!(b0["block"], serde_json::json!([TILE, TILE]));
    // Overviews 350x301, 175x151 (the last one fits a tile).
    let ovr: Vec<serde_json::Value> = b0["overviews"].as_array().expect("overviews").clone();
    let sizes: Vec<serde_json::Value> = ovr.iter().map(|o| o["size"].clone()).collect();
    assert_eq!(sizes, vec![serde_json::json!([350, 301]), serde_json::json!([175, 151])]);
    // Pixels: corners, the partial edge tiles, the nodata block, and overview pixels against the block means.
    for (x, y) in [(0, 0), (699, 600), (255, 255), (256, 256), (511, 600), (310, 120), (699, 0)] {
        let got = geo_support::gdallocationinfo(&path, None, x, y);
        let want: Vec<f64> = (0..3).map(|b| value(x, y, b) as f64).collect();
        assert_eq!(got, want, "pixel ({x}, {y})");
    }
    for (k, x, y) in [(1, 0, 0), (1, 349, 300), (1, 155, 60), (1, 150, 50), (2, 174, 150), (2, 77, 30), (2, 10, 100)] {
        let got = geo_support::gdallocationinfo(&path, Some(k - 1), x, y);
        for (b, g) in got.iter().enumerate() {
            let want = overview_value(w, h, k, x, y, b);
            assert!((g - want).abs() <= 1e-3 * want.abs().max(1.0), "overview {k} ({x}, {y}) band {b}: {g} vs {want}");
        }
    }
    // The preview is the first level that fits 256: overview 2.
    assert_eq!((preview.factor, preview.image.width, preview.image.height), (4, 175, 151));
    let n = 175 * 151;
    assert!((preview.image.data[n + 30 * 175 + 77] as f64 - overview_value(w, h, 2, 77, 30, 1)).abs() < 1e-3);
}

#[test]
fn a_single_tile_cog_has_no_overviews_and_unfinished_writes_leave_nothing() {
    let dir = common::TempDir::new("cog");
    let path = dir.path().join("small.tif");
    write(&path, 200, 90, 90).expect("preview");
    geo_support::validate_cog(&path);
    let info = geo_support::gdalinfo_json(&path);
    assert!(info["bands"][0]["overviews"].as_array().is_none_or(|o| o.is_empty()));
    assert_eq!(
        geo_support::gdallocationinfo(&path, None, 199, 89),
        vec![199.0 * 0.5 + 89.0 * 0.25, 1000.0 + 99.5 + 22.25, 2121.75]
    );

    // Too few rows: finish names the shortfall and nothing is left behind.
    let partial = dir.path().join("partial.tif");
    let opts = CogOptions { geotiff: GeoTiffOptions { nodata: Some(NODATA), ..Default::default() }, preview_max: 0 };
    let mut cog = CogWriter::create(&partial, 10, 10, vec![band("h", None, None)], &opts).expect("create");
    cog.push_rows(&[0.0; 30]).expect("three rows");
    let err = cog.finish().err().expect("short raster refused").to_string();
    assert!(err.contains("only 3 of 10 rows"), "{err}");
    // Too many rows and ragged rows are refused by name.
    let mut cog = CogWriter::create(&partial, 10, 2, vec![band("h", None, None)], &opts).expect("create");
    assert!(cog.push_rows(&[0.0; 15]).is_err());
    assert!(cog.push_rows(&[0.0; 30]).expect_err("3 rows into 2").to_string().contains("3 rows pushed"));
    drop(cog);
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 1, "only small.tif: {left:?}");
    // No nodata: refused (the padding needs one).
    let err = CogWriter::create(
        &partial,
        10,
        2,
        vec![band("h", None, None)],
        &CogOptions { geotiff: GeoTiffOptions::default(), preview_max: 0 },
    );
    assert!(err.err().expect("no nodata").to_string().contains("nodata"));
}
