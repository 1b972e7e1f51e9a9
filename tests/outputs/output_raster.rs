//! Raster outputs read back by independent decoders: GeoTIFF through the `tiff` crate (values bit-exact, the
//! GDAL_METADATA XML, nodata, geo tags) and `gdalinfo -json`; EXR channels by name through `exr`; PNG pixels
//! through `png`. Plus vegetation indices, previews and the contact sheet.

use crate::output_support;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use msnerf::output::image::{band, ms600pro_bands};
use msnerf::output::raster::preview::{self, Rgb8, Stretch};
use msnerf::output::raster::{
    compute_index, contact_sheet, write_exr, write_geotiff, write_index_geotiff, Colormap, GeoReference,
    GeoTiffOptions, Tile, VegetationIndex,
};
use msnerf::output::{OutputError, SpectralImage};
use output_support::{scratch, six_band};
use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;

fn read_tiff_f32(path: &Path) -> (u32, u32, Vec<f32>, Decoder<BufReader<File>>) {
    let mut d = Decoder::new(BufReader::new(File::open(path).unwrap())).unwrap();
    let (w, h) = d.dimensions().unwrap();
    let v = match d.read_image().unwrap() {
        DecodingResult::F32(v) => v,
        _ => panic!("not f32"),
    };
    (w, h, v, d)
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn geotiff_round_trips_bit_exact_with_gdal_metadata() {
    let dir = scratch("geotiff");
    let mut img = six_band(37, 23);
    img.data[5] = f32::NAN;
    img.data[7] = -0.0;
    img.data[8] = 1e-40; // subnormal
    let path = dir.join("ortho.tif");
    let georef = GeoReference { origin: [500000.0, 4000000.0], pixel_size: [0.05, 0.05], epsg: Some(32650) };
    let opts = GeoTiffOptions {
        nodata: Some(-10000.0),
        georef: Some(georef),
        bigtiff: None,
        metadata: vec![("SOFTWARE_NOTE".into(), "a & b <c>".into())],
    };
    write_geotiff(&path, &img, &opts).unwrap();
    let (w, h, v, mut d) = read_tiff_f32(&path);
    assert_eq!((w, h), (37, 23));
    assert_eq!(bits(&v), bits(&img.to_interleaved()));
    let xml = d.get_tag_ascii_string(Tag::Unknown(42112)).unwrap();
    let doc = roxmltree::Document::parse(&xml).unwrap();
    let items: Vec<_> = doc.descendants().filter(|n| n.has_tag_name("Item")).collect();
    let desc = |i: usize| {
        items
            .iter()
            .find(|n| n.attribute("name") == Some("DESCRIPTION") && n.attribute("sample") == Some(&i.to_string()))
            .and_then(|n| n.text())
            .unwrap()
            .to_string()
    };
    assert_eq!(desc(0), "Blue 450nm");
    assert_eq!(desc(5), "NIR 840nm");
    let item = |name: &str, i: usize| {
        items
            .iter()
            .find(|n| n.attribute("name") == Some(name) && n.attribute("sample") == Some(&i.to_string()))
            .and_then(|n| n.text())
            .map(str::to_string)
    };
    assert_eq!(item("wavelength", 3).as_deref(), Some("720"));
    assert_eq!(item("fwhm", 3).as_deref(), Some("10"));
    assert_eq!(item("CENTRAL_WAVELENGTH_UM", 5).as_deref(), Some("0.84"));
    assert!(items.iter().any(|n| n.attribute("name") == Some("SOFTWARE_NOTE") && n.text() == Some("a & b <c>")));
    assert_eq!(d.get_tag_ascii_string(Tag::Unknown(42113)).unwrap(), "-10000");
    assert_eq!(d.get_tag_f64_vec(Tag::Unknown(33550)).unwrap(), vec![0.05, 0.05, 0.0]);
    assert_eq!(d.get_tag_f64_vec(Tag::Unknown(33922)).unwrap(), vec![0.0, 0.0, 0.0, 500000.0, 4000000.0, 0.0]);
    let keys = d.get_tag_u16_vec(Tag::Unknown(34735)).unwrap();
    assert_eq!(&keys[..4], &[1, 1, 0, 3]);
    assert!(keys.chunks(4).any(|k| k == [3072, 0, 1, 32650]));
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "no temporary file left behind");

    // BigTIFF on request reads back the same.
    let big = dir.join("big.tif");
    write_geotiff(&big, &img, &GeoTiffOptions { bigtiff: Some(true), ..Default::default() }).unwrap();
    assert_eq!(&std::fs::read(&big).unwrap()[..4], b"II\x2b\x00");
    let (_, _, v, _) = read_tiff_f32(&big);
    assert_eq!(bits(&v), bits(&img.to_interleaved()));

    // A single band, many strips (tall image).
    let tall = SpectralImage::single(3, 30000, band("NIR", Some(840.0), None), (0..90000).map(|i| i as f32).collect())
        .unwrap();
    let p = dir.join("tall.tif");
    write_geotiff(&p, &tall, &GeoTiffOptions::default()).unwrap();
    let (_, _, v, _) = read_tiff_f32(&p);
    assert_eq!(v, tall.data);
}

