//! Multispectral point clouds: [`PointCloud`] (f64 positions, B float reflectances per point, optional normals
//! and display colours), writers and readers for PLY ([`ply`]) and LAS 1.4 ([`las`]), filters ([`filter`]:
//! statistical outlier removal, crop boxes, deterministic subsampling) and the k-d tree they share ([`kdtree`]).

pub mod filter;
pub mod kdtree;
pub mod las;
pub mod ply;

pub use filter::{crop, remove_statistical_outliers, subsample, Aabb, OrientedBox};
pub use las::{read_las, write_las, LasOptions};
pub use ply::{read_ply, write_ply, PlyCoords, PlyOptions};

use std::path::Path;

use crate::data::PoseTransform;
use crate::output::image::nearest_band;
use crate::output::raster::preview::{band_range, Stretch, COMPOSITE_TOLERANCE_NM, NATURAL_COLOUR_NM};
use crate::output::{Band, OutputError, Result};

/// A point cloud with per-band values.
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud {
    /// World (or normalised-frame) coordinates in f64: UTM-sized values keep sub-millimetre precision.
    pub positions: Vec<[f64; 3]>,
    pub bands: Vec<Band>,
    /// `positions.len() × bands.len()` values, point-major (`values[i·B + b]`), reflectance in [0, 1].
    pub values: Vec<f32>,
    pub normals: Option<Vec<[f32; 3]>>,
    /// Display colour; when absent, writers derive a natural-colour composite from the bands.
    pub rgb: Option<Vec<[u8; 3]>>,
}

impl PointCloud {
    /// A cloud without normals or colours; checks the shapes.
    pub fn new(positions: Vec<[f64; 3]>, bands: Vec<Band>, values: Vec<f32>) -> Result<PointCloud> {
        let c = PointCloud { positions, bands, values, normals: None, rgb: None };
        c.validate()?;
        Ok(c)
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    pub fn n_bands(&self) -> usize {
        self.bands.len()
    }

    /// The band values of point `i`.
    pub fn point_values(&self, i: usize) -> &[f32] {
        let nb = self.n_bands();
        &self.values[i * nb..(i + 1) * nb]
    }

    /// Checks that every array has one entry per point and that positions are finite.
    pub fn validate(&self) -> Result<()> {
        let n = self.len();
        if self.values.len() != n * self.n_bands() {
            return Err(OutputError::invalid(
                "point cloud values",
                format!("{} values for {n} points x {} bands", self.values.len(), self.n_bands()),
            ));
        }
        if let Some(nr) = &self.normals {
            if nr.len() != n {
                return Err(OutputError::invalid(
                    "point cloud normals",
                    format!("{} normals for {n} points", nr.len()),
                ));
            }
        }
        if let Some(c) = &self.rgb {
            if c.len() != n {
                return Err(OutputError::invalid("point cloud rgb", format!("{} colours for {n} points", c.len())));
            }
        }
        if let Some(i) = self.positions.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(OutputError::invalid(
                "point cloud positions",
                format!("point {i} is not finite: {:?}", self.positions[i]),
            ));
        }
        Ok(())
    }

    /// The points at `idx`, in that order (indices must be `< len()` and the cloud valid: an internal helper
    /// for the filters, which check both).
    pub fn select(&self, idx: &[usize]) -> PointCloud {
        let nb = self.n_bands();
        PointCloud {
            positions: idx.iter().map(|&i| self.positions[i]).collect(),
            bands: self.bands.clone(),
            values: idx.iter().flat_map(|&i| self.values[i * nb..(i + 1) * nb].iter().copied()).collect(),
            normals: self.normals.as_ref().map(|n| idx.iter().map(|&i| n[i]).collect()),
            rgb: self.rgb.as_ref().map(|c| idx.iter().map(|&i| c[i]).collect()),
        }
    }

    /// Band `b` of every point.
    pub fn band_column(&self, b: usize) -> Vec<f32> {
        let nb = self.n_bands();
        self.values.iter().skip(b).step_by(nb.max(1)).copied().collect()
    }

    /// Display colours: `rgb` if set, else bands nearest 660/555/450 nm (the first three bands, or grey from the
    /// first, when those wavelengths are absent) under `stretch`; black when there are no bands.
    pub fn display_rgb(&self, stretch: Stretch) -> Vec<[u8; 3]> {
        if let Some(c) = &self.rgb {
            return c.clone();
        }
        let nb = self.n_bands();
        if nb == 0 {
            return vec![[0; 3]; self.len()];
        }
        let by_nm: Option<Vec<usize>> = NATURAL_COLOUR_NM
            .iter()
            .map(|&nm| nearest_band(&self.bands, nm, COMPOSITE_TOLERANCE_NM, "display colour").ok())
            .collect();
        let idx = by_nm.unwrap_or_else(|| if nb >= 3 { vec![0, 1, 2] } else { vec![0, 0, 0] });
        let cols: Vec<(Vec<f32>, f64, f64)> = idx
            .iter()
            .map(|&b| {
                let col = self.band_column(b);
                let (lo, hi) = band_range(&col, &self.bands[b], stretch);
                (col, lo, hi)
            })
            .collect();
        (0..self.len())
            .map(|i| {
                [0, 1, 2].map(|c| {
                    let (col, lo, hi) = &cols[c];
                    let v = col[i] as f64;
                    if !v.is_finite() {
                        return 0;
                    }
                    let t = if hi > lo { (v - lo) / (hi - lo) } else { 0.5 };
                    (t.clamp(0.0, 1.0) * 255.0).round() as u8
                })
            })
            .collect()
    }

    /// Maps positions (and normals) from the normalised training frame back to the world frame.
    pub fn to_world(&mut self, t: &PoseTransform) {
        for p in &mut self.positions {
            *p = t.to_world(*p);
        }
        if let Some(normals) = &mut self.normals {
            let r = &t.transform;
            for n in normals.iter_mut() {
                let v = [n[0] as f64, n[1] as f64, n[2] as f64];
                let w = [0, 1, 2].map(|j| r[0][j] * v[0] + r[1][j] * v[1] + r[2][j] * v[2]);
                *n = w.map(|x| x as f32);
            }
        }
    }
}

/// Reads a `.ply` or `.las` file by extension.
pub fn read_cloud(path: &Path) -> Result<PointCloud> {
    match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("ply") => read_ply(path),
        Some("las") => read_las(path),
        _ => Err(OutputError::read(path, "unknown point cloud format: expected a .ply or .las file")),
    }
}
