//! A trained run loaded back from its folder (config.yaml, dataset.json, checkpoints/latest.msnp): the dataset,
//! the pose normalisation and a [`Pipeline`] with the trained parameters, plus whole-view rendering of dataset
//! frames and of novel views (orbits, camera paths).

use super::config::ModelConfig;
use super::error::{NerfError, NerfResult};
use super::model::Model;
use super::pipeline::Pipeline;
use super::rays::GpuCamera;
use super::rig_rays::RigRays;
use super::trainer::{camera_table, load_run_dataset};
use super::views::NovelView;
use crate::data::{Dataset, PoseTransform};
use crate::gpu::{Context, GpuResult};
use std::path::{Path, PathBuf};
use std::time::Instant;

pub struct LoadedRun {
    pub dir: PathBuf,
    pub cfg: ModelConfig,
    pub ds: Dataset,
    pub transform: PoseTransform,
    pub pipe: Pipeline,
    pub checkpoint: PathBuf,
    /// Novel views in the camera table after the dataset's cameras (see [`LoadedRun::set_novel_views`]).
    pub novel: Vec<NovelView>,
    /// The dataset's cameras in the table: its frames, then, with `rig_cameras`, every frame's band cameras.
    dataset_cameras: usize,
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

/// The step a run's checkpoint was written after (`checkpoints/latest.json`'s `step`); errors name the file.
fn trained_step(path: &Path) -> NerfResult<u64> {
    let text = std::fs::read_to_string(path).map_err(|e| NerfError::file(path, e))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| NerfError::file(path, e))?;
    v["step"].as_u64().ok_or_else(|| NerfError::key(path, "step", "missing or not a step count"))
}

/// Refuses a dataset that is not the one the run trained on, by what the run's `dataset.json` recorded: the band
/// names in order, the image size and the training and held-out frames. A dataset re-imported with other bands,
/// or `dataset.json` pointed at another flight, would otherwise render the model's bands under the wrong names.
pub fn check_run_dataset(info_path: &Path, info: &serde_json::Value, ds: &crate::data::Dataset) -> NerfResult<()> {
    let names: Vec<&str> = ds.bands.iter().map(|b| b.name.as_str()).collect();
    if let Some(recorded) = info["bands"].as_array() {
        let was: Vec<&str> = recorded.iter().map(|b| b["name"].as_str().unwrap_or("?")).collect();
        if was != names {
            return Err(NerfError::key(
                info_path,
                "bands",
                format!(
                    "the run trained on bands [{}], the dataset at `data` now has [{}]: not the dataset of this run \
                     (resuming a run trained with `--bands`? give the same `--bands` again)",
                    was.join(", "),
                    names.join(", ")
                ),
            ));
        }
    }
    for (key, now) in [("width", ds.width as u64), ("height", ds.height as u64)] {
        if let Some(was) = info[key].as_u64().filter(|&w| w != now) {
            return Err(NerfError::key(
                info_path,
                key,
                format!(
                    "the run trained on images of {key} {was}, the dataset's have {now}: not the dataset of this run"
                ),
            ));
        }
    }
    for (key, split) in [("train_frames", crate::data::Split::Train), ("eval_frames", crate::data::Split::Eval)] {
        let now = ds.split_indices(split);
        if let Ok(was) = serde_json::from_value::<Vec<usize>>(info[key].clone()) {
            if was != now {
                return Err(NerfError::key(
                    info_path,
                    key,
                    format!(
                        "the run's {} frames differ from the dataset's {} now (frames added, removed or re-split): \
                         not the dataset of this run",
                        was.len(),
                        now.len()
                    ),
                ));
            }
        }
    }
    Ok(())
}

