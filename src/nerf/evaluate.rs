//! Evaluation of a trained run (nerfstudio keeps it in the pipeline, so does msnerf: `msnerf eval`, the demo and
//! `msnerf sweep` call it): per view PSNR and SSIM per band, LPIPS on natural-colour composites when given the
//! network, and the rendered median depth against the dataset's depth maps.

use std::path::PathBuf;

use crate::data::{DataError, Split};
use crate::nerf::run::LoadedRun;
use crate::output::image::SpectralImage;
use crate::output::metrics::depth::{DepthErrors, DepthReport};
use crate::output::metrics::lpips::Lpips;
use crate::output::metrics::{image_metrics, EvalReport, MetricOptions, ViewEval};
use crate::output::raster::preview::{COMPOSITE_TOLERANCE_NM, NATURAL_COLOUR_NM};
use crate::output::OutputError;

/// Why an evaluation failed: the dataset, the outputs layer, or a named frame.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("{}: the {split} split has no frames", path.display())]
    NoFrames { path: PathBuf, split: String },
    #[error("frame `{frame}`: {reason}")]
    Frame { frame: String, reason: String },
    /// Rendering a frame failed.
    #[error("frame `{frame}`: {err}")]
    Render { frame: String, err: Box<super::error::NerfError> },
}

/// Ground truth of a frame as a spectral image and its mask.
pub fn ground_truth(run: &LoadedRun, frame: usize) -> Result<(SpectralImage, Option<Vec<bool>>), EvalError> {
    ground_truth_of(&run.ds, frame)
}

/// [`ground_truth`] of frame `frame` of `ds`.
pub fn ground_truth_of(
    ds: &crate::data::Dataset,
    frame: usize,
) -> Result<(SpectralImage, Option<Vec<bool>>), EvalError> {
    let r = ds.read_frame(frame)?;
    let mut data: Vec<f32> = (0..r.bands).flat_map(|b| r.band_f32(b)).collect();
    let mask: Option<Vec<bool>> = r.mask.as_ref().map(|m| m.iter().map(|&v| v != 0).collect());
    if let Some(m) = &mask {
        // Masked-out pixels may hold nodata (NaN, -3.4e38: the loader checks only the pixels a mask keeps). The
        // metrics skip them, but SSIM's window reaches across them: they become 0 so no neighbour's value is lost.
        let px = m.len();
        for (i, v) in data.iter_mut().enumerate() {
            if !m[i % px] {
                *v = 0.0;
            }
        }
    }
    let img = SpectralImage::from_planar(r.width as usize, r.height as usize, ds.bands.clone(), data)?;
    Ok((img, mask))
}

/// The natural-colour composite (bands nearest 660, 555, 450 nm; a 3-band image without wavelengths as R, G, B) as
/// 3 planes clamped to [0, 1], and the band indices used.
pub fn natural_colour_planes(img: &SpectralImage) -> Result<(Vec<f32>, [usize; 3]), EvalError> {
    let idx = if img.n_bands() == 3 && img.bands.iter().all(|b| b.center_nm.is_none()) {
        [0, 1, 2]
    } else {
        let mut idx = [0; 3];
        for (i, &nm) in NATURAL_COLOUR_NM.iter().enumerate() {
            idx[i] = crate::output::image::nearest_band(&img.bands, nm, COMPOSITE_TOLERANCE_NM, "LPIPS composite")?;
        }
        idx
    };
    let px = img.width * img.height;
    let planes = idx.iter().flat_map(|&b| img.data[b * px..(b + 1) * px].iter().map(|v| v.clamp(0.0, 1.0))).collect();
    Ok((planes, idx))
}

