//! The training step's NaN/Inf guard, on the device and in the step's own submission (issue 22: no extra round trip,
//! and a verdict the host may read a step or two later).
//!
//! A flag buffer: word 0 is "this step is poisoned", every other word names one buffer. In recording order:
//! - after each chunk, its ray outputs (losses, colours, depths) and, on proposal-update steps, its interlevel
//!   losses are checked (ungated);
//! - after the last chunk, the pose regulariser's losses and every gradient chunk (ungated);
//! - then, gated on word 0 (a no-op on a clean step), the last chunk's intermediate buffers in pipeline order.
//!
//! Adam reads word 0 and skips the update when it is set ([`crate::nn::adam::step_gated`]). The host reads the words
//! back with the losses and names the first poisoned buffer in pipeline order ([`Guard::first_named`]): ray
//! directions, each proposal's encoding, density and weights, the NeRF level's, the ray outputs, the interlevel
//! losses, the pose regulariser, then the gradient chunks. Each check covers the part of its buffer the chunk wrote.

use super::buffers::{ChunkBuffers, GpuAlloc};
use crate::gpu::{GpuBuffer, GpuResult, MemoryCategory, Recorder};
use crate::nn::params::ParamStore;
use crate::ops::record_check_finite_slot;

/// Flag word 0: something in this step was non-finite.
pub const ANY: usize = 0;

pub struct Guard {
    /// Word i + 1 names `names[i]`, in pipeline order.
    names: Vec<String>,
    pub flags: GpuBuffer<u32>,
    n_proposals: usize,
}

/// Where each kind of check writes: the intermediates first (slots 1 ..= 4 + 3P, in the order
/// [`intermediates`] lists them), then these (`names` follows the same order).
struct Slots {
    ray_out: usize,
    interlevel: usize,
    pose_reg: usize,
    grad0: usize,
}

impl Slots {
    fn of(n_proposals: usize) -> Self {
        let ray_out = 1 + intermediate_names(n_proposals).len();
        Self { ray_out, interlevel: ray_out + 1, pose_reg: ray_out + 2, grad0: ray_out + 3 }
    }
}

/// The names of the gated intermediates, in pipeline order.
fn intermediate_names(n_proposals: usize) -> Vec<String> {
    let mut names = vec!["ray directions".to_owned()];
    for i in 0..n_proposals {
        names.extend(["encoding", "density", "weights"].map(|w| format!("proposal {i} {w}")));
    }
    names.extend(["nerf encoding", "nerf density", "colour output", "nerf weights"].map(String::from));
    names
}

/// The gated intermediates' buffers, in the order of [`intermediate_names`].
fn intermediates(b: &ChunkBuffers<GpuAlloc>) -> Vec<&GpuBuffer<f32>> {
    let mut bufs = vec![&b.dirs];
    for pl in &b.proposals {
        bufs.extend([&pl.enc, &pl.raw, &pl.weights]);
    }
    bufs.extend([&b.nerf.enc, &b.nerf.raw, &b.colour.out, &b.nerf.weights]);
    bufs
}

impl Guard {
    /// Flag words of a guard over `n_proposals` proposal levels and `grad_chunks` gradient chunks (the VRAM plan).
    pub fn word_count(n_proposals: usize, grad_chunks: usize) -> usize {
        Self::names(n_proposals, grad_chunks).len() + 1
    }

    fn names(n_proposals: usize, grad_chunks: usize) -> Vec<String> {
        let mut names = intermediate_names(n_proposals);
        names.extend(["ray outputs", "interlevel losses", "pose regulariser losses"].map(String::from));
        names.extend((0..grad_chunks).map(|i| format!("parameter gradients (chunk {i})")));
        names
    }

    pub fn new(ctx: &crate::gpu::Context, n_proposals: usize, grad_chunks: usize) -> GpuResult<Self> {
        let names = Self::names(n_proposals, grad_chunks);
        let flags = GpuBuffer::new(
            ctx,
            &crate::gpu::BufferDesc { name: "NaN guard flags", len: names.len() + 1, category: MemoryCategory::Other },
        )?;
        Ok(Self { names, flags, n_proposals })
    }

