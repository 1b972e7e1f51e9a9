//! The memory ledger: current and peak device bytes per category, from every allocation the runtime makes.
//! Bytes are what the device reserves for a buffer (`vkGetBufferMemoryRequirements().size`), so the VRAM
//! planner, which asks the device the same question, can be checked against it exactly.

use serde::Serialize;
use std::collections::BTreeMap;

#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MemoryCategory {
    Parameters,
    Gradients,
    OptimizerState,
    Activations,
    Rays,
    Images,
    Staging,
    Other,
}

impl MemoryCategory {
    pub const ALL: [MemoryCategory; 8] = [
        Self::Parameters,
        Self::Gradients,
        Self::OptimizerState,
        Self::Activations,
        Self::Rays,
        Self::Images,
        Self::Staging,
        Self::Other,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Parameters => "parameters",
            Self::Gradients => "gradients",
            Self::OptimizerState => "optimizer state",
            Self::Activations => "activations",
            Self::Rays => "rays",
            Self::Images => "images",
            Self::Staging => "staging",
            Self::Other => "other",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

#[derive(Clone, Debug)]
struct LiveAllocation {
    name: String,
    category: MemoryCategory,
    bytes: u64,
}

/// Per-category current and peak bytes, and the peak of the total (which is not the sum of category peaks).
#[derive(Default, Debug)]
pub struct MemoryLedger {
    current: [u64; 8],
    peak: [u64; 8],
    total_current: u64,
    total_peak: u64,
    live: BTreeMap<u64, LiveAllocation>,
    next_id: u64,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct CategoryBytes {
    pub category: MemoryCategory,
    pub current: u64,
    pub peak: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct MemoryReport {
    pub categories: Vec<CategoryBytes>,
    pub total_current: u64,
    pub total_peak: u64,
    pub live_allocations: usize,
    /// The largest live allocations, biggest first: (name, category, bytes).
    pub largest: Vec<(String, MemoryCategory, u64)>,
}

impl MemoryLedger {
    pub fn record_alloc(&mut self, name: &str, category: MemoryCategory, bytes: u64) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        let c = category.index();
        self.current[c] += bytes;
        self.peak[c] = self.peak[c].max(self.current[c]);
        self.total_current += bytes;
        self.total_peak = self.total_peak.max(self.total_current);
        self.live.insert(id, LiveAllocation { name: name.to_owned(), category, bytes });
        id
    }

    pub fn record_free(&mut self, id: u64) {
        if let Some(a) = self.live.remove(&id) {
            self.current[a.category.index()] -= a.bytes;
            self.total_current -= a.bytes;
        }
    }

    /// Starts a new peak measurement from the current state (e.g. after set-up, before training).
    pub fn reset_peaks(&mut self) {
        self.peak = self.current;
        self.total_peak = self.total_current;
    }

    pub fn current(&self, category: MemoryCategory) -> u64 {
        self.current[category.index()]
    }

    pub fn peak(&self, category: MemoryCategory) -> u64 {
        self.peak[category.index()]
    }

    pub fn total_current(&self) -> u64 {
        self.total_current
    }

    pub fn total_peak(&self) -> u64 {
        self.total_peak
    }

    pub fn report(&self) -> MemoryReport {
        let mut largest: Vec<_> = self.live.values().map(|a| (a.name.clone(), a.category, a.bytes)).collect();
        largest.sort_by(|a, b| b.2.cmp(&a.2).then(a.0.cmp(&b.0)));
        largest.truncate(16);
        MemoryReport {
            categories: MemoryCategory::ALL
                .iter()
                .map(|&c| CategoryBytes { category: c, current: self.current(c), peak: self.peak(c) })
                .collect(),
            total_current: self.total_current,
            total_peak: self.total_peak,
            live_allocations: self.live.len(),
            largest,
        }
    }
}

impl MemoryReport {
    /// A small aligned table (MiB with two decimals), categories with no bytes left out.
    pub fn table(&self) -> String {
        let mib = |b: u64| b as f64 / (1u64 << 20) as f64;
        let mut s = format!("{:<16} {:>12} {:>12}\n", "category", "current MiB", "peak MiB");
        for c in self.categories.iter().filter(|c| c.peak > 0) {
            s += &format!("{:<16} {:>12.2} {:>12.2}\n", c.category.name(), mib(c.current), mib(c.peak));
        }
        s += &format!("{:<16} {:>12.2} {:>12.2}\n", "total", mib(self.total_current), mib(self.total_peak));
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ledger_tracks_current_and_peaks_exactly() {
        let mut l = MemoryLedger::default();
        let a = l.record_alloc("a", MemoryCategory::Parameters, 1000);
        let b = l.record_alloc("b", MemoryCategory::Gradients, 300);
        l.record_free(a);
        let c = l.record_alloc("c", MemoryCategory::Parameters, 200);
        assert_eq!(l.current(MemoryCategory::Parameters), 200);
        assert_eq!(l.peak(MemoryCategory::Parameters), 1000);
        assert_eq!(l.total_peak(), 1300);
        assert_eq!(l.total_current(), 500);
        l.record_free(b);
        l.record_free(c);
        l.record_free(c); // double free is ignored, not double-counted
        assert_eq!(l.total_current(), 0);
        l.reset_peaks();
        assert_eq!(l.total_peak(), 0);
    }
}