impl LoadedRun {
    /// Loads `dir`; errors name the file that is missing or malformed.
    pub fn load(ctx: &Context, dir: &Path) -> NerfResult<Self> {
        if !dir.join("config.yaml").is_file() || !dir.join("checkpoints/latest.msnp").is_file() {
            return Err(NerfError::file(
                dir,
                "not a run folder (it needs config.yaml and checkpoints/latest.msnp, as `msnerf train` writes)",
            ));
        }
        let cfg = ModelConfig::load(&dir.join("config.yaml"))?;
        let info_path = dir.join("dataset.json");
        let info: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(&info_path)
                .map_err(|e| NerfError::file(&info_path, format!("{e} (is this a run folder?)")))?,
        )
        .map_err(|e| NerfError::file(&info_path, e))?;
        let data = info["data"].as_str().ok_or_else(|| NerfError::key(&info_path, "data", "missing"))?;
        // `band_indices`: the run trained on these bands only (`msnerf train --bands`, sweep axis `bands`).
        let band_indices: Option<Vec<usize>> = serde_json::from_value(info["band_indices"].clone())
            .map_err(|e| NerfError::key(&info_path, "band_indices", e))?;
        let mut ds = load_run_dataset(Path::new(data), band_indices.as_deref(), &cfg.sampling)?;
        check_run_dataset(&info_path, &info, &ds)?;
        ds.options.alpha_background = cfg.rendering.alpha_background(false);
        let checkpoint = dir.join("checkpoints/latest.msnp");
        let mut model = Model::new(ctx, &cfg, ds.n_bands(), ds.frames.len())?;
        model.store.load(&checkpoint)?;
        let table = camera_table(&ds);
        let dataset_cameras = table.len();
        let mut pipe = Pipeline::new(ctx, model, &table).map_err(NerfError::gpu("building the pipeline"))?;
        pipe.appearance_rows = Some(ds.split_indices(crate::data::Split::Train));
        if cfg.field.coarse_to_fine.is_some() {
            // The grid's levels as the last trained step weighted them (the trainer state beside the checkpoint).
            pipe.set_step(trained_step(&dir.join("checkpoints/latest.json"))?);
        }
        let transform = ds.pose_transform();
        Ok(Self { dir: dir.to_path_buf(), cfg, ds, transform, pipe, checkpoint, novel: Vec::new(), dataset_cameras })
    }

    /// Renders every pixel of frame `frame` through the frame camera (with `rig_cameras`, every band registered to
    /// it: what renders, clouds and orthophotos show).
    pub fn render_view(&mut self, frame: usize) -> NerfResult<RenderedView> {
        let (w, h) = (self.ds.width as usize, self.ds.height as usize);
        self.render_camera(frame, w, h).map_err(NerfError::gpu(format!("rendering frame {frame}")))
    }

    /// Renders frame `frame` as its image file holds it: without `rig_cameras` the frame camera's view
    /// ([`LoadedRun::render_view`]); with them band b from band b's own camera (B renders, each keeping one band), so
    /// that it compares pixel for pixel with the dataset's unregistered image. Depth and accumulation are the frame
    /// camera's.
    pub fn render_observed_view(&mut self, frame: usize) -> NerfResult<RenderedView> {
        let Some(rig) = RigRays::new(&self.ds) else { return self.render_view(frame) };
        let mut view = self.render_view(frame)?;
        let (w, h, b_n) = (view.width, view.height, self.ds.n_bands());
        // Bands seen through the frame camera are already right in the frame camera's view.
        for b in (0..b_n).filter(|&b| !rig.frame_bands()[b]) {
            let cam = rig.camera(frame, b) as usize;
            let band = self.render_camera(cam, w, h).map_err(NerfError::gpu(format!("rendering frame {frame}")))?;
            for p in 0..w * h {
                view.colour[p * b_n + b] = band.colour[p * b_n + b];
            }
            view.seconds += band.seconds;
        }
        Ok(view)
    }

    /// Puts `views` in the pipeline's camera table after the dataset's cameras (replacing earlier novel views), so
    /// that [`LoadedRun::render_novel_view`] can render them.
    pub fn set_novel_views(&mut self, views: &[NovelView]) -> NerfResult<()> {
        let mut table = camera_table(&self.ds);
        for v in views {
            let c2w: [[f32; 4]; 3] = [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| v.c2w[r][c] as f32));
            table.push(GpuCamera::new(&v.camera, &c2w));
        }
        self.pipe.set_cameras(&table).map_err(NerfError::gpu("camera table"))?;
        self.novel = views.to_vec();
        Ok(())
    }

    /// The camera-table index of novel view `k` of the last [`LoadedRun::set_novel_views`].
    pub fn novel_camera(&self, k: usize) -> u32 {
        (self.dataset_cameras + k) as u32
    }

    /// Renders novel view `k` of the last [`LoadedRun::set_novel_views`] at its own size; `frame` of the result is
    /// its index in the camera table.
    pub fn render_novel_view(&mut self, k: usize) -> NerfResult<RenderedView> {
        let v = self.novel.get(k).ok_or_else(|| NerfError::invalid(format!("novel view {k}"), "was not set"))?;
        let (w, h, name) = (v.camera.width as usize, v.camera.height as usize, v.name.clone());
        self.render_camera(self.dataset_cameras + k, w, h).map_err(NerfError::gpu(format!("rendering {name}")))
    }

    fn render_camera(&mut self, cam: usize, w: usize, h: usize) -> GpuResult<RenderedView> {
        let pixels: Vec<u32> =
            (0..h as u32).flat_map(|r| (0..w as u32).flat_map(move |c| [cam as u32, r, c])).collect();
        let t = Instant::now();
        let out = self.pipe.render(&pixels)?;
        let scale = 1.0 / self.transform.scale as f32;
        Ok(RenderedView {
            frame: cam,
            width: w,
            height: h,
            colour: out.colour,
            accumulation: out.accumulation,
            depth: out.median_depth.iter().map(|d| d * scale).collect(),
            seconds: t.elapsed().as_secs_f64(),
        })
    }
}
