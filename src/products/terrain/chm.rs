//! The canopy height model: the height of the surface above the terrain, CHM = DSM - DTM, cell by cell on one grid.
//! Differences below zero (the surface a little under the interpolated terrain: noise on open ground) are zero, as
//! a height above ground cannot be negative; cells where either model has no height have none.

use super::grid::HeightGrid;

/// DSM - DTM, at least 0, NaN where either is (see the module doc). The grids must match.
pub fn canopy_height(dsm: &HeightGrid, dtm: &HeightGrid) -> HeightGrid {
    assert!(dsm.width == dtm.width && dsm.height == dtm.height, "the DSM and the DTM share one grid");
    let z = dsm
        .z
        .iter()
        .zip(&dtm.z)
        .map(|(&s, &t)| if s.is_finite() && t.is_finite() { (s - t).max(0.0) } else { f32::NAN })
        .collect();
    HeightGrid { width: dsm.width, height: dsm.height, gsd: dsm.gsd, z }
}
