//! Gap filling of a height raster by inverse distance weighting along eight directions, as GDAL's `FillNodata`
//! (which OpenDroneMap runs on its DEMs) searches: for each cell to fill, the nearest source cell along each of the
//! eight compass directions within `max_cells` (distance in cells, diagonal steps counting sqrt 2), then the mean
//! of those heights weighted by 1 / d^2. A cell is filled only when sources lie in at least [`MIN_DIRECTIONS`]
//! directions, so a gap is bridged between its edges rather than extrapolated from one side, and only when no two
//! of its sources rise from one to the other faster than `max_rise_per_cell` (height per cell of the distance
//! between them): a gap between a roof and the ground beside it is a step, not a surface to interpolate, and stays
//! a hole. GDAL's conic search and smoothing passes are left out: a flat pond between level banks comes out exactly
//! at the banks' height, and nothing but the gap's own cells changes.
//!
//! Why IDW from the gap's edges: a DSM cell without photometric support has no measurement of its own; the
//! neighbours that do are the only evidence, and a distance limit keeps a wide gap a hole instead of a guess.

/// Fewest directions with a source for a cell to be filled.
pub const MIN_DIRECTIONS: usize = 2;
/// Steepest slope (rise over run) a filled gap may bridge: 45 degrees.
pub const MAX_SLOPE: f64 = 1.0;

const DIRS: [(i64, i64); 8] = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)];

/// Fills the cells where `fill` is true from the cells where `source` is true (row-major `width` x `height`);
/// returns the filled value of every cell asked for (None where no fill was possible). `values` of non-source
/// cells are not read.
pub fn fill_idw(
    values: &[f32],
    source: &[bool],
    fill: &[bool],
    width: usize,
    height: usize,
    max_cells: f64,
    max_rise_per_cell: f64,
) -> Vec<Option<f32>> {
    let n = width * height;
    assert!(values.len() == n && source.len() == n && fill.len() == n, "one value per cell");
    let mut out = vec![None; n];
    for r in 0..height {
        for c in 0..width {
            let i = r * width + c;
            if !fill[i] {
                continue;
            }
            let (mut sw, mut swv) = (0.0f64, 0.0f64);
            // The nearest source along each direction: (row, column, value); no allocation per cell.
            let mut found = [(0i64, 0i64, 0.0f64); 8];
            let mut nf = 0;
            for (dr, dc) in DIRS {
                let step = if dr != 0 && dc != 0 { std::f64::consts::SQRT_2 } else { 1.0 };
                let (mut rr, mut cc, mut d) = (r as i64, c as i64, 0.0);
                loop {
                    rr += dr;
                    cc += dc;
                    d += step;
                    if d > max_cells || rr < 0 || cc < 0 || rr >= height as i64 || cc >= width as i64 {
                        break;
                    }
                    let j = rr as usize * width + cc as usize;
                    if source[j] && values[j].is_finite() {
                        let w = 1.0 / (d * d);
                        sw += w;
                        swv += w * values[j] as f64;
                        found[nf] = (rr, cc, values[j] as f64);
                        nf += 1;
                        break;
                    }
                }
            }
            let found = &found[..nf];
            let step = found.iter().enumerate().any(|(k, a)| {
                found[k + 1..].iter().any(|b| {
                    let run = (((a.0 - b.0).pow(2) + (a.1 - b.1).pow(2)) as f64).sqrt();
                    (a.2 - b.2).abs() > max_rise_per_cell * run
                })
            });
            if found.len() >= MIN_DIRECTIONS && !step {
                out[i] = Some((swv / sw) as f32);
            }
        }
    }
    out
}
