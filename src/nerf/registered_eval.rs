//! `msnerf eval RUN --registered-truth DIR`: how well a run's bands agree with each other where a rig's band offsets
//! matter. Each view of the split is rendered through the frame camera (every band registered to it, as renders,
//! clouds and orthophotos show them) and compared with `DIR/<frame stem>.tif`, the true image of every band seen
//! from the frame camera (`msnerf simulate` writes it as `truth/registered/` for scenes with `rig_parallax`).
//!
//! Errors are reported per band, apart at **depth discontinuities** and elsewhere: a pixel is at a discontinuity
//! when the dataset's depth map changes by more than 5 % of its depth between it and a pixel within 2 pixels
//! (where a band camera beside the frame camera sees a different surface, so no 2D warp of its image can be right),
//! and the normalised difference index of the band pair asked for (NIR and red by default: NDVI) is compared too,
//! since band ratios are what users compute and misregistration corrupts first.

use std::path::Path;

use crate::data::Split;
use crate::nerf::error::{NerfError, NerfResult};
use crate::nerf::run::LoadedRun;

/// Root-mean-square errors of one class of pixels.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct PixelClassErrors {
    pub pixels: usize,
    /// Per band, RMSE against the registered truth.
    pub rmse: Vec<f64>,
    /// Mean of the per-band RMSEs.
    pub mean_rmse: f64,
    /// RMSE of the normalised difference index (a - b) / (a + b) of the index bands.
    pub index_rmse: f64,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct RegisteredReport {
    pub views: usize,
    pub bands: Vec<String>,
    /// The index bands (a, b) of `index_rmse`.
    pub index_bands: [String; 2],
    pub discontinuity: PixelClassErrors,
    pub elsewhere: PixelClassErrors,
}

#[derive(Default)]
struct Acc {
    n: usize,
    sq: Vec<f64>,
    index_sq: f64,
}

impl Acc {
    fn finish(&self) -> PixelClassErrors {
        let rmse: Vec<f64> = self.sq.iter().map(|s| (s / self.n.max(1) as f64).sqrt()).collect();
        PixelClassErrors {
            pixels: self.n,
            mean_rmse: rmse.iter().sum::<f64>() / rmse.len().max(1) as f64,
            rmse,
            index_rmse: (self.index_sq / self.n.max(1) as f64).sqrt(),
        }
    }
}

/// Pixels whose depth differs by more than 5 % from a pixel within 2 pixels.
pub fn discontinuities(depth: &[f32], w: usize, h: usize) -> Vec<bool> {
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let d = depth[y * w + x];
            let mut edge = false;
            for yy in y.saturating_sub(2)..(y + 3).min(h) {
                for xx in x.saturating_sub(2)..(x + 3).min(w) {
                    edge |= (depth[yy * w + xx] - d).abs() > 0.05 * d.abs();
                }
            }
            out[y * w + x] = edge;
        }
    }
    out
}

fn index_of(a: f64, b: f64) -> f64 {
    if a + b > 1e-6 {
        (a - b) / (a + b)
    } else {
        0.0
    }
}

/// Evaluates the views of `split` against the registered truth in `truth_dir`; `index_bands` names the pair of
/// the normalised difference index (default: the bands nearest 840 and 660 nm).
pub fn evaluate_registered(
    run: &mut LoadedRun,
    split: Split,
    truth_dir: &Path,
    index_bands: Option<(usize, usize)>,
) -> NerfResult<RegisteredReport> {
    let frames = run.ds.split_indices(split);
    if frames.is_empty() {
        return Err(NerfError::key(&run.ds.transforms_path, "frames", format!("the {split:?} split is empty")));
    }
    let b_n = run.ds.n_bands();
    let nearest = |nm: f64| {
        (0..b_n)
            .min_by(|&a, &b| {
                let d = |i: usize| (run.ds.bands[i].center_nm.unwrap_or(f64::MAX) - nm).abs();
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0)
    };
    let (ia, ib) = index_bands.unwrap_or((nearest(840.0), nearest(660.0)));
    let (mut edge, mut rest) = (Acc { sq: vec![0.0; b_n], ..Default::default() }, Acc::default());
    rest.sq = vec![0.0; b_n];
    // Truth files hold every band of the dataset's files; a run on a band subset reads its own.
    let selected: Vec<usize> = run.ds.band_selection.as_ref().map_or((0..b_n).collect(), |s| s.indices.clone());
    let file_band = |b: usize| selected[b];
    let n_file = run.ds.file_bands().len();
    let first_band = run.ds.file_bands()[0].name.to_ascii_lowercase();
    for &f in &frames {
        let mut stem =
            Path::new(&run.ds.frames[f].name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        // One file per band (`band_files`): the frame is named by its first band's file, `<view>_<band>`.
        if matches!(run.ds.frames[f].image, crate::data::ImageSource::BandFiles(_)) {
            let lower = stem.to_ascii_lowercase();
            if let Some(cut) = lower.strip_suffix(&first_band).and_then(|s| s.strip_suffix('_')).map(str::len) {
                stem.truncate(cut);
            }
        }
        let path = truth_dir.join(format!("{stem}.tif"));
        let truth = crate::data::tiff_reader::read_tiff(&path, 1 << 32)
            .map_err(|e| NerfError::file(&path, format!("registered truth: {e}")))?
            .raster;
        let (w, h) = (run.ds.width as usize, run.ds.height as usize);
        if (truth.width as usize, truth.height as usize, truth.bands) != (w, h, n_file) {
            return Err(NerfError::file(
                &path,
                format!(
                    "{}x{} with {} bands; the dataset's files are {w}x{h} with {n_file}",
                    truth.width, truth.height, truth.bands
                ),
            ));
        }
        let depth = run.ds.read_depth(f)?.ok_or_else(|| {
            NerfError::key(
                &run.ds.transforms_path,
                "depth_file_path",
                format!("frame {} has no depth map", run.ds.frames[f].name),
            )
        })?;
        let edges = discontinuities(&depth, w, h);
        let rv = run.render_view(f)?;
        for (p, &at_edge) in edges.iter().enumerate() {
            let acc = if at_edge { &mut edge } else { &mut rest };
            acc.n += 1;
            let (row, col) = ((p / w) as u32, (p % w) as u32);
            for b in 0..b_n {
                let e = rv.colour[p * b_n + b] as f64 - truth.get(row, col, file_band(b)) as f64;
                acc.sq[b] += e * e;
            }
            let pred = index_of(rv.colour[p * b_n + ia] as f64, rv.colour[p * b_n + ib] as f64);
            let want = index_of(truth.get(row, col, file_band(ia)) as f64, truth.get(row, col, file_band(ib)) as f64);
            acc.index_sq += (pred - want).powi(2);
        }
    }
    Ok(RegisteredReport {
        views: frames.len(),
        bands: run.ds.bands.iter().map(|b| b.name.clone()).collect(),
        index_bands: [run.ds.bands[ia].name.clone(), run.ds.bands[ib].name.clone()],
        discontinuity: edge.finish(),
        elsewhere: rest.finish(),
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_step_in_depth_marks_two_pixels_each_side() {
        let depth: Vec<f32> = (0..10).map(|x| if x < 5 { 10.0 } else { 5.0 }).collect();
        let e = super::discontinuities(&depth, 10, 1);
        assert_eq!(e, [false, false, false, true, true, true, true, false, false, false]);
    }
}
