//! Multispectral point clouds from a trained run (nerfstudio `ns-export pointcloud`, spec/nerfacto.md §6.7): render
//! training rays, keep those whose accumulation passes a threshold, place a point at the median depth, and carry
//! every band's value; positions go back to the dataset's own world frame and units. With `normals`, each point also
//! gets the density field's normal there ([`super::normals`]), facing the camera that saw it, rotated back into the
//! world frame.

use super::normals::{density_gradients, normal_from_gradient};
use super::run::LoadedRun;
use crate::data::Split;
use crate::output::pointcloud::PointCloud;
use rand::{Rng, SeedableRng};

#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// Points to draw before filtering.
    pub rays: usize,
    /// Minimum accumulation (opacity) of a ray for its point to be kept.
    pub min_accumulation: f32,
    pub seed: u64,
    /// Also compute each point's surface normal from the density field.
    pub normals: bool,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self { rays: 200_000, min_accumulation: 0.5, seed: 42, normals: false }
    }
}

/// Renders random training pixels and returns the kept points (world frame) with their band values.
pub fn export_points(run: &mut LoadedRun, opts: &ExportOptions) -> Result<PointCloud, String> {
    let frames = run.ds.split_indices(Split::Train);
    if frames.is_empty() {
        return Err(format!("{}: no training frames to export from", run.ds.transforms_path.display()));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.seed);
    let (w, h) = (run.ds.width, run.ds.height);
    let mut pixels = Vec::with_capacity(opts.rays * 3);
    for _ in 0..opts.rays {
        pixels.extend([
            frames[rng.random_range(0..frames.len())] as u32,
            rng.random_range(0..h),
            rng.random_range(0..w),
        ]);
    }
    let out = run.pipe.render(&pixels).map_err(|e| format!("rendering export rays: {e}"))?;
    let bands = run.ds.bands.clone();
    let b = bands.len();
    let mut positions = Vec::new();
    let mut normalised = Vec::new();
    let mut view_dirs = Vec::new();
    let mut values = Vec::new();
    for i in 0..opts.rays {
        if out.accumulation[i] < opts.min_accumulation || !out.median_depth[i].is_finite() {
            continue;
        }
        let (f, row, col) = (pixels[3 * i] as usize, pixels[3 * i + 1], pixels[3 * i + 2]);
        let c2w = run.transform.pose_to_normalized(&run.ds.frames[f].c2w);
        let ray = run.ds.frames[f].camera.ray_f64(&c2w, row, col);
        let t = out.median_depth[i] as f64;
        let p = [0, 1, 2].map(|k| ray.origin[k] + ray.direction[k] * t);
        positions.push(run.transform.to_world(p));
        normalised.push(p);
        view_dirs.push(ray.direction);
        values.extend_from_slice(&out.colour[i * b..(i + 1) * b]);
    }
    let mut cloud = PointCloud::new(positions, bands, values).map_err(|e| e.to_string())?;
    if opts.normals {
        let grads = density_gradients(&run.pipe.ctx, &run.pipe.model, &normalised)
            .map_err(|e| format!("density normals: {e}"))?;
        let normals = grads
            .iter()
            .zip(&view_dirs)
            .map(|(&g, &d)| {
                // A vanishing gradient (empty space) has no normal: written as (0, 0, 0).
                normal_from_gradient(g, d).map_or([0.0; 3], |n| run.transform.direction_to_world(n).map(|v| v as f32))
            })
            .collect();
        cloud.normals = Some(normals);
    }
    Ok(cloud)
}
