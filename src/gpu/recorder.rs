//! `Recorder`: records a sequence of kernel dispatches (and copies between [`HostBuffer`]s and device buffers) into
//! one command buffer, then submits it: [`Recorder::submit_and_wait`] blocks, [`Recorder::submit`] returns an
//! [`InFlight`] that owns the command buffer and everything it uses until [`InFlight::wait`] (so the host can
//! record the next sequence while this one runs).
//! - Barriers: a compute-to-compute memory barrier goes in before a dispatch that binds a buffer an earlier
//!   dispatch since the last barrier also bound (every binding counts as read-write: conservative and simple).
//!   Independent dispatches run without one, and so do the members of a [`Recorder::independent`] group (the
//!   caller states they do not depend on each other, e.g. a hash grid's levels).
//! - Descriptors: pushed with VK_KHR_push_descriptor, or allocated from per-recorder pools when the device
//!   lacks it (or `MSNERF_DISABLE_PUSH_DESCRIPTOR=1`).
//! - Timing: a GPU timestamp after every dispatch, reported per named dispatch ([`TimingReport`]); on by default
//!   where the queue has timestamps, off with [`Context::recorder_timed`] (`false`) for steps not being profiled.
//! - Copies: [`Recorder::copy_in`] (host buffer to device buffer, before the dispatches that read it) and
//!   [`Recorder::copy_out`] (device buffer to host buffer). Copies recorded back to back form a group between two
//!   barriers (so the copies of one group must not depend on each other); a submission with copies out ends with a
//!   barrier that makes them visible to the host.
//! - Temporaries handed to [`Recorder::keep_alive`] live until the work completes.

use super::buffer::Binding;
use super::context::{Context, MAX_BINDINGS, TEXEL_BINDINGS, TEXEL_BINDING_BASE};
use super::error::{GpuError, GpuResult, VkCheck};
use super::host_buffer::HostBuffer;
use super::host_clock::HostWork;
use super::kernel::{fold_groups, Kernel};
use super::timing::{DispatchTime, TimingReport};
use ash::vk;
use bytemuck::Pod;
use std::any::Any;
use std::time::Instant;

const QUERIES_PER_POOL: u32 = 1024;
const SETS_PER_POOL: u32 = 256;

pub struct Recorder<'a> {
    ctx: &'a Context,
    /// This recorder's own command pool (one thread at a time may use a pool) and its command buffer.
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    label: String,
    /// Buffers bound since the last barrier.
    touched: Vec<vk::Buffer>,
    barriers: u32,
    names: Vec<&'static str>,
    query_pools: Vec<vk::QueryPool>,
    desc_pools: Vec<vk::DescriptorPool>,
    sets_in_pool: u32,
    keep: Vec<Box<dyn Any>>,
    timing: bool,
    finished: bool,
    /// A copy into a host buffer was recorded: the submission ends with a transfer-to-host barrier.
    copies_out: bool,
    /// The last command recorded was a copy: the next dispatch (or a copy after one) needs the closing barrier.
    in_copies: bool,
    /// Inside [`Recorder::independent`]: the buffers its dispatches bound so far (no barrier among them).
    group: Option<Vec<vk::Buffer>>,
    created: Instant,
}

/// A submitted sequence: owns its command buffer, query and descriptor pools and kept-alive values until
/// [`InFlight::wait`] (or its drop, which waits too: the device may not be using what it frees).
pub struct InFlight {
    ctx: Context,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    label: String,
    ticket: u64,
    barriers: u32,
    names: Vec<&'static str>,
    query_pools: Vec<vk::QueryPool>,
    desc_pools: Vec<vk::DescriptorPool>,
    keep: Vec<Box<dyn Any>>,
    submitted: Instant,
    done: bool,
}

