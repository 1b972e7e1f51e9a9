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
    /// Word i + 1 names `names[i]`.
    names: Vec<String>,
    pub flags: GpuBuffer<u32>,
    n_proposals: usize,
}

impl Guard {
    /// Flag words of a guard over `n_proposals` proposal levels and `grad_chunks` gradient chunks (the VRAM plan).
    pub fn word_count(n_proposals: usize, grad_chunks: usize) -> usize {
        Self::names(n_proposals, grad_chunks).len() + 1
    }

    fn names(n_proposals: usize, grad_chunks: usize) -> Vec<String> {
        let mut names = vec!["ray directions".to_owned()];
        for i in 0..n_proposals {
            names.extend([
                format!("proposal {i} encoding"),
                format!("proposal {i} density"),
                format!("proposal {i} weights"),
            ]);
        }
        names.extend(
            ["nerf encoding", "nerf density", "colour output", "nerf weights", "ray outputs"].map(String::from),
        );
        names.extend(["interlevel losses", "pose regulariser losses"].map(String::from));
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

    fn slot(&self, name: &str) -> usize {
        1 + self.names.iter().position(|n| n == name).expect("a guard name")
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
        let part = |len: usize| len * r / b.rays.max(1);
        record_check_finite_slot(rec, &b.ray_out, part(b.ray_out.len()), &self.flags, self.slot("ray outputs"), false)?;
        if update_props {
            for pl in &b.proposals {
                if let Some(l) = &pl.losses {
                    record_check_finite_slot(rec, l, r, &self.flags, self.slot("interlevel losses"), false)?;
                }
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
        if let Some(pb) = b.pose.as_ref().filter(|_| n_reg > 0) {
            let slot = self.slot("pose regulariser losses");
            record_check_finite_slot(rec, &pb.reg_losses, n_reg, &self.flags, slot, false)?;
        }
        // The checks only ever write 1 into the flag words: no barrier among those of one group. The gated group
        // must see every ungated verdict, so it comes after a barrier.
        rec.independent(|rec| {
            for (i, c) in store.grads().chunks().iter().enumerate() {
                let slot = self.slot(&format!("parameter gradients (chunk {i})"));
                record_check_finite_slot(rec, c, c.len(), &self.flags, slot, false)?;
            }
            Ok(())
        })?;
        let part = |buf: &GpuBuffer<f32>| buf.len() * r / b.rays.max(1);
        let mut named: Vec<(String, &GpuBuffer<f32>)> = vec![("ray directions".into(), &b.dirs)];
        for (i, pl) in b.proposals.iter().enumerate().take(self.n_proposals) {
            named.push((format!("proposal {i} encoding"), &pl.enc));
            named.push((format!("proposal {i} density"), &pl.raw));
            named.push((format!("proposal {i} weights"), &pl.weights));
        }
        named.push(("nerf encoding".into(), &b.nerf.enc));
        named.push(("nerf density".into(), &b.nerf.raw));
        named.push(("colour output".into(), &b.colour.out));
        named.push(("nerf weights".into(), &b.nerf.weights));
        rec.independent(|rec| {
            for (name, buf) in named {
                record_check_finite_slot(rec, buf, part(buf), &self.flags, self.slot(&name), true)?;
            }
            Ok(())
        })
    }

    /// The first poisoned buffer in pipeline order, from the flag words read back; `None` on a clean step.
    pub fn first_named(&self, words: &[u32]) -> Option<String> {
        if words.first().is_none_or(|&w| w == 0) {
            return None;
        }
        let named = self.names.iter().zip(&words[1..]).find(|(_, &w)| w != 0).map(|(n, _)| n.clone());
        Some(named.unwrap_or_else(|| "parameter gradients".into()))
    }
}