#[test]
fn the_data_layer_reads_our_geotiff_and_exr_back() {
    // Outputs can be re-ingested: the dataset readers see six float bands with the same values.
    let dir = scratch("reingest");
    let img = six_band(13, 7);
    let (t, e) = (dir.join("o.tif"), dir.join("o.exr"));
    write_geotiff(&t, &img, &GeoTiffOptions::default()).unwrap();
    write_exr(&e, &img).unwrap();
    let d = msnerf::data::tiff_reader::read_tiff(&t, 1 << 30).unwrap();
    assert_eq!((d.raster.width, d.raster.height, d.raster.bands), (13, 7, 6));
    for b in 0..6 {
        assert_eq!(d.raster.get(6, 12, b), img.band_data(b)[6 * 13 + 12]);
    }
    let d = msnerf::data::exr_reader::read_exr(&e, 1 << 30).unwrap();
    assert_eq!(d.raster.bands, 6);
    let names = &d.meta.channel_names;
    let nir = names.iter().position(|n| n == "NIR").unwrap();
    assert_eq!(d.raster.get(3, 4, nir), img.band_data(5)[3 * 13 + 4]);
}

#[test]
fn writers_report_the_path_on_failure() {
    let img = six_band(4, 4);
    let bad = Path::new("/nonexistent-dir-msnerf/x.tif");
    let e = write_geotiff(bad, &img, &GeoTiffOptions::default()).unwrap_err();
    assert!(matches!(e, OutputError::Write { .. }));
    assert!(e.to_string().contains("/nonexistent-dir-msnerf/x.tif"), "{e}");
    assert!(SpectralImage::from_planar(4, 4, ms600pro_bands(), vec![0.0; 10]).is_err());
    // Hand-built inconsistent images are errors, not panics.
    let bad = SpectralImage { data: vec![0.0; 10], ..img.clone() };
    let e = write_geotiff(Path::new("x.tif"), &bad, &GeoTiffOptions::default()).unwrap_err().to_string();
    assert!(e.contains("10 values"), "{e}");
    assert!(write_exr(Path::new("x.exr"), &bad).is_err());
    assert!(preview::natural_colour(&bad, Stretch::default()).is_err());
    assert!(compute_index(&bad, VegetationIndex::Ndvi, 25.0).is_err());
    assert!(preview::error_preview(&bad, &img, None).is_err());
}