impl Context {
    /// Starts recording; `label` names the sequence in timing reports.
    pub fn recorder(&self, label: &str) -> GpuResult<Recorder<'_>> {
        self.recorder_timed(label, true)
    }

    /// Starts recording, with per-dispatch timestamps only if `timing` (and the queue has them).
    pub fn recorder_timed(&self, label: &str, timing: bool) -> GpuResult<Recorder<'_>> {
        let (pool, cmd) = self.alloc_command_buffer()?;
        let timing = timing && self.caps().timestamp_period_ns.is_some();
        let mut rec = Recorder {
            ctx: self,
            pool,
            cmd,
            label: label.to_owned(),
            touched: Vec::new(),
            barriers: 0,
            names: Vec::new(),
            query_pools: Vec::new(),
            desc_pools: Vec::new(),
            sets_in_pool: SETS_PER_POOL,
            keep: Vec::new(),
            timing,
            finished: false,
            copies_out: false,
            in_copies: false,
            group: None,
            created: Instant::now(),
        };
        // Earlier submissions (uploads, other sequences) finish their writes before this one reads.
        rec.global_barrier(vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_WRITE, false);
        if rec.timing {
            rec.write_timestamp(vk::PipelineStageFlags2::NONE)?;
        }
        Ok(rec)
    }
}

