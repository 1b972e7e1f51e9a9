//! Reads a north-up GeoTIFF's grid and pixels (the `tiff` crate decodes strips and tiles): `ModelPixelScale` and
//! `ModelTiepoint` give the grid, `GDAL_NODATA` the nodata value, the GeoKey directory the EPSG code. Used to align a
//! survey export to an existing raster (`--align-to`) and by `msnerf compare-raster`. Rotated grids
//! (`ModelTransformation`) are refused by name.

use std::path::Path;

use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::tags::Tag;

use super::geotiff::{TAG_GDAL_METADATA, TAG_GDAL_NODATA};
use crate::output::{OutputError, Result};

/// A GeoTIFF's grid.
#[derive(Debug, Clone, PartialEq)]
pub struct RasterGrid {
    /// World x, y of the top-left corner of the top-left pixel.
    pub origin: [f64; 2],
    /// Pixel width and height (positive).
    pub pixel_size: [f64; 2],
    pub width: usize,
    pub height: usize,
    pub bands: usize,
    pub nodata: Option<f64>,
    pub epsg: Option<u16>,
    /// Band descriptions from `GDAL_METADATA` (empty when absent).
    pub descriptions: Vec<String>,
}

impl RasterGrid {
    /// The pixel (col, row) holding world point (x, y), if inside.
    pub fn pixel_at(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let c = ((x - self.origin[0]) / self.pixel_size[0]).floor();
        let r = ((self.origin[1] - y) / self.pixel_size[1]).floor();
        (c >= 0.0 && r >= 0.0 && (c as usize) < self.width && (r as usize) < self.height)
            .then_some((c as usize, r as usize))
    }

    /// World x, y of the centre of pixel (col, row).
    pub fn centre(&self, col: usize, row: usize) -> [f64; 2] {
        [
            self.origin[0] + (col as f64 + 0.5) * self.pixel_size[0],
            self.origin[1] - (row as f64 + 0.5) * self.pixel_size[1],
        ]
    }
}

/// A GeoTIFF's grid and its pixels as f32, band-planar (`data[b * w * h + row * w + col]`); nodata stays as stored.
pub struct GeoRaster {
    pub grid: RasterGrid,
    pub data: Vec<f32>,
}

impl GeoRaster {
    pub fn value(&self, band: usize, col: usize, row: usize) -> f32 {
        self.data[band * self.grid.width * self.grid.height + row * self.grid.width + col]
    }

    /// Whether `v` is this raster's nodata (NaN always is).
    pub fn is_nodata(&self, v: f32) -> bool {
        v.is_nan() || self.grid.nodata.is_some_and(|n| v as f64 == n || v == n as f32)
    }
}

fn doubles(dec: &mut Decoder<std::io::BufReader<std::fs::File>>, tag: u16) -> Option<Vec<f64>> {
    dec.find_tag(Tag::Unknown(tag)).ok().flatten().and_then(|v| v.into_f64_vec().ok())
}

fn ascii(dec: &mut Decoder<std::io::BufReader<std::fs::File>>, tag: u16) -> Option<String> {
    dec.find_tag(Tag::Unknown(tag)).ok().flatten().and_then(|v| v.into_string().ok())
}

fn open(path: &Path) -> Result<Decoder<std::io::BufReader<std::fs::File>>> {
    let f = std::fs::File::open(path).map_err(|e| OutputError::read(path, e))?;
    let mut limits = Limits::default();
    limits.decoding_buffer_size = 1 << 34;
    limits.intermediate_buffer_size = 1 << 34;
    Ok(Decoder::new(std::io::BufReader::new(f)).map_err(|e| OutputError::read(path, e))?.with_limits(limits))
}

