//! Rig-aware rays (issue 19): for a dataset with `rig_cameras` ([`crate::data::rig_cameras`]) every band of every
//! frame is a camera of its own in the camera table, after the frames: band b of frame f at
//! `frames + f * B + b`, its pose `frame pose · rig_from_band`, its own intrinsics. A training ray then comes from
//! one band's camera and observes that band only: its other targets are NaN, which the loss reads as "not
//! observed" (glsl/render/composite.comp). Per-camera parameters (pose corrections, appearance) stay per frame: a
//! ray's camera for them is its frame.
//!
//! Ray i of a batch observes band `i % B`, so every band gets the same share of each batch and eq. 3.1's per-band
//! means weigh the bands equally. Rays that carry a depth target from the frame's depth map or sparse points are
//! frame-camera rays; their observed bands are those whose camera is the frame camera ([`RigRays::frame_bands`]).

use super::pipeline::Batch;
use super::rays::GpuCamera;
use crate::data::rig_cameras::band_c2w;
use crate::data::{Dataset, PixelBatch};

/// The rig's cameras as the trainer addresses them.
#[derive(Clone, Debug)]
pub struct RigRays {
    frames: usize,
    bands: usize,
    /// Per band: its camera is the frame camera (for every frame).
    frame_camera: Vec<bool>,
}

impl RigRays {
    /// `None` when the dataset has no `rig_cameras`.
    pub fn new(ds: &Dataset) -> Option<Self> {
        ds.rig.as_ref()?;
        let bands = ds.n_bands();
        let frame_camera = (0..bands)
            .map(|b| {
                let cam = ds.band_camera(b).expect("the dataset has a rig");
                ds.frames.iter().all(|f| cam.is_frame_camera(&f.camera))
            })
            .collect();
        Some(Self { frames: ds.frames.len(), bands, frame_camera })
    }

    /// Camera-table index of band `b` of frame `f`.
    pub fn camera(&self, f: usize, b: usize) -> u32 {
        (self.frames + f * self.bands + b) as u32
    }

    /// The bands a frame-camera ray observes.
    pub fn frame_bands(&self) -> &[bool] {
        &self.frame_camera
    }

    /// The band cameras of every frame (normalised frame), in table order, to append after the frames' cameras.
    pub fn table(ds: &Dataset) -> Vec<GpuCamera> {
        let t = ds.pose_transform();
        let mut out = Vec::new();
        if ds.rig.is_none() {
            return out;
        }
        for f in &ds.frames {
            for b in 0..ds.n_bands() {
                let cam = ds.band_camera(b).expect("the dataset has a rig");
                let m = t.pose_to_normalized(&band_c2w(&f.c2w, cam));
                let c2w: [[f32; 4]; 3] = [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| m[r][c] as f32));
                out.push(GpuCamera::new(&cam.camera, &c2w));
            }
        }
        out
    }

    /// Appends the pixels of `px` to `batch` as rig rays: pixel i (ray `first + i` of the batch) through band
    /// `(first + i) % B`'s camera, or, with `frame_rays` (rays drawn for their depth targets), through the frame
    /// camera. `depth` gives a ray's depth target `(d, s)`; band-camera rays get one only when their band's camera is
    /// the frame camera.
    pub fn push(
        &self,
        batch: &mut Batch,
        px: &PixelBatch,
        frame_rays: bool,
        mut depth: Option<&mut dyn FnMut(usize, u32, u32) -> [f32; 2]>,
    ) {
        let b_n = self.bands;
        for i in 0..px.image.len() {
            let (f, row, col) = (px.image[i] as usize, px.row[i], px.col[i]);
            let values = &px.values[i * b_n..(i + 1) * b_n];
            let weight = if px.mask[i] == 0 { 0.0 } else { 1.0 };
            let band = batch.rays() % b_n;
            let observed = |b: usize| if frame_rays { self.frame_camera[b] } else { b == band };
            let cam = if frame_rays { f as u32 } else { self.camera(f, band) };
            batch.pixels.extend([cam, row, col]);
            batch.cameras.push(f as u32);
            batch.targets.extend((0..b_n).map(|b| if observed(b) { values[b] } else { f32::NAN }));
            batch.targets.push(weight);
            if let Some(d) = depth.as_mut() {
                let with_depth = frame_rays || self.frame_camera[band];
                batch.depth.extend(if with_depth { d(f, row, col) } else { [0.0, 1.0] });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two frames, three bands, band 0 seen through the frame camera: ray i observes band i % 3 through its camera
    /// (after the two frame cameras), carries its frame for per-camera parameters, NaN for the other bands and a
    /// depth target only where its band's camera is the frame camera; depth rays are frame-camera rays.
    #[test]
    fn rig_rays_observe_one_band_through_its_camera() {
        let rig = RigRays { frames: 2, bands: 3, frame_camera: vec![true, false, false] };
        let px = PixelBatch {
            bands: 3,
            image: vec![1, 0, 1, 1],
            row: vec![5, 6, 7, 8],
            col: vec![9, 10, 11, 12],
            values: (0..12).map(|v| v as f32 / 10.0).collect(),
            mask: vec![1, 1, 0, 1],
        };
        let mut batch = Batch::default();
        let mut column = |f: usize, row: u32, _col: u32| [f as f32 + row as f32, 0.5];
        let depth: &mut dyn FnMut(usize, u32, u32) -> [f32; 2] = &mut column;
        rig.push(&mut batch, &px, false, Some(&mut *depth));
        assert_eq!(batch.pixels, [2 + 3, 5, 9, 2 + 1, 6, 10, 2 + 3 + 2, 7, 11, 2 + 3, 8, 12]);
        assert_eq!(batch.cameras, [1, 0, 1, 1]);
        for i in 0..batch.rays() {
            let t = batch.band_targets(i);
            for (b, v) in t.iter().enumerate() {
                assert_eq!(v.is_finite(), b == i % 3, "ray {i} band {b}");
            }
            assert_eq!(t[i % 3], px.values[i * 3 + i % 3]);
            assert_eq!(batch.ray_weight(i), if i == 2 { 0.0 } else { 1.0 });
        }
        assert_eq!(batch.depth, [6.0, 0.5, 0.0, 1.0, 0.0, 1.0, 9.0, 0.5]);
        assert_eq!((batch.depth_target(0), batch.depth_target(1)), (Some((6.0, 0.5)), None));
        // Depth rays: the frame camera, the frame-camera bands observed.
        let mut depth_rays = Batch::default();
        rig.push(&mut depth_rays, &px, true, Some(depth));
        assert_eq!(depth_rays.pixel(0), [1, 5, 9]);
        assert!((0..depth_rays.rays()).all(|i| {
            let t = depth_rays.band_targets(i);
            t[0].is_finite() && t[1].is_nan() && t[2].is_nan()
        }));
        assert_eq!(depth_rays.depth[..2], [6.0, 0.5]);
    }
}