impl<'a> Recorder<'a> {
    pub fn context(&self) -> &'a Context {
        self.ctx
    }

    /// A 1D dispatch over `elements` invocations, named after the kernel.
    pub fn dispatch<P: Pod>(&mut self, k: &Kernel<P>, bindings: &[Binding], push: &P, elements: u64) -> GpuResult<()> {
        self.dispatch_named(k.name, k, bindings, &[], push, elements)
    }

    /// A 1D dispatch with a label for the timing report, and buffers the kernel reaches through device
    /// addresses (`extra_deps`) so barriers account for them.
    pub fn dispatch_named<P: Pod>(
        &mut self,
        label: &'static str,
        k: &Kernel<P>,
        bindings: &[Binding],
        extra_deps: &[vk::Buffer],
        push: &P,
        elements: u64,
    ) -> GpuResult<()> {
        let groups = k.groups_for(elements);
        let grid = fold_groups(groups, self.ctx.caps().max_workgroup_count).ok_or_else(|| GpuError::Dispatch {
            kernel: k.name.to_owned(),
            msg: format!("{elements} elements need {groups} groups: more than the device can launch"),
        })?;
        self.dispatch_groups(label, k, bindings, extra_deps, push, grid)
    }

    /// A dispatch of an explicit group grid.
    pub fn dispatch_groups<P: Pod>(
        &mut self,
        label: &'static str,
        k: &Kernel<P>,
        bindings: &[Binding],
        extra_deps: &[vk::Buffer],
        push: &P,
        groups: [u32; 3],
    ) -> GpuResult<()> {
        let caps = self.ctx.caps();
        let fail = |msg: String| GpuError::Dispatch { kernel: k.name.to_owned(), msg };
        // Storage bindings in order at 0.., texel views in order at TEXEL_BINDING_BASE.. (kernel.rs checks both).
        let texels = bindings.iter().filter(|b| b.view.is_some()).count();
        if bindings.len() - texels != k.arity() || texels != k.texel_arity() {
            return Err(fail(format!(
                "{} storage and {texels} texel bindings given, the kernel declares {} and {}",
                bindings.len() - texels,
                k.arity(),
                k.texel_arity()
            )));
        }
        if let Some(b) = bindings.iter().find(|b| b.view.is_none() && b.range > caps.max_storage_buffer_range) {
            return Err(fail(format!(
                "binding {:?} covers {} bytes, over maxStorageBufferRange {} (use LargeArray or a slice)",
                b.name, b.range, caps.max_storage_buffer_range
            )));
        }
        if groups.iter().zip(caps.max_workgroup_count).any(|(g, m)| *g > m) {
            return Err(fail(format!("group grid {groups:?} exceeds {:?}", caps.max_workgroup_count)));
        }
        if groups.contains(&0) {
            return Ok(());
        }
        if self.in_copies {
            self.copy_barrier();
            self.in_copies = false;
        }
        let deps = bindings.iter().map(|b| b.buffer).chain(extra_deps.iter().copied());
        if deps.clone().any(|b| self.touched.contains(&b)) {
            self.global_barrier(vk::PipelineStageFlags2::COMPUTE_SHADER, vk::AccessFlags2::SHADER_STORAGE_WRITE, true);
        }
        match &mut self.group {
            Some(g) => g.extend(deps),
            None => self.touched.extend(deps),
        }

        let d = self.ctx.device();
        let layout = self.ctx.shared.pipeline_layout;
        let infos: Vec<vk::DescriptorBufferInfo> = bindings
            .iter()
            .filter(|b| b.view.is_none())
            .map(|b| vk::DescriptorBufferInfo { buffer: b.buffer, offset: b.offset, range: b.range })
            .collect();
        let views: Vec<vk::BufferView> = bindings.iter().filter_map(|b| b.view).collect();
        unsafe { d.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, k.pipeline) };
        if !infos.is_empty() || !views.is_empty() {
            let set =
                if self.ctx.shared.push_descriptor.is_some() { vk::DescriptorSet::null() } else { self.alloc_set()? };
            let mut writes: Vec<vk::WriteDescriptorSet> = infos
                .iter()
                .enumerate()
                .map(|(i, info)| {
                    vk::WriteDescriptorSet::default()
                        .dst_set(set)
                        .dst_binding(i as u32)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(std::slice::from_ref(info))
                })
                .collect();
            writes.extend(views.iter().enumerate().map(|(i, view)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(TEXEL_BINDING_BASE + i as u32)
                    .descriptor_type(vk::DescriptorType::UNIFORM_TEXEL_BUFFER)
                    .texel_buffer_view(std::slice::from_ref(view))
            }));
            match &self.ctx.shared.push_descriptor {
                Some(pd) => unsafe {
                    pd.cmd_push_descriptor_set(self.cmd, vk::PipelineBindPoint::COMPUTE, layout, 0, &writes)
                },
                None => unsafe {
                    d.update_descriptor_sets(&writes, &[]);
                    d.cmd_bind_descriptor_sets(self.cmd, vk::PipelineBindPoint::COMPUTE, layout, 0, &[set], &[]);
                },
            }
        }
        let bytes = bytemuck::bytes_of(push);
        if !bytes.is_empty() {
            unsafe { d.cmd_push_constants(self.cmd, layout, vk::ShaderStageFlags::COMPUTE, 0, bytes) };
        }
        unsafe { d.cmd_dispatch(self.cmd, groups[0], groups[1], groups[2]) };
        if self.timing {
            self.write_timestamp(vk::PipelineStageFlags2::COMPUTE_SHADER)?;
            self.names.push(label);
        }
        Ok(())
    }

    /// Records `f`'s dispatches as one group that needs no barrier among its members: they are ordered after
    /// earlier work that touched their buffers (one barrier before the first that needs it), and later work waits
    /// for all of them, but they may run concurrently. Only for dispatches that do not depend on each other: e.g.
    /// the levels of a hash grid, which write disjoint columns of one output, or add atomically into disjoint
    /// parameter ranges. Groups do not nest.
    pub fn independent<R>(&mut self, f: impl FnOnce(&mut Self) -> GpuResult<R>) -> GpuResult<R> {
        if self.group.is_some() {
            return Err(GpuError::Dispatch {
                kernel: self.label.clone(),
                msg: "Recorder::independent groups do not nest".into(),
            });
        }
        self.group = Some(Vec::new());
        let r = f(self);
        let members = self.group.take().unwrap_or_default();
        self.touched.extend(members);
        r
    }

    /// An explicit full compute barrier (e.g. after work that reached buffers the recorder cannot see).
    pub fn barrier(&mut self) {
        self.global_barrier(vk::PipelineStageFlags2::COMPUTE_SHADER, vk::AccessFlags2::SHADER_STORAGE_WRITE, true);
    }

    /// Keeps `value` (typically temporary buffers) alive until the recorded work has completed.
    pub fn keep_alive<T: Any>(&mut self, value: T) {
        self.keep.push(Box::new(value));
    }

    /// Number of barriers recorded so far (including the leading one).
    pub fn barrier_count(&self) -> u32 {
        self.barriers
    }

    /// Copies `n` elements from `src` (byte offset `src_at`) into `dst` from element `dst_at`, ordered after
    /// every earlier dispatch and copy of this recorder and before every later one.
    pub fn copy_in<T: Pod>(
        &mut self,
        src: &HostBuffer,
        src_at: u64,
        dst: &super::GpuBuffer<T>,
        dst_at: usize,
        n: usize,
    ) -> GpuResult<()> {
        let sz = std::mem::size_of::<T>() as u64;
        let bytes = n as u64 * sz;
        if dst_at + n > dst.len() || src_at + bytes > src.bytes() {
            return Err(GpuError::Buffer {
                name: dst.name().to_owned(),
                msg: format!(
                    "copy of {n} elements to {dst_at} (of {}) from byte {src_at} of {:?} ({} bytes)",
                    dst.len(),
                    src.inner.name,
                    src.bytes()
                ),
            });
        }
        self.copy(src.raw(), src_at, dst.raw(), dst_at as u64 * sz, bytes);
        Ok(())
    }

    /// Copies elements `[start, end)` of `src` into `dst` at byte offset `dst_at`; readable by the host once
    /// the submission has signalled.
    pub fn copy_out<T: Pod>(
        &mut self,
        src: &super::GpuBuffer<T>,
        start: usize,
        end: usize,
        dst: &HostBuffer,
        dst_at: u64,
    ) -> GpuResult<()> {
        let sz = std::mem::size_of::<T>() as u64;
        let bytes = (end.saturating_sub(start)) as u64 * sz;
        if start > end || end > src.len() || dst_at + bytes > dst.bytes() {
            return Err(GpuError::Buffer {
                name: src.name().to_owned(),
                msg: format!(
                    "copy of elements {start}..{end} (of {}) to byte {dst_at} of {:?} ({} bytes)",
                    src.len(),
                    dst.inner.name,
                    dst.bytes()
                ),
            });
        }
        self.copies_out = true;
        self.copy(src.raw(), start as u64 * sz, dst.raw(), dst_at, bytes);
        Ok(())
    }

    /// One buffer copy in the current group of copies: the group opens with a barrier after earlier work
    /// (including reads of what it overwrites) and closes with one before the next dispatch.
    fn copy(&mut self, src: vk::Buffer, src_at: u64, dst: vk::Buffer, dst_at: u64, bytes: u64) {
        if bytes == 0 {
            return;
        }
        if !self.in_copies {
            self.copy_barrier();
            self.in_copies = true;
        }
        let region = vk::BufferCopy { src_offset: src_at, dst_offset: dst_at, size: bytes };
        unsafe { self.ctx.device().cmd_copy_buffer(self.cmd, src, dst, &[region]) };
    }

    /// Shader and transfer writes before it are visible to shader and transfer accesses after it.
    fn copy_barrier(&mut self) {
        let all = vk::PipelineStageFlags2::COMPUTE_SHADER | vk::PipelineStageFlags2::COPY;
        let barrier = vk::MemoryBarrier2::default()
            .src_stage_mask(all)
            .src_access_mask(vk::AccessFlags2::SHADER_STORAGE_WRITE | vk::AccessFlags2::TRANSFER_WRITE)
            .dst_stage_mask(all)
            .dst_access_mask(
                vk::AccessFlags2::SHADER_STORAGE_READ
                    | vk::AccessFlags2::SHADER_SAMPLED_READ
                    | vk::AccessFlags2::SHADER_STORAGE_WRITE
                    | vk::AccessFlags2::TRANSFER_READ
                    | vk::AccessFlags2::TRANSFER_WRITE,
            );
        unsafe {
            self.ctx
                .device()
                .cmd_pipeline_barrier2(self.cmd, &vk::DependencyInfo::default().memory_barriers(&[barrier]))
        };
        self.barriers += 1;
        self.touched.clear();
    }

    /// Submits, waits for completion and returns the timing report.
    pub fn submit_and_wait(self) -> GpuResult<TimingReport> {
        self.submit()?.wait()
    }

    /// Submits without waiting; the returned [`InFlight`] is waited on (or dropped) later.
    pub fn submit(mut self) -> GpuResult<InFlight> {
        self.finished = true;
        if self.copies_out {
            let b = [vk::MemoryBarrier2::default()
                .src_stage_mask(vk::PipelineStageFlags2::COPY)
                .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
                .dst_stage_mask(vk::PipelineStageFlags2::HOST)
                .dst_access_mask(vk::AccessFlags2::HOST_READ)];
            unsafe {
                self.ctx.device().cmd_pipeline_barrier2(self.cmd, &vk::DependencyInfo::default().memory_barriers(&b))
            };
        }
        self.ctx.add_host_time(HostWork::Record, self.created);
        let start = Instant::now();
        let cmd = std::mem::replace(&mut self.cmd, vk::CommandBuffer::null());
        let mut flight = InFlight {
            ctx: self.ctx.clone(),
            pool: self.pool,
            cmd,
            label: std::mem::take(&mut self.label),
            ticket: 0,
            barriers: self.barriers,
            names: if self.timing { std::mem::take(&mut self.names) } else { Vec::new() },
            query_pools: std::mem::take(&mut self.query_pools),
            desc_pools: std::mem::take(&mut self.desc_pools),
            keep: std::mem::take(&mut self.keep),
            submitted: start,
            done: false,
        };
        match self.ctx.submit(cmd) {
            Ok(t) => flight.ticket = t,
            Err(e) => {
                // Never submitted: nothing to wait for (the pool goes back to the idle list with the flight).
                flight.done = true;
                return Err(e);
            }
        }
        self.ctx.add_host_time(HostWork::SubmitWait, start);
        Ok(flight)
    }

    fn global_barrier(&mut self, src_stage: vk::PipelineStageFlags2, src_access: vk::AccessFlags2, count: bool) {
        let b = [vk::MemoryBarrier2::default()
            .src_stage_mask(src_stage)
            .src_access_mask(src_access)
            .dst_stage_mask(vk::PipelineStageFlags2::COMPUTE_SHADER)
            // Sampled reads: kernels read some buffers as uniform texel buffers (gpu/texel.rs).
            .dst_access_mask(
                vk::AccessFlags2::SHADER_STORAGE_READ
                    | vk::AccessFlags2::SHADER_SAMPLED_READ
                    | vk::AccessFlags2::SHADER_STORAGE_WRITE,
            )];
        unsafe {
            self.ctx.device().cmd_pipeline_barrier2(self.cmd, &vk::DependencyInfo::default().memory_barriers(&b))
        };
        if count {
            self.barriers += 1;
        }
        self.touched.clear();
    }

    fn write_timestamp(&mut self, stage: vk::PipelineStageFlags2) -> GpuResult<()> {
        let index = self.names.len() as u32 + u32::from(stage != vk::PipelineStageFlags2::NONE);
        let pool_index = (index / QUERIES_PER_POOL) as usize;
        if pool_index == self.query_pools.len() {
            let info =
                vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(QUERIES_PER_POOL);
            let pool = unsafe { self.ctx.device().create_query_pool(&info, None) }.vk("vkCreateQueryPool")?;
            unsafe { self.ctx.device().cmd_reset_query_pool(self.cmd, pool, 0, QUERIES_PER_POOL) };
            self.query_pools.push(pool);
        }
        let stage = if stage == vk::PipelineStageFlags2::NONE { vk::PipelineStageFlags2::TOP_OF_PIPE } else { stage };
        unsafe {
            self.ctx.device().cmd_write_timestamp2(
                self.cmd,
                stage,
                self.query_pools[pool_index],
                index % QUERIES_PER_POOL,
            )
        };
        Ok(())
    }

    fn alloc_set(&mut self) -> GpuResult<vk::DescriptorSet> {
        let d = self.ctx.device();
        if self.sets_in_pool == SETS_PER_POOL {
            let sizes = [
                vk::DescriptorPoolSize {
                    ty: vk::DescriptorType::STORAGE_BUFFER,
                    descriptor_count: SETS_PER_POOL * MAX_BINDINGS,
                },
                vk::DescriptorPoolSize {
                    ty: vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
                    descriptor_count: SETS_PER_POOL * TEXEL_BINDINGS,
                },
            ];
            let info = vk::DescriptorPoolCreateInfo::default().max_sets(SETS_PER_POOL).pool_sizes(&sizes);
            self.desc_pools.push(unsafe { d.create_descriptor_pool(&info, None) }.vk("vkCreateDescriptorPool")?);
            self.sets_in_pool = 0;
        }
        let layouts = [self.ctx.shared.set_layout];
        let pool = *self.desc_pools.last().expect("pool created above");
        let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(pool).set_layouts(&layouts);
        let set = unsafe { d.allocate_descriptor_sets(&info) }.vk("vkAllocateDescriptorSets")?[0];
        self.sets_in_pool += 1;
        Ok(set)
    }
}

