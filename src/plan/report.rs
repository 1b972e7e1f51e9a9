//! The text report `msnerf plan` prints: every planned GPU buffer grouped by ledger category (buffers of the same
//! name and part merged into one row with a count), per-part subtotals, the total against the budget, the
//! host-memory plan and the fit.

use super::fit::Plan;
use super::vram::Part;
use crate::gpu::MemoryCategory;
use std::fmt::Write;

const MIB: f64 = (1u64 << 20) as f64;
const GIB: f64 = (1u64 << 30) as f64;

fn mib(b: u64) -> String {
    format!("{:.2}", b as f64 / MIB)
}

/// The whole report.
pub fn text(p: &Plan) -> String {
    let v = &p.vram;
    let mut s = String::new();
    let d = &p.data;
    let _ = writeln!(
        s,
        "model {} ({:.1} M parameters), {} bands, {} views ({} training) of {}x{}; hardware profile {}",
        v.model,
        v.n_params as f64 / 1e6,
        v.bands,
        d.n_frames,
        d.n_train,
        d.width,
        d.height,
        p.profile
    );
    let _ = writeln!(
        s,
        "rays: {} per batch, {} per training chunk (one GPU pass), {} per evaluation chunk",
        v.rays.rays_per_batch, v.rays.rays_per_chunk, v.rays.eval_rays_per_chunk
    );
    let _ =
        writeln!(s, "byte counts: {}; parameter chunks of 2^{} floats", v.device.source, v.device.param_chunk_shift);
    let _ = writeln!(s, "\nGPU buffers");
    let _ = writeln!(s, "  {:<44} {:<30} {:>5} {:>12}", "category / buffer", "part", "count", "MiB");
    for c in MemoryCategory::ALL {
        let rows: Vec<_> = v.entries.iter().filter(|e| e.category == c).collect();
        if rows.is_empty() {
            continue;
        }
        let total: u64 = rows.iter().map(|e| e.bytes).sum();
        let _ = writeln!(s, "  {:<44} {:<30} {:>5} {:>12}", c.name(), "", rows.len(), mib(total));
        let mut merged: Vec<(&str, Part, usize, u64)> = Vec::new();
        for e in rows {
            match merged.iter_mut().find(|m| m.0 == e.name && m.1 == e.part) {
                Some(m) => {
                    m.2 += 1;
                    m.3 += e.bytes;
                }
                None => merged.push((&e.name, e.part, 1, e.bytes)),
            }
        }
        for (name, part, n, b) in merged {
            let _ = writeln!(s, "    {:<42} {:<30} {:>5} {:>12}", name, part.name(), n, mib(b));
        }
    }
    let _ = writeln!(s, "\n  by part:");
    for part in [
        Part::ParameterStore,
        Part::LevelTables,
        Part::CameraTable,
        Part::TrainChunk,
        Part::EvalChunk,
        Part::Staging,
        Part::NanGuard,
    ] {
        let _ = writeln!(s, "    {:<42} {:>49}", part.name(), mib(v.part_bytes(part)));
    }
    let _ = writeln!(
        s,
        "\n  total (planned peak): {} MiB = {:.2} GiB of a {:.2} GiB budget ({}): {}",
        mib(v.total_bytes),
        v.total_bytes as f64 / GIB,
        p.vram_budget_bytes as f64 / GIB,
        p.profile,
        if p.fits_vram { "fits" } else { "DOES NOT FIT" }
    );
    let h = &p.host;
    let _ = writeln!(s, "\nhost memory (training-image cache, paper §6.1)");
    let _ = writeln!(
        s,
        "  {} training images of {:.2} MiB; budget {:.2} GiB",
        h.n_images,
        h.bytes_per_image as f64 / MIB,
        h.budget_bytes as f64 / GIB
    );
    let m = h.resample_every.map_or_else(|| "none (all images resident)".to_string(), |m| format!("{m} steps"));
    let _ = writeln!(
        s,
        "  N = {} resident, M = {}; resident {:.2} GiB, peak with decode scratch {:.2} GiB: {}",
        h.n_resident,
        m,
        h.resident_bytes as f64 / GIB,
        h.peak_bytes as f64 / GIB,
        if h.fits() { "fits" } else { "DOES NOT FIT" }
    );
    let _ = writeln!(
        s,
        "  the training process: {:.2} GiB with its own {:.0} MiB ({:.2} GiB on a CPU device, whose GPU buffers are \
         host memory)",
        p.process_host_bytes(false) as f64 / GIB,
        super::host::PROCESS_OVERHEAD_BYTES as f64 / MIB,
        p.process_host_bytes(true) as f64 / GIB
    );
    if let Some(f) = &p.fit {
        let _ = writeln!(s, "\nfit (multiples of {} rays)", super::fit::FIT_STEP);
        match f.max_rays_per_chunk {
            Some(r) => {
                let _ = writeln!(
                    s,
                    "  largest training rays_per_chunk: {r} ({:.2} GiB with the evaluation chunk of {}); any rays_per_batch works, processed in chunks",
                    f.total_bytes_at_max.unwrap_or(0) as f64 / GIB,
                    v.rays.eval_rays_per_chunk
                );
            }
            None => {
                let _ =
                    writeln!(s, "  no training chunk fits with the evaluation chunk of {}", v.rays.eval_rays_per_chunk);
            }
        }
        match f.max_eval_rays_per_chunk {
            Some(r) => {
                let _ = writeln!(
                    s,
                    "  largest eval_rays_per_chunk: {r} (with the training chunk of {})",
                    v.rays.rays_per_chunk
                );
            }
            None => {
                let _ = writeln!(s, "  no evaluation chunk fits with the training chunk of {}", v.rays.rays_per_chunk);
            }
        }
    }
    for prob in p.problems() {
        let _ = writeln!(s, "\nDOES NOT FIT: {prob}");
    }
    s
}
