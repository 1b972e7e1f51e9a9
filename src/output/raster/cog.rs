//! Streaming Cloud-Optimized GeoTIFF writer for rasters larger than host memory (the DSM and orthomosaic of
//! `msnerf export dsm|ortho`).
//!
//! The caller pushes pixel-interleaved float32 rows top to bottom; nothing but one tile row per resolution level is
//! held. Layout, as GDAL's COG driver writes it and `validate_cloud_optimized_geotiff.py --full-check=yes` checks it:
//! - header, then GDAL's structural-metadata "ghost" block (`LAYOUT=IFDS_BEFORE_DATA`, `BLOCK_ORDER=ROW_MAJOR`,
//!   `BLOCK_LEADER=SIZE_AS_UINT4`, `BLOCK_TRAILER=LAST_4_BYTES_REPEATED`), so `gdalinfo` reports `LAYOUT=COG`;
//! - every IFD before any pixel: the full-resolution image (georeferencing, band metadata, nodata), then the
//!   overviews (NewSubfileType 1), halving until the coarsest fits one tile;
//! - the tiles, smallest overview first and the full resolution last, each row-major; each tile is preceded by its
//!   size as a u32 and followed by a copy of its last four bytes (GDAL's leader and trailer).
//!
//! Tiles are 256 x 256, uncompressed, pixel-interleaved; so every tile's offset is known before the first pixel
//! arrives and tiles are written in place as their rows complete. Overviews are the 2 x 2 mean of the level above,
//! nodata skipped (GDAL's `AVERAGE`). Edge tiles are padded with nodata.
//!
//! Host memory: 256 rows of every level, about 2 x 256 x width x bands x 4 bytes, plus the preview level kept for
//! PNG previews (the first level no larger than `preview_max` on either side).
//!
//! The file is written under a temporary name and renamed by [`CogWriter::finish`]; dropped unfinished it is removed.

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::geotiff::{ascii, encode_ifd, float_layout_entries, geo_entries, longs, nodata_string, offsets, Entry};
use super::geotiff::{GeoTiffOptions, TAG_GDAL_NODATA};
use crate::output::{Band, OutputError, Result, SpectralImage};
use crate::util::atomic::AtomicFile;

/// Tile edge in pixels (GDAL's COG default).
pub const TILE: usize = 256;

const GHOST: &str = "LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\nBLOCK_LEADER=SIZE_AS_UINT4\n\
BLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=NO\n ";

/// Options of a COG: nodata (required: overviews and padding need it), georeferencing, dataset metadata.
#[derive(Debug, Clone)]
pub struct CogOptions {
    pub geotiff: GeoTiffOptions,
    /// Keep the first level whose width and height are both at most this for previews (0: none).
    pub preview_max: usize,
}

struct Level {
    width: usize,
    height: usize,
    tiles_x: usize,
    /// File offset of the first tile slot (leader included).
    data_offset: u64,
    /// The current tile row: up to TILE rows of `width * bands` values.
    buf: Vec<f32>,
    buf_rows: usize,
    tile_row: usize,
    rows_done: usize,
    /// A row waiting for its partner before the 2 x 2 mean goes to the next level.
    pending: Option<Vec<f32>>,
}

/// A COG being written; see the module doc.
pub struct CogWriter {
    path: PathBuf,
    atomic: Option<AtomicFile>,
    file: File,
    bands: Vec<Band>,
    nodata: f32,
    levels: Vec<Level>,
    preview_level: Option<usize>,
    preview: Vec<f32>,
}

/// The preview level's pixels and its size relative to the full resolution.
pub struct CogPreview {
    pub image: SpectralImage,
    /// Full-resolution pixels per preview pixel (a power of two).
    pub factor: usize,
}

fn tile_bytes(bands: usize) -> u64 {
    (TILE * TILE * bands * 4) as u64
}

/// Slot of one tile in the file: leader, data, trailer.
fn slot_bytes(bands: usize) -> u64 {
    tile_bytes(bands) + 8
}