impl Drop for Recorder<'_> {
    fn drop(&mut self) {
        if self.cmd == vk::CommandBuffer::null() {
            return; // handed to an InFlight
        }
        // Never submitted (an error while recording): resetting the pool discards the recording.
        free_resources(self.ctx, (self.pool, self.cmd), &mut self.query_pools, &mut self.desc_pools);
        self.keep.clear();
    }
}

fn free_resources(
    ctx: &Context,
    pool_cmd: (vk::CommandPool, vk::CommandBuffer),
    query_pools: &mut Vec<vk::QueryPool>,
    desc_pools: &mut Vec<vk::DescriptorPool>,
) {
    let d = ctx.device();
    ctx.free_command_buffer(pool_cmd);
    unsafe {
        for p in query_pools.drain(..) {
            d.destroy_query_pool(p, None);
        }
        for p in desc_pools.drain(..) {
            d.destroy_descriptor_pool(p, None);
        }
    }
}

impl InFlight {
    /// Whether the device has finished this submission (never blocks).
    pub fn is_done(&self) -> GpuResult<bool> {
        Ok(self.done || self.ctx.completed_value()? >= self.ticket)
    }

    /// Blocks until the submission has completed; returns its timing report (`wall_ms`: from submission to
    /// completion as the host saw it).
    pub fn wait(mut self) -> GpuResult<TimingReport> {
        let start = Instant::now();
        self.ctx.wait(self.ticket)?;
        self.done = true;
        self.ctx.add_host_time(HostWork::SubmitWait, start);
        let wall_ms = self.submitted.elapsed().as_secs_f64() * 1e3;
        let mut report = TimingReport {
            label: std::mem::take(&mut self.label),
            wall_ms,
            barriers: self.barriers,
            ..Default::default()
        };
        if !self.names.is_empty() {
            let n = self.names.len() as u32 + 1;
            let mut ticks = vec![0u64; n as usize];
            for (p, pool) in self.query_pools.iter().enumerate() {
                let first = p as u32 * QUERIES_PER_POOL;
                let count = (n - first).min(QUERIES_PER_POOL);
                let dst = &mut ticks[first as usize..(first + count) as usize];
                unsafe {
                    self.ctx.device().get_query_pool_results(
                        *pool,
                        0,
                        dst,
                        vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                    )
                }
                .vk("vkGetQueryPoolResults")?;
            }
            let period = self.ctx.caps().timestamp_period_ns.unwrap_or(1.0) as f64;
            for (i, name) in self.names.iter().enumerate() {
                let ms = ticks[i + 1].saturating_sub(ticks[i]) as f64 * period * 1e-6;
                report.gpu_ms += ms;
                report.dispatches.push(DispatchTime { name: (*name).to_owned(), ms });
            }
        }
        Ok(report)
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        if !self.done && self.ctx.wait(self.ticket).is_err() {
            // The device may still use the command buffer and what it binds: leave them to the device's
            // destruction, after it idles.
            crate::gpu::context::lock(&self.ctx.shared.lost_pools).push(self.pool);
            return;
        }
        free_resources(&self.ctx, (self.pool, self.cmd), &mut self.query_pools, &mut self.desc_pools);
        self.keep.clear();
    }
}