/// Evaluates the views of `split` (at most `max_views`, evenly spread, when given), with LPIPS when `lpips` is given.
pub fn evaluate(
    run: &mut LoadedRun,
    split: Split,
    max_views: Option<usize>,
    lpips: Option<&Lpips>,
    depth: bool,
) -> Result<EvalReport, EvalError> {
    let mut frames = run.ds.split_indices(split);
    if let Some(m) = max_views.filter(|&m| m > 0 && m < frames.len()) {
        frames = (0..m).map(|k| frames[k * frames.len() / m]).collect();
    }
    if frames.is_empty() {
        return Err(EvalError::NoFrames { path: run.ds.transforms_path.clone(), split: format!("{split:?}") });
    }
    let mut views = Vec::new();
    let mut lpips_values = Vec::new();
    let mut lpips_bands = [0usize; 3];
    if depth {
        if let Some(&f) = frames.iter().find(|&&f| run.ds.frames[f].depth.is_none()) {
            return Err(EvalError::Frame {
                frame: run.ds.frames[f].name.clone(),
                reason: format!(
                    "no `depth_file_path` in {} (depth evaluation needs a depth map for every view)",
                    run.ds.transforms_path.display()
                ),
            });
        }
    }
    let mut depth_views = Vec::new();
    for f in frames {
        let rv = run
            .render_observed_view(f)
            .map_err(|e| EvalError::Render { frame: run.ds.frames[f].name.clone(), err: Box::new(e) })?;
        let pred = SpectralImage::from_interleaved(rv.width, rv.height, run.ds.bands.clone(), &rv.colour)?;
        let (gt, mask) = ground_truth(run, f)?;
        let metrics = image_metrics(&pred, &gt, mask.as_deref(), &MetricOptions { data_range: 1.0 })?;
        if let Some(net) = lpips {
            let (a, idx) = natural_colour_planes(&pred)?;
            let (b, _) = natural_colour_planes(&gt)?;
            let name = &run.ds.frames[f].name;
            lpips_values.push(
                net.distance(&a, &b, pred.width, pred.height)
                    .map_err(|reason| EvalError::Frame { frame: name.clone(), reason: format!("LPIPS: {reason}") })?,
            );
            lpips_bands = idx;
        }
        if depth {
            depth_views.push((run.ds.frames[f].name.clone(), depth_errors(run, f, &rv.depth, mask.as_deref())?));
        }
        views.push(ViewEval {
            name: run.ds.frames[f].name.clone(),
            metrics,
            num_rays: rv.width * rv.height,
            render_seconds: Some(rv.seconds),
        });
    }
    let exp = run.ds.root.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let mut report = EvalReport::new(
        &exp,
        &format!("msnerf-{}", run.cfg.name),
        &run.checkpoint.display().to_string(),
        &run.ds.bands,
        &views,
        1.0,
    )?;
    if lpips.is_some() {
        let names: Vec<String> = lpips_bands.iter().map(|&b| run.ds.bands[b].name.clone()).collect();
        let note = format!("AlexNet LPIPS v0.1 on natural-colour composites (R, G, B = {})", names.join(", "));
        report.set_lpips_with_note(&lpips_values, &note)?;
    }
    if depth {
        report.depth = Some(DepthReport::new("median", &depth_views));
    }
    Ok(report)
}

/// Depth errors of frame `f`: its depth map (converted to distance along the ray when it stores z) against the
/// rendered median depth `rendered` (world units along the unit ray).
pub fn depth_errors(
    run: &LoadedRun,
    f: usize,
    rendered: &[f32],
    mask: Option<&[bool]>,
) -> Result<DepthErrors, EvalError> {
    let frame = &run.ds.frames[f];
    let frame_err = |reason: String| EvalError::Frame { frame: frame.name.clone(), reason };
    let mut truth = run.ds.read_depth(f)?.ok_or_else(|| frame_err("no depth map".into()))?;
    let cam = &frame.camera;
    if run.ds.depth_is_z && cam.model == crate::data::CameraModel::OpenCvFisheye {
        return Err(frame_err(
            "z-depth maps of fisheye cameras are not supported (use `depth_type: ray_distance`)".into(),
        ));
    }
    if run.ds.depth_is_z {
        let w = cam.width as usize;
        for (q, t) in truth.iter_mut().enumerate() {
            let ray = cam.ray_f64(&frame.c2w, (q / w) as u32, (q % w) as u32);
            *t = (*t as f64 * ray.direction_norm) as f32;
        }
    }
    DepthErrors::of_view(rendered, &truth, 0.5 * (cam.fx + cam.fy), mask).map_err(|e| frame_err(e.to_string()))
}