impl CogWriter {
    /// Creates the file (under a temporary name) for a `width` x `height` raster of `bands`, and writes its header and
    /// every IFD.
    pub fn create(path: &Path, width: usize, height: usize, bands: Vec<Band>, opts: &CogOptions) -> Result<Self> {
        let nb = bands.len();
        if width == 0 || height == 0 || nb == 0 {
            return Err(OutputError::invalid("raster", format!("{width}x{height} with {nb} bands is empty")));
        }
        if width > u32::MAX as usize || height > u32::MAX as usize || nb > u16::MAX as usize {
            return Err(OutputError::invalid("raster", format!("{width}x{height}x{nb} does not fit a TIFF")));
        }
        let nodata = opts
            .geotiff
            .nodata
            .ok_or_else(|| OutputError::invalid("nodata", "a COG needs a nodata value for its padding"))?
            as f32;
        // Levels: halve until one tile holds the whole image.
        let mut dims = vec![(width, height)];
        while dims.last().is_some_and(|&(w, h)| w > TILE || h > TILE) {
            let (w, h) = *dims.last().expect("non-empty");
            dims.push((w.div_ceil(2), h.div_ceil(2)));
        }
        let n_tiles: Vec<usize> = dims.iter().map(|&(w, h)| w.div_ceil(TILE) * h.div_ceil(TILE)).collect();
        let data_len: u64 = n_tiles.iter().map(|&n| n as u64 * slot_bytes(nb)).sum();
        let big = opts.geotiff.bigtiff.unwrap_or(data_len + (1 << 24) > u32::MAX as u64);
        let header_len: u64 = if big { 16 } else { 8 };
        let ghost = format!("GDAL_STRUCTURAL_METADATA_SIZE={:06} bytes\n{GHOST}", GHOST.len());
        let first_ifd = (header_len + ghost.len() as u64).next_multiple_of(2);

        // Pass 1 sizes the IFDs (their length does not depend on the offsets), pass 2 writes the real offsets.
        let entries = |level: usize, tile_offsets: &[u64]| -> Result<Vec<Entry>> {
            let (w, h) = dims[level];
            let mut e = float_layout_entries(w, h, nb);
            e.push(longs(254, &[u32::from(level > 0)]));
            e.push(longs(322, &[TILE as u32]));
            e.push(longs(323, &[TILE as u32]));
            e.push(offsets(324, tile_offsets, big));
            e.push(offsets(325, &vec![tile_bytes(nb); tile_offsets.len()], big));
            if level == 0 {
                e.extend(geo_entries(&bands, &opts.geotiff)?);
            } else if let Some(nd) = opts.geotiff.nodata {
                e.push(ascii(TAG_GDAL_NODATA, &nodata_string(nd)));
            }
            Ok(e)
        };
        let mut ifd_offsets = Vec::with_capacity(dims.len());
        let mut at = first_ifd;
        for (l, &n) in n_tiles.iter().enumerate() {
            ifd_offsets.push(at);
            let len = encode_ifd(entries(l, &vec![0; n])?, 0, 0, big, path)?.len() as u64;
            at = (at + len).next_multiple_of(2);
        }
        // Tile data: smallest overview first, full resolution last.
        let mut data_offsets = vec![0u64; dims.len()];
        let mut d = at;
        for l in (0..dims.len()).rev() {
            data_offsets[l] = d;
            d += n_tiles[l] as u64 * slot_bytes(nb);
        }
        if !big && d > u32::MAX as u64 {
            return Err(OutputError::write(path, "the file would exceed 4 GiB: ask for BigTIFF"));
        }
        let (atomic, mut file) = AtomicFile::create(path)?;
        let io = |e: std::io::Error| OutputError::write(path, e);
        let mut head = Vec::new();
        if big {
            head.extend_from_slice(b"II\x2b\x00\x08\x00\x00\x00");
            head.extend_from_slice(&first_ifd.to_le_bytes());
        } else {
            head.extend_from_slice(b"II\x2a\x00");
            head.extend_from_slice(&(first_ifd as u32).to_le_bytes());
        }
        head.extend_from_slice(ghost.as_bytes());
        head.resize(first_ifd as usize, 0);
        for l in 0..dims.len() {
            let tiles: Vec<u64> = (0..n_tiles[l] as u64).map(|t| data_offsets[l] + t * slot_bytes(nb) + 4).collect();
            let next = ifd_offsets.get(l + 1).copied().unwrap_or(0);
            let ifd = encode_ifd(entries(l, &tiles)?, ifd_offsets[l], next, big, path)?;
            head.resize(ifd_offsets[l] as usize, 0);
            head.extend_from_slice(&ifd);
        }
        head.resize(at as usize, 0);
        file.write_all(&head).map_err(io)?;
        let levels = dims
            .iter()
            .zip(&data_offsets)
            .map(|(&(w, h), &off)| Level {
                width: w,
                height: h,
                tiles_x: w.div_ceil(TILE),
                data_offset: off,
                buf: vec![nodata; TILE * w * nb],
                buf_rows: 0,
                tile_row: 0,
                rows_done: 0,
                pending: None,
            })
            .collect();
        let preview_level =
            (opts.preview_max > 0).then(|| dims.iter().position(|&(w, h)| w.max(h) <= opts.preview_max)).flatten();
        Ok(CogWriter {
            path: path.to_path_buf(),
            atomic: Some(atomic),
            file,
            bands,
            nodata,
            levels,
            preview_level,
            preview: Vec::new(),
        })
    }

    /// Full-resolution width and height.
    pub fn size(&self) -> (usize, usize) {
        (self.levels[0].width, self.levels[0].height)
    }

    /// Rows received so far.
    pub fn rows_done(&self) -> usize {
        self.levels[0].rows_done
    }

