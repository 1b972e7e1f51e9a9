//! What one training step sends to the device and gets back, in two persistent host buffers per step in flight
//! ([`crate::gpu::HostBuffer`]): the step's command buffer copies each chunk's inputs out of the first and its
//! outputs into the second, so a step is one submission with no staging round trip (issue 22).
//!
//! ```text
//! input:  pixels u32[3R] | camera per ray u32[R] | targets f32[R (B + 1)] | depth f32[2R] (with loss.depth)
//! output: ray outputs f32[R (RAY_OUT_FIXED + B)] | interlevel losses f32[P R] | guard flags u32[W] | pose
//!         regulariser losses f32[C]
//! ```
//! R is the batch's rays (the buffers grow to the largest batch seen), P the proposal levels, W the guard's flag
//! words, C the cameras. Sections start on 16-byte boundaries.

use super::buffers::RAY_OUT_FIXED;
use crate::gpu::{Context, GpuResult, HostBuffer, HostDirection};

/// Byte offsets of the sections for a batch of `rays` rays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepLayout {
    pub rays: usize,
    pub bands: usize,
    pub proposals: usize,
    pub flag_words: usize,
    pub cameras: usize,
    pub pixels: u64,
    pub cams: u64,
    pub targets: u64,
    pub depth: u64,
    pub input_bytes: u64,
    pub ray_out: u64,
    pub interlevel: u64,
    pub flags: u64,
    pub reg: u64,
    pub output_bytes: u64,
}

fn sections(sizes: &[u64]) -> (Vec<u64>, u64) {
    let mut at = Vec::with_capacity(sizes.len());
    let mut end = 0u64;
    for &s in sizes {
        at.push(end);
        end = (end + s).next_multiple_of(16);
    }
    (at, end.max(16))
}

impl StepLayout {
    pub fn new(rays: usize, bands: usize, proposals: usize, flag_words: usize, cameras: usize) -> Self {
        let r = rays as u64;
        let (i, input_bytes) = sections(&[12 * r, 4 * r, 4 * r * (bands as u64 + 1), 8 * r]);
        let (o, output_bytes) = sections(&[
            4 * r * (RAY_OUT_FIXED + bands) as u64,
            4 * r * proposals as u64,
            4 * flag_words as u64,
            4 * cameras as u64,
        ]);
        Self {
            rays,
            bands,
            proposals,
            flag_words,
            cameras,
            pixels: i[0],
            cams: i[1],
            targets: i[2],
            depth: i[3],
            input_bytes,
            ray_out: o[0],
            interlevel: o[1],
            flags: o[2],
            reg: o[3],
            output_bytes,
        }
    }

    /// Row length of the ray outputs (floats).
    pub fn ray_out_row(&self) -> usize {
        RAY_OUT_FIXED + self.bands
    }
}

/// One step's host buffers.
pub struct StepIo {
    pub layout: StepLayout,
    pub input: HostBuffer,
    pub output: HostBuffer,
}

impl StepIo {
    pub fn new(ctx: &Context, layout: StepLayout) -> GpuResult<Self> {
        Ok(Self {
            layout,
            input: HostBuffer::new(ctx, "step inputs", layout.input_bytes, HostDirection::ToDevice)?,
            output: HostBuffer::new(ctx, "step outputs", layout.output_bytes, HostDirection::ToHost)?,
        })
    }

    /// Writes a batch: pixel triples, each ray's camera for per-camera parameters, targets and depth targets
    /// (`depth` empty: none, zeros are written when the layout has room for them).
    pub fn write_batch(&mut self, pixels: &[u32], cams: &[u32], targets: &[f32], depth: &[f32]) -> GpuResult<()> {
        let l = self.layout;
        self.input.write(l.pixels, pixels)?;
        self.input.write(l.cams, cams)?;
        self.input.write(l.targets, targets)?;
        if depth.is_empty() {
            self.input.write(l.depth, &vec![0.0f32; 2 * cams.len()])?;
        } else {
            self.input.write(l.depth, depth)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sections_are_aligned_and_disjoint() {
        let l = StepLayout::new(1001, 6, 2, 23, 7);
        let ins = [(l.pixels, 12 * 1001), (l.cams, 4 * 1001), (l.targets, 4 * 1001 * 7), (l.depth, 8 * 1001)];
        let outs =
            [(l.ray_out, 4 * 1001 * (RAY_OUT_FIXED as u64 + 6)), (l.interlevel, 8 * 1001), (l.flags, 92), (l.reg, 28)];
        for secs in [&ins[..], &outs[..]] {
            for w in secs.windows(2) {
                assert_eq!(w[1].0 % 16, 0);
                assert!(w[0].0 + w[0].1 <= w[1].0, "{secs:?}");
            }
        }
        assert!(ins[3].0 + ins[3].1 <= l.input_bytes && outs[3].0 + outs[3].1 <= l.output_bytes);
    }
}
