//! GPU timestamp results of a recorded sequence: per dispatch, and summed per kernel name.
//! A dispatch's time runs from the previous timestamp to the one written after it, so barriers and waits
//! count toward the dispatch that waited. On lavapipe timestamps measure CPU time: fine for a breakdown,
//! not for performance claims about GPUs.

use serde::Serialize;

#[derive(Clone, Debug, Serialize)]
pub struct DispatchTime {
    pub name: String,
    pub ms: f64,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct KernelTime {
    pub name: String,
    pub count: u32,
    pub total_ms: f64,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct TimingReport {
    pub label: String,
    /// In recording order; empty when the queue has no timestamps.
    pub dispatches: Vec<DispatchTime>,
    /// Sum of the dispatch times.
    pub gpu_ms: f64,
    /// Host time from submission to completion.
    pub wall_ms: f64,
    pub barriers: u32,
}

impl TimingReport {
    /// Per kernel name: count and total time, largest first.
    pub fn by_kernel(&self) -> Vec<KernelTime> {
        let mut out: Vec<KernelTime> = Vec::new();
        for d in &self.dispatches {
            match out.iter_mut().find(|k| k.name == d.name) {
                Some(k) => {
                    k.count += 1;
                    k.total_ms += d.ms;
                }
                None => out.push(KernelTime { name: d.name.clone(), count: 1, total_ms: d.ms }),
            }
        }
        out.sort_by(|a, b| b.total_ms.total_cmp(&a.total_ms).then(a.name.cmp(&b.name)));
        out
    }

    /// Adds another report's dispatches (e.g. summing many training steps).
    pub fn accumulate(&mut self, other: &TimingReport) {
        self.dispatches.extend(other.dispatches.iter().cloned());
        self.gpu_ms += other.gpu_ms;
        self.wall_ms += other.wall_ms;
        self.barriers += other.barriers;
    }

    pub fn table(&self) -> String {
        let mut s = format!("{:<28} {:>6} {:>10} {:>7}\n", "kernel", "calls", "ms", "share");
        for k in self.by_kernel() {
            let share = if self.gpu_ms > 0.0 { 100.0 * k.total_ms / self.gpu_ms } else { 0.0 };
            s += &format!("{:<28} {:>6} {:>10.3} {:>6.1}%\n", k.name, k.count, k.total_ms, share);
        }
        s += &format!("{:<28} {:>6} {:>10.3}\n", "total (gpu)", self.dispatches.len(), self.gpu_ms);
        s
    }
}