    /// Flag words (word 0 included).
    pub fn words(&self) -> usize {
        self.names.len() + 1
    }

    /// Zeroes every flag (first thing in a step).
    pub fn record_reset(&self, rec: &mut Recorder) -> GpuResult<()> {
        crate::ops::fill(rec, &self.flags, 0u32, 0, self.words())
    }

    /// The ungated checks of one chunk of `r` rays: its ray outputs and its interlevel losses.
    pub fn record_chunk(
        &self,
        rec: &mut Recorder,
        b: &ChunkBuffers<GpuAlloc>,
        r: usize,
        update_props: bool,
    ) -> GpuResult<()> {
        let slots = Slots::of(self.n_proposals);
        let part = |len: usize| len * r / b.rays.max(1);
        record_check_finite_slot(rec, &b.ray_out, part(b.ray_out.len()), &self.flags, slots.ray_out, false)?;
        if update_props {
            for l in b.proposals.iter().filter_map(|pl| pl.losses.as_ref()) {
                record_check_finite_slot(rec, l, r, &self.flags, slots.interlevel, false)?;
            }
        }
        Ok(())
    }

    /// The end of a step: the regulariser's `n_reg` losses and every gradient chunk (ungated), then the last
    /// chunk's (`r` rays) intermediate buffers, gated.
    pub fn record_end(
        &self,
        rec: &mut Recorder,
        b: &ChunkBuffers<GpuAlloc>,
        r: usize,
        store: &ParamStore,
        n_reg: usize,
    ) -> GpuResult<()> {
        let slots = Slots::of(self.n_proposals);
        if let Some(pb) = b.pose.as_ref().filter(|_| n_reg > 0) {
            record_check_finite_slot(rec, &pb.reg_losses, n_reg, &self.flags, slots.pose_reg, false)?;
        }
        // The checks only ever write 1 into the flag words: no barrier among those of one group. The gated group
        // must see every ungated verdict, so it comes after a barrier.
        rec.independent(|rec| {
            for (i, c) in store.grads().chunks().iter().enumerate() {
                record_check_finite_slot(rec, c, c.len(), &self.flags, slots.grad0 + i, false)?;
            }
            Ok(())
        })?;
        let part = |buf: &GpuBuffer<f32>| buf.len() * r / b.rays.max(1);
        rec.independent(|rec| {
            for (i, buf) in intermediates(b).into_iter().enumerate() {
                record_check_finite_slot(rec, buf, part(buf), &self.flags, 1 + i, true)?;
            }
            Ok(())
        })
    }

    /// The first poisoned buffer in pipeline order, from the flag words read back; `None` on a clean step.
    pub fn first_named(&self, words: &[u32]) -> Option<String> {
        if words.get(ANY).is_none_or(|&w| w == 0) {
            return None;
        }
        let named = self.names.iter().zip(&words[1..]).find(|(_, &w)| w != 0).map(|(n, _)| n.clone());
        Some(named.unwrap_or_else(|| "parameter gradients".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_follow_the_names() {
        for p in 0..3 {
            let names = Guard::names(p, 2);
            let slots = Slots::of(p);
            let at = |n: &str| 1 + names.iter().position(|x| x == n).expect("named");
            assert_eq!(slots.ray_out, at("ray outputs"));
            assert_eq!(slots.interlevel, at("interlevel losses"));
            assert_eq!(slots.pose_reg, at("pose regulariser losses"));
            assert_eq!(slots.grad0, at("parameter gradients (chunk 0)"));
            assert_eq!(slots.grad0 + 1, at("parameter gradients (chunk 1)"));
            assert_eq!(at("nerf weights") + 1, slots.ray_out, "the intermediates come first");
        }
    }
}
