//! A trained run loaded back from its folder (config.yaml, dataset.json, checkpoints/latest.msnp): the dataset,
//! the pose normalisation and a [`Pipeline`] with the trained parameters, plus whole-view rendering.

use super::config::ModelConfig;
use super::model::Model;
use super::pipeline::Pipeline;
use super::trainer::{camera_table, load_run_dataset};
use crate::data::{Dataset, PoseTransform};
use crate::gpu::Context;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub struct LoadedRun {
    pub dir: PathBuf,
    pub cfg: ModelConfig,
    pub ds: Dataset,
    pub transform: PoseTransform,
    pub pipe: Pipeline,
    pub checkpoint: PathBuf,
}

/// One rendered view (pixel-interleaved, row-major).
pub struct RenderedView {
    pub frame: usize,
    pub width: usize,
    pub height: usize,
    /// width x height x B
    pub colour: Vec<f32>,
    pub accumulation: Vec<f32>,
    /// Distance along the unit ray (dataset units after mapping back: see `LoadedRun::to_world_distance`).
    pub depth: Vec<f32>,
    pub seconds: f64,
}

impl LoadedRun {
    /// Loads `dir`; errors name the file that is missing or malformed.
    pub fn load(ctx: &Context, dir: &Path) -> Result<Self, String> {
        if !dir.join("config.yaml").is_file() || !dir.join("checkpoints/latest.msnp").is_file() {
            return Err(format!(
                "{}: not a run folder (it needs config.yaml and checkpoints/latest.msnp, as `msnerf train` writes)",
                dir.display()
            ));
        }
        let cfg = ModelConfig::load(&dir.join("config.yaml"))?;
        let info_path = dir.join("dataset.json");
        let info: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(&info_path)
                .map_err(|e| format!("{}: {e} (is this a run folder?)", info_path.display()))?,
        )
        .map_err(|e| format!("{}: {e}", info_path.display()))?;
        let data = info["data"].as_str().ok_or_else(|| format!("{}: key `data` missing", info_path.display()))?;
        // `band_indices`: the run trained on these bands only (`msnerf train --bands`, sweep axis `bands`).
        let band_indices: Option<Vec<usize>> = serde_json::from_value(info["band_indices"].clone())
            .map_err(|e| format!("{}: key `band_indices`: {e}", info_path.display()))?;
        let ds = load_run_dataset(Path::new(data), band_indices.as_deref())?;
        let checkpoint = dir.join("checkpoints/latest.msnp");
        let mut model = Model::new(ctx, &cfg, ds.n_bands(), ds.frames.len()).map_err(|e| e.to_string())?;
        model.store.load(&checkpoint).map_err(|e| e.to_string())?;
        let pipe = Pipeline::new(ctx, model, &camera_table(&ds)).map_err(|e| e.to_string())?;
        let transform = ds.pose_transform();
        Ok(Self { dir: dir.to_path_buf(), cfg, ds, transform, pipe, checkpoint })
    }

    /// Renders every pixel of frame `frame` (its own camera and pose).
    pub fn render_view(&mut self, frame: usize) -> Result<RenderedView, String> {
        let (w, h) = (self.ds.width as usize, self.ds.height as usize);
        let pixels: Vec<u32> =
            (0..h as u32).flat_map(|r| (0..w as u32).flat_map(move |c| [frame as u32, r, c])).collect();
        let t = Instant::now();
        let out = self.pipe.render(&pixels).map_err(|e| format!("rendering frame {frame}: {e}"))?;
        let scale = 1.0 / self.transform.scale as f32;
        Ok(RenderedView {
            frame,
            width: w,
            height: h,
            colour: out.colour,
            accumulation: out.accumulation,
            depth: out.median_depth.iter().map(|d| d * scale).collect(),
            seconds: t.elapsed().as_secs_f64(),
        })
    }
}
