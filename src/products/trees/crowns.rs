//! Crowns grown from tree tops over a canopy height model, the seeded region growing of Dalponte and Coomes (2016,
//! "Tree-centric mapping of forest carbon density from airborne laser scanning and hyperspectral data", Methods in
//! Ecology and Evolution 7:1236-1245), as lidR's `dalponte2016` runs it: a cell joins the crown of a neighbouring
//! (4-connected) crown cell when it is at least `min_height`, higher than `seed_fraction` of the crown's top, higher
//! than `crown_fraction` of the crown's mean height so far, and within `max_diameter / 2` of the top. Cells are
//! taken highest first (a priority queue), so two crowns meet at the valley between them.

use std::collections::BinaryHeap;

use crate::products::terrain::HeightGrid;

/// Parameters of [`grow_crowns`] (lidR's `dalponte2016` defaults, the diameter in world units) and of the crowns a
/// tree needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrownParams {
    pub min_height: f64,
    pub seed_fraction: f64,
    pub crown_fraction: f64,
    pub max_diameter: f64,
    /// A top whose crown covers less than this share of its search window's disc (the crown width expected at
    /// its height, [`super::TopParams::radius`]) is not a tree: a spike or a fragment of another crown.
    pub min_area_fraction: f64,
    /// A crown needs at least this share of its cells measured or interpolated in the DSM (when its quality is known).
    /// Off (0) by default: since the DSM's cross-check, a crown's cells are field-only by design (a plane patch does
    /// not fit a dome), and the lawn blobs this once set apart are no longer measured.
    pub min_support: f64,
}

impl Default for CrownParams {
    fn default() -> Self {
        CrownParams {
            min_height: 2.0,
            seed_fraction: 0.45,
            crown_fraction: 0.55,
            max_diameter: 20.0,
            min_area_fraction: 0.5,
            min_support: 0.0,
        }
    }
}

#[derive(PartialEq)]
struct Item {
    z: f32,
    cell: usize,
    crown: u32,
}

impl Eq for Item {}

impl PartialOrd for Item {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}

impl Ord for Item {
    // Highest first; ties by cell so the order is deterministic.
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.z.total_cmp(&o.z).then(o.cell.cmp(&self.cell))
    }
}

/// The crown of every cell: 1 + the index into `tops`, 0 for none (see the module doc).
pub fn grow_crowns(chm: &HeightGrid, tops: &[usize], p: &CrownParams) -> Vec<u32> {
    let (w, h) = (chm.width, chm.height);
    let mut label = vec![0u32; w * h];
    let mut sum = vec![0.0f64; tops.len()];
    let mut count = vec![0usize; tops.len()];
    let mut heap = BinaryHeap::new();
    for (t, &cell) in tops.iter().enumerate() {
        heap.push(Item { z: chm.z[cell], cell, crown: t as u32 + 1 });
    }
    let max_r2 = (0.5 * p.max_diameter / chm.gsd).powi(2);
    while let Some(Item { cell, crown, .. }) = heap.pop() {
        if label[cell] != 0 {
            continue;
        }
        let t = (crown - 1) as usize;
        label[cell] = crown;
        sum[t] += chm.z[cell] as f64;
        count[t] += 1;
        let top = tops[t];
        let top_z = chm.z[top] as f64;
        let mean = sum[t] / count[t] as f64;
        let (r, c) = (cell / w, cell % w);
        let (tr, tc) = (top / w, top % w);
        let nbrs = [
            r.checked_sub(1).map(|r| (r, c)),
            (r + 1 < h).then_some((r + 1, c)),
            c.checked_sub(1).map(|c| (r, c)),
            (c + 1 < w).then_some((r, c + 1)),
        ];
        for (rr, cc) in nbrs.into_iter().flatten() {
            let j = rr * w + cc;
            let z = chm.z[j];
            if label[j] != 0 || !z.is_finite() {
                continue;
            }
            let zd = z as f64;
            let d2 = (rr as f64 - tr as f64).powi(2) + (cc as f64 - tc as f64).powi(2);
            if zd >= p.min_height && zd > p.seed_fraction * top_z && zd > p.crown_fraction * mean && d2 <= max_r2 {
                heap.push(Item { z, cell: j, crown });
            }
        }
    }
    label
}