#[test]
fn gdalinfo_reads_six_bands_with_descriptions() {
    let gdalinfo = std::process::Command::new("gdalinfo").arg("--version").output();
    assert!(
        gdalinfo.is_ok_and(|o| o.status.success()),
        "gdalinfo is not installed: run `bash tools/setup-debian.sh` (or `apt-get install gdal-bin`)"
    );
    let dir = scratch("gdalinfo");
    let img = six_band(19, 11);
    let path = dir.join("six.tif");
    let georef = GeoReference { origin: [500000.0, 4000000.0], pixel_size: [0.1, 0.1], epsg: Some(32650) };
    write_geotiff(&path, &img, &GeoTiffOptions { nodata: Some(f64::NAN), georef: Some(georef), ..Default::default() })
        .unwrap();
    let out = std::process::Command::new("gdalinfo").args(["-json", "-mdd", "all"]).arg(&path).output().unwrap();
    assert!(out.status.success(), "gdalinfo failed: {}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let bands = j["bands"].as_array().unwrap();
    assert_eq!(bands.len(), 6);
    let want = ["Blue 450nm", "Green 555nm", "Red 660nm", "RedEdge1 720nm", "RedEdge2 750nm", "NIR 840nm"];
    for (b, w) in bands.iter().zip(want) {
        assert_eq!(b["description"], w);
        assert_eq!(b["type"], "Float32");
        assert!(b["noDataValue"].as_str().is_some_and(|s| s.eq_ignore_ascii_case("nan")), "{}", b["noDataValue"]);
    }
    assert_eq!(bands[5]["metadata"][""]["wavelength"], "840");
    assert_eq!(bands[5]["metadata"][""]["fwhm"], "35");
    assert_eq!(j["size"], serde_json::json!([19, 11]));
    assert_eq!(j["geoTransform"], serde_json::json!([500000.0, 0.1, 0.0, 4000000.0, 0.0, -0.1]));
    let wkt = j["coordinateSystem"]["wkt"].as_str().unwrap();
    assert!(wkt.contains("UTM zone 50N"), "{wkt}");
}

#[test]
fn exr_channels_read_back_by_name() {
    let dir = scratch("exr");
    let img = six_band(21, 9);
    let path = dir.join("bands.exr");
    write_exr(&path, &img).unwrap();
    let image = exr::prelude::read_first_flat_layer_from_file(&path).unwrap();
    assert_eq!(image.layer_data.size.width(), 21);
    let chans = &image.layer_data.channel_data.list;
    assert_eq!(chans.len(), 6);
    for (b, band) in img.bands.iter().enumerate() {
        let c = chans.iter().find(|c| c.name.to_string() == band.name).unwrap();
        match &c.sample_data {
            exr::prelude::FlatSamples::F32(v) => assert_eq!(bits(v), bits(img.band_data(b))),
            _ => panic!("channel {} is not f32", band.name),
        }
    }
    let mut dup = img.clone();
    dup.bands[1].name = dup.bands[0].name.clone();
    assert!(write_exr(&dir.join("dup.exr"), &dup).is_err());
}

fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(BufReader::new(File::open(path).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn previews_write_pngs_that_read_back() {
    let dir = scratch("png");
    let img = six_band(40, 30);
    let nat = preview::natural_colour(&img, Stretch::default()).unwrap();
    let p = dir.join("rgb.png");
    nat.write_png(&p).unwrap();
    let (w, h, px) = read_png(&p);
    assert_eq!((w, h), (40, 30));
    assert_eq!(px, nat.data);

    // Natural colour picks 660/555/450 (bands 2, 1, 0), CIR 840/660/555 (5, 2, 1): a fixed stretch makes
    // the bytes predictable.
    let fixed = Stretch::Fixed { min: 0.0, max: 1.0 };
    let nat = preview::natural_colour(&img, fixed).unwrap();
    let cir = preview::cir(&img, fixed).unwrap();
    let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    for p in [0usize, 77, 1199] {
        let (x, y) = (p % 40, p / 40);
        assert_eq!(nat.get(x, y), [2, 1, 0].map(|b| byte(img.band_data(b)[p])));
        assert_eq!(cir.get(x, y), [5, 2, 1].map(|b| byte(img.band_data(b)[p])));
    }
    // Reflectance stretch: 0–0.5 for visible, 0–0.8 for NIR.
    let refl = preview::cir(&img, Stretch::Reflectance).unwrap();
    let v = img.band_data(5)[0];
    assert_eq!(refl.get(0, 0)[0], ((v as f64 / 0.8).clamp(0.0, 1.0) * 255.0).round() as u8);
    let v = img.band_data(2)[0];
    assert_eq!(refl.get(0, 0)[1], ((v as f64 / 0.5).clamp(0.0, 1.0) * 255.0).round() as u8);

    // Percentile stretch: numpy's linear interpolation.
    let vals: Vec<f32> = (0..=100).map(|i| i as f32).collect();
    assert_eq!(preview::percentile(&vals, 2.0), 2.0);
    assert!((preview::percentile(&[0.0, 1.0, 2.0, 10.0], 98.0) - 9.52).abs() < 1e-12);

    // Missing wavelengths: the error names the composite and the wavelength.
    let rgb3 = SpectralImage::from_planar(4, 4, ms600pro_bands()[..3].to_vec(), vec![0.1; 48]).unwrap();
    let e = preview::cir(&rgb3, fixed).unwrap_err().to_string();
    assert!(e.contains("CIR") && e.contains("840"), "{e}");

    // Depth, accumulation, error map and index previews.
    let depth: Vec<f32> = (0..1200).map(|i| i as f32 / 100.0).collect();
    let d = preview::depth_preview(&depth, 40, 30, None, Colormap::Turbo).unwrap();
    assert_eq!(d.get(0, 0), Colormap::Turbo.map(0.0));
    assert_eq!(d.get(39, 29), Colormap::Turbo.map(1.0));
    let acc = preview::accumulation_preview(&vec![0.5; 1200], 40, 30).unwrap();
    assert_eq!(acc.get(3, 3), [128, 128, 128]);
    let mut pred = img.clone();
    pred.data[0] += 0.3;
    let (err, vmax) = preview::error_preview(&pred, &img, None).unwrap();
    assert!((vmax - (0.09f64 / 6.0).sqrt()).abs() < 1e-6);
    assert_eq!(err.get(0, 0), Colormap::Inferno.map(1.0));
    assert_eq!(err.get(1, 0), Colormap::Inferno.map(0.0));
    let ndvi = compute_index(&img, VegetationIndex::Ndvi, 25.0).unwrap();
    let prev = preview::index_preview(&ndvi, 40, 30, (-1.0, 1.0)).unwrap();
    assert!(prev.height > 30, "colour bar strip below the image");
    assert_eq!(prev.get(0, prev.height - 1), Colormap::RdYlGn.map(0.0));
    assert_eq!(prev.get(39, prev.height - 1), Colormap::RdYlGn.map(1.0));
    let p = dir.join("ndvi.png");
    prev.write_png(&p).unwrap();
    let (_, hh, px) = read_png(&p);
    assert_eq!(hh as usize, prev.height);
    assert_eq!(px, prev.data);
}

#[test]
fn contact_sheet_lays_tiles_on_a_grid() {
    let a = Rgb8::filled(10, 8, [255, 0, 0]);
    let b = Rgb8::filled(6, 8, [0, 255, 0]);
    let c = Rgb8::filled(10, 5, [0, 0, 255]);
    let tiles = [Tile { image: &a, label: None }, Tile { image: &b, label: None }, Tile { image: &c, label: None }];
    let s = contact_sheet(&tiles, 2, 3, [40, 40, 40]).unwrap();
    assert_eq!((s.width, s.height), (2 * 10 + 3 * 3, 2 * 8 + 3 * 3));
    assert_eq!(s.get(3, 3), [255, 0, 0]);
    assert_eq!(s.get(3 + 10 + 3, 3), [0, 255, 0]);
    assert_eq!(s.get(3, 3 + 8 + 3), [0, 0, 255]);
    assert_eq!(s.get(0, 0), [40, 40, 40]);
    assert_eq!(s.get(3 + 10 + 3 + 7, 3), [40, 40, 40], "narrower tile leaves background");
    // Labels add a strip with ink.
    let tiles = [Tile { image: &a, label: Some("NDVI 0.5") }];
    let s = contact_sheet(&tiles, 1, 2, [0, 0, 0]).unwrap();
    assert!(s.height > 8 + 4);
    let ink = (0..s.width)
        .flat_map(|x| (10..s.height).map(move |y| (x, y)))
        .filter(|&(x, y)| s.get(x, y) == [255; 3])
        .count();
    assert!(ink > 10, "label pixels drawn");
    assert!(contact_sheet(&[], 2, 1, [0; 3]).is_err());
}

#[test]
fn vegetation_indices_use_centre_wavelengths() {
    // One pixel per row of interest; bands B G R RE1 RE2 NIR.
    let px: [[f32; 6]; 3] = [[0.05, 0.08, 0.04, 0.2, 0.35, 0.5], [0.1, 0.1, 0.1, 0.1, 0.1, 0.1], [0.0; 6]];
    let mut data = vec![0.0f32; 18];
    for (p, v) in px.iter().enumerate() {
        for b in 0..6 {
            data[b * 3 + p] = v[b];
        }
    }
    let img = SpectralImage::from_planar(3, 1, ms600pro_bands(), data).unwrap();
    let f = |b: usize| px[0][b] as f64;
    let (bl, g, r, re1, re2, nir) = (f(0), f(1), f(2), f(3), f(4), f(5));
    let want = [
        (VegetationIndex::Ndvi, (nir - r) / (nir + r)),
        (VegetationIndex::Ndre720, (nir - re1) / (nir + re1)),
        (VegetationIndex::Ndre750, (nir - re2) / (nir + re2)),
        (VegetationIndex::Gndvi, (nir - g) / (nir + g)),
        (VegetationIndex::Savi, 1.5 * (nir - r) / (nir + r + 0.5)),
        (VegetationIndex::Osavi, (nir - r) / (nir + r + 0.16)),
        (VegetationIndex::Evi, 2.5 * (nir - r) / (nir + 6.0 * r - 7.5 * bl + 1.0)),
        (VegetationIndex::Ndwi, (g - nir) / (g + nir)),
        (VegetationIndex::CiRededge, nir / re1 - 1.0),
        (VegetationIndex::CiGreen, nir / g - 1.0),
        (VegetationIndex::Mtci, (re2 - re1) / (re1 - r)),
        (VegetationIndex::Ndvi705, (re2 - re1) / (re2 + re1)),
    ];
    assert_eq!(want.len(), VegetationIndex::ALL.len());
    for (idx, w) in want {
        let v = compute_index(&img, idx, 25.0).unwrap();
        assert_eq!(v[0], w as f32, "{}", idx.name());
        assert_eq!(VegetationIndex::parse(&idx.name().to_lowercase()).unwrap(), idx);
    }
    // Zero denominators give NaN (equal bands for MTCI's RE1 − R, all-zero pixel for NDVI).
    assert!(compute_index(&img, VegetationIndex::Mtci, 25.0).unwrap()[1].is_nan());
    assert!(compute_index(&img, VegetationIndex::Ndvi, 25.0).unwrap()[2].is_nan());
    assert!(compute_index(&img, VegetationIndex::CiGreen, 25.0).unwrap()[2].is_nan());

    // A MicaSense RedEdge-like set (475/560/668/717/842): NDRE750 and MTCI have no 750 nm band.
    let mica: Vec<_> = [("Blue", 475.0), ("Green", 560.0), ("Red", 668.0), ("RedEdge", 717.0), ("NIR", 842.0)]
        .iter()
        .map(|&(n, c)| band(n, Some(c), None))
        .collect();
    let m = SpectralImage::from_planar(2, 2, mica, vec![0.2; 20]).unwrap();
    assert!(compute_index(&m, VegetationIndex::Ndvi, 25.0).is_ok());
    let e = compute_index(&m, VegetationIndex::Ndre750, 25.0).unwrap_err();
    assert!(matches!(e, OutputError::MissingBand { .. }));
    let e = e.to_string();
    assert!(e.contains("NDRE750") && e.contains("750"), "{e}");
    let e = VegetationIndex::parse("NDXI").unwrap_err().to_string();
    assert!(e.contains("NDXI") && e.contains("NDVI"), "{e}");

    // Written as a single-band float32 GeoTIFF with NaN nodata.
    let dir = scratch("index");
    let p = dir.join("ndvi.tif");
    let out = write_index_geotiff(&p, &img, VegetationIndex::Ndvi, 25.0, None).unwrap();
    let (w, h, v, mut d) = read_tiff_f32(&p);
    assert_eq!((w, h), (3, 1));
    assert_eq!(bits(&v), bits(&out.data));
    assert!(v[2].is_nan());
    assert_eq!(d.get_tag_ascii_string(Tag::Unknown(42113)).unwrap(), "nan");
    let xml = d.get_tag_ascii_string(Tag::Unknown(42112)).unwrap();
    assert!(xml.contains(">NDVI<") && xml.contains("NIR 840nm, Red 660nm"), "{xml}");
}