fn grid_of(path: &Path, dec: &mut Decoder<std::io::BufReader<std::fs::File>>) -> Result<RasterGrid> {
    let (w, h) = dec.dimensions().map_err(|e| OutputError::read(path, e))?;
    let bands = dec.find_tag_unsigned::<u32>(Tag::SamplesPerPixel).map_err(|e| OutputError::read(path, e))?.unwrap_or(1)
        as usize;
    if doubles(dec, 34264).is_some() {
        return Err(OutputError::read(path, "a rotated grid (ModelTransformation) is not supported: warp it north-up"));
    }
    let scale = doubles(dec, 33550).ok_or_else(|| OutputError::read(path, "no ModelPixelScale: not georeferenced"))?;
    let tie = doubles(dec, 33922).ok_or_else(|| OutputError::read(path, "no ModelTiepoint: not georeferenced"))?;
    if scale.len() < 2 || tie.len() < 6 || !(scale[0] > 0.0 && scale[1] > 0.0) {
        return Err(OutputError::read(path, format!("ModelPixelScale {scale:?} / ModelTiepoint {tie:?} malformed")));
    }
    let origin = [tie[3] - tie[0] * scale[0], tie[4] + tie[1] * scale[1]];
    let nodata = ascii(dec, TAG_GDAL_NODATA).and_then(|s| {
        let s = s.trim().trim_end_matches('\0');
        if s.eq_ignore_ascii_case("nan") {
            Some(f64::NAN)
        } else {
            s.parse().ok()
        }
    });
    let keys: Vec<u16> =
        dec.find_tag(Tag::Unknown(34735)).ok().flatten().and_then(|v| v.into_u16_vec().ok()).unwrap_or_default();
    let epsg = keys.chunks_exact(4).skip(1).find(|k| (k[0] == 3072 || k[0] == 2048) && k[1] == 0).map(|k| k[3]);
    let descriptions = ascii(dec, TAG_GDAL_METADATA).map(|xml| descriptions_from(&xml, bands)).unwrap_or_default();
    Ok(RasterGrid {
        origin,
        pixel_size: [scale[0], scale[1]],
        width: w as usize,
        height: h as usize,
        bands,
        nodata,
        epsg,
        descriptions,
    })
}

/// The `DESCRIPTION` items of a `GDAL_METADATA` XML, per band (empty strings where missing).
fn descriptions_from(xml: &str, bands: usize) -> Vec<String> {
    let mut out = vec![String::new(); bands];
    for item in xml.split("<Item ").skip(1) {
        let Some((attrs, rest)) = item.split_once('>') else { continue };
        if !attrs.contains("name=\"DESCRIPTION\"") {
            continue;
        }
        let sample: Option<usize> =
            attrs.split("sample=\"").nth(1).and_then(|s| s.split('"').next()).and_then(|s| s.parse().ok());
        if let (Some(i), Some((v, _))) = (sample, rest.split_once("</Item>")) {
            if i < bands {
                out[i] = v.replace("&lt;", "<").replace("&gt;", ">").replace("&quot;", "\"").replace("&amp;", "&");
            }
        }
    }
    out
}

/// The grid of the GeoTIFF at `path` without reading its pixels.
pub fn read_grid(path: &Path) -> Result<RasterGrid> {
    let mut dec = open(path)?;
    grid_of(path, &mut dec)
}

/// The grid and pixels of the GeoTIFF at `path` (first image; 8/16/32-bit integers and floats).
pub fn read_geotiff(path: &Path) -> Result<GeoRaster> {
    let mut dec = open(path)?;
    let grid = grid_of(path, &mut dec)?;
    let img = dec.read_image().map_err(|e| OutputError::read(path, e))?;
    let inter: Vec<f32> = match img {
        DecodingResult::F32(v) => v,
        DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I32(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        _ => return Err(OutputError::read(path, "unsupported sample type")),
    };
    let (n, nb) = (grid.width * grid.height, grid.bands);
    if inter.len() != n * nb {
        return Err(OutputError::read(
            path,
            format!("{} samples for {}x{}x{nb}", inter.len(), grid.width, grid.height),
        ));
    }
    let mut data = vec![0.0f32; inter.len()];
    for (p, px) in inter.chunks_exact(nb).enumerate() {
        for (b, &v) in px.iter().enumerate() {
            data[b * n + p] = v;
        }
    }
    Ok(GeoRaster { grid, data })
}
