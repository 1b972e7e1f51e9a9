//! Where the host's time goes in the GPU layer (issue 22's first deliverable: measure before changing anything).
//! Every [`Context`](super::Context) keeps running totals, cheap enough to stay on (a few atomic adds per
//! submission):
//! - `record`: from a [`Recorder`](super::Recorder)'s creation to its submission (building command buffers,
//!   pipeline lookups, descriptor writes, timestamps);
//! - `submit_wait`: a recorder's submission until the device signals it (queue submit plus the blocking wait:
//!   GPU execution and the idle gap before it);
//! - `upload` / `readback`: staged transfers, each a one-shot submission and wait plus the host copies;
//! - the number of queue submissions and of blocking waits.
//!
//! [`HostTimes::since`] gives the difference between two snapshots, e.g. per training step.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// The kinds of host time counted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HostWork {
    Record,
    SubmitWait,
    Upload,
    Readback,
}

/// Running totals (nanoseconds and counts).
#[derive(Debug, Default)]
pub struct HostClock {
    ns: [AtomicU64; 4],
    submits: AtomicU64,
    waits: AtomicU64,
}

/// A snapshot of the totals, in milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct HostTimes {
    pub record_ms: f64,
    pub submit_wait_ms: f64,
    pub upload_ms: f64,
    pub readback_ms: f64,
    pub submits: u64,
    pub waits: u64,
}

impl HostClock {
    pub fn add(&self, work: HostWork, d: Duration) {
        self.ns[work as usize].fetch_add(d.as_nanos() as u64, Ordering::Relaxed);
    }

    pub fn count_submit(&self) {
        self.submits.fetch_add(1, Ordering::Relaxed);
    }

    pub fn count_wait(&self) {
        self.waits.fetch_add(1, Ordering::Relaxed);
    }

    pub fn snapshot(&self) -> HostTimes {
        let ms = |w: HostWork| self.ns[w as usize].load(Ordering::Relaxed) as f64 * 1e-6;
        HostTimes {
            record_ms: ms(HostWork::Record),
            submit_wait_ms: ms(HostWork::SubmitWait),
            upload_ms: ms(HostWork::Upload),
            readback_ms: ms(HostWork::Readback),
            submits: self.submits.load(Ordering::Relaxed),
            waits: self.waits.load(Ordering::Relaxed),
        }
    }
}

impl HostTimes {
    /// What happened between `earlier` and this snapshot.
    pub fn since(&self, earlier: &HostTimes) -> HostTimes {
        HostTimes {
            record_ms: self.record_ms - earlier.record_ms,
            submit_wait_ms: self.submit_wait_ms - earlier.submit_wait_ms,
            upload_ms: self.upload_ms - earlier.upload_ms,
            readback_ms: self.readback_ms - earlier.readback_ms,
            submits: self.submits - earlier.submits,
            waits: self.waits - earlier.waits,
        }
    }

    /// Every total divided by `n` (per step).
    pub fn per(&self, n: usize) -> HostTimes {
        let k = 1.0 / n.max(1) as f64;
        HostTimes {
            record_ms: self.record_ms * k,
            submit_wait_ms: self.submit_wait_ms * k,
            upload_ms: self.upload_ms * k,
            readback_ms: self.readback_ms * k,
            submits: self.submits / n.max(1) as u64,
            waits: self.waits / n.max(1) as u64,
        }
    }
}