    /// Appends whole rows (pixel-interleaved: `width * bands` values each) below those already pushed.
    pub fn push_rows(&mut self, rows: &[f32]) -> Result<()> {
        let stride = self.levels[0].width * self.bands.len();
        if rows.len() % stride != 0 {
            return Err(OutputError::invalid("rows", format!("{} values are not whole rows of {stride}", rows.len())));
        }
        let n = rows.len() / stride;
        if self.rows_done() + n > self.levels[0].height {
            return Err(OutputError::invalid(
                "rows",
                format!("{} rows pushed to a raster of {}", self.rows_done() + n, self.levels[0].height),
            ));
        }
        for r in rows.chunks_exact(stride) {
            self.add_row(0, r.to_vec())?;
        }
        Ok(())
    }

    fn is_nodata(&self, v: f32) -> bool {
        v.is_nan() || v == self.nodata
    }

    fn add_row(&mut self, l: usize, row: Vec<f32>) -> Result<()> {
        let nb = self.bands.len();
        if self.preview_level == Some(l) {
            self.preview.extend_from_slice(&row);
        }
        let lv = &mut self.levels[l];
        let stride = lv.width * nb;
        lv.buf[lv.buf_rows * stride..(lv.buf_rows + 1) * stride].copy_from_slice(&row);
        lv.buf_rows += 1;
        lv.rows_done += 1;
        let last = lv.rows_done == lv.height;
        if lv.buf_rows == TILE || last {
            self.flush(l)?;
        }
        if l + 1 < self.levels.len() {
            let pending = self.levels[l].pending.take();
            match pending {
                Some(prev) => {
                    let down = self.downsample(l, &prev, Some(&row));
                    self.add_row(l + 1, down)?;
                }
                None if last => {
                    let down = self.downsample(l, &row, None);
                    self.add_row(l + 1, down)?;
                }
                None => self.levels[l].pending = Some(row),
            }
        }
        Ok(())
    }

    /// The 2 x 2 mean (nodata skipped) of rows `a` and `b` of level `l`: one row of level `l + 1`.
    fn downsample(&self, l: usize, a: &[f32], b: Option<&[f32]>) -> Vec<f32> {
        let nb = self.bands.len();
        let (w, w2) = (self.levels[l].width, self.levels[l + 1].width);
        let mut out = vec![self.nodata; w2 * nb];
        for x in 0..w2 {
            for k in 0..nb {
                let (mut sum, mut n) = (0.0f64, 0u32);
                for xs in [2 * x, 2 * x + 1].into_iter().filter(|&xs| xs < w) {
                    for r in std::iter::once(a).chain(b) {
                        let v = r[xs * nb + k];
                        if !self.is_nodata(v) {
                            sum += v as f64;
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    out[x * nb + k] = (sum / n as f64) as f32;
                }
            }
        }
        out
    }

    /// Writes level `l`'s buffered tile row (padded with nodata) into its tile slots.
    fn flush(&mut self, l: usize) -> Result<()> {
        let nb = self.bands.len();
        let nodata = self.nodata;
        let lv = &mut self.levels[l];
        let stride = lv.width * nb;
        lv.buf[lv.buf_rows * stride..].fill(nodata);
        let mut slot = Vec::with_capacity(slot_bytes(nb) as usize);
        let first = (lv.tile_row * lv.tiles_x) as u64;
        let at = lv.data_offset + first * slot_bytes(nb);
        let mut out = Vec::with_capacity(lv.tiles_x * slot.capacity());
        for tx in 0..lv.tiles_x {
            slot.clear();
            slot.extend_from_slice(&(tile_bytes(nb) as u32).to_le_bytes());
            let (x0, x1) = (tx * TILE, ((tx + 1) * TILE).min(lv.width));
            for r in 0..TILE {
                let row = &lv.buf[r * stride..(r + 1) * stride];
                slot.extend(row[x0 * nb..x1 * nb].iter().flat_map(|v| v.to_le_bytes()));
                for _ in 0..(TILE - (x1 - x0)) * nb {
                    slot.extend_from_slice(&nodata.to_le_bytes());
                }
            }
            let tail: [u8; 4] = slot[slot.len() - 4..].try_into().expect("4 bytes");
            slot.extend_from_slice(&tail);
            out.extend_from_slice(&slot);
        }
        lv.buf_rows = 0;
        lv.tile_row += 1;
        let io = |e: std::io::Error| OutputError::write(&self.path, e);
        self.file.seek(SeekFrom::Start(at)).map_err(io)?;
        self.file.write_all(&out).map_err(io)
    }

    /// Checks that every row arrived, syncs and renames the file into place; returns the preview level.
    pub fn finish(mut self) -> Result<Option<CogPreview>> {
        let (_, h) = self.size();
        if self.rows_done() != h {
            return Err(OutputError::write(&self.path, format!("only {} of {h} rows were written", self.rows_done())));
        }
        self.file.sync_all().map_err(|e| OutputError::write(&self.path, e))?;
        self.atomic.take().expect("not finished twice").commit()?;
        let Some(l) = self.preview_level else { return Ok(None) };
        let lv = &self.levels[l];
        let image = SpectralImage::from_interleaved(lv.width, lv.height, self.bands.clone(), &self.preview)?;
        Ok(Some(CogPreview { image, factor: 1 << l }))
    }
}
