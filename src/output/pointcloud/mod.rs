//! Multispectral point clouds: [`PointCloud`] (f64 positions, B float reflectances per point, optional normals
//! and display colours, named per-point f32 [`ScalarField`] attributes such as export confidences), writers and
//! readers for PLY ([`ply`]) and LAS 1.4 ([`las`]), filters ([`filter`]: statistical outlier removal, crop boxes,
//! deterministic subsampling; [`thin`]: one point per grid cell), the k-d tree they share ([`kdtree`]) and
//! trimmed ICP with a similarity ([`icp`]). Every filter picks points through [`PointCloud::select`], which keeps
//! attributes aligned with their points.

pub mod filter;
pub mod icp;
pub mod kdtree;
pub mod las;
pub mod local_plane;
pub mod ply;
pub mod thin;

pub use filter::{crop, remove_statistical_outliers, subsample, Aabb, OrientedBox};
pub use las::{read_las, write_las, LasOptions};
pub use ply::{read_ply, write_ply, PlyCoords, PlyOptions};

use std::path::Path;

use crate::data::PoseTransform;
use crate::output::image::nearest_band;
use crate::output::raster::preview::{band_range, Stretch, COMPOSITE_TOLERANCE_NM, NATURAL_COLOUR_NM};
use crate::output::{Band, OutputError, Result};

/// Longest attribute name in bytes: LAS Extra Bytes names are `char[32]`, written with a terminating NUL.
pub const MAX_ATTRIBUTE_NAME_BYTES: usize = 31;

/// Names no attribute may take (compared ignoring ASCII case): coordinates, normals (PLY and LAS Extra Bytes
/// names), and the colour / alpha properties the PLY reader recognises.
pub const RESERVED_ATTRIBUTE_NAMES: [&str; 19] = [
    "x",
    "y",
    "z",
    "nx",
    "ny",
    "nz",
    "red",
    "green",
    "blue",
    "alpha",
    "r",
    "g",
    "b",
    "diffuse_red",
    "diffuse_green",
    "diffuse_blue",
    "NormalX",
    "NormalY",
    "NormalZ",
];

/// A named per-point scalar (a confidence such as accumulation, depth spread, number of agreeing views):
/// PLY `property float <name>`, LAS f32 Extra Bytes `<name>`; CloudCompare shows each as a scalar field.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarField {
    /// ASCII letters, digits and `_`, at most [`MAX_ATTRIBUTE_NAME_BYTES`] bytes; unique in the cloud (ignoring
    /// case) and none of [`RESERVED_ATTRIBUTE_NAMES`] or the band property names
    /// ([`ply::band_property_names`]).
    pub name: String,
    /// One value per point.
    pub values: Vec<f32>,
    /// Free text without line breaks (a PLY header comment; LAS keeps its first 31 bytes in the Extra Bytes
    /// descriptor and all of it in the msnerf VLR).
    pub description: String,
}

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
    /// Per-point scalar attributes, in file order (written after the bands); see [`ScalarField`].
    pub attributes: Vec<ScalarField>,
}

impl PointCloud {
    /// A cloud without normals, colours or attributes; checks the shapes.
    pub fn new(positions: Vec<[f64; 3]>, bands: Vec<Band>, values: Vec<f32>) -> Result<PointCloud> {
        let c = PointCloud { positions, bands, values, normals: None, rgb: None, attributes: Vec::new() };
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

    /// Appends the attribute `name` (one value per point); on an error (see [`ScalarField`] for the rules) the
    /// cloud is left unchanged and the error names the attribute.
    pub fn add_attribute(
        &mut self,
        name: impl Into<String>,
        description: impl Into<String>,
        values: Vec<f32>,
    ) -> Result<()> {
        self.attributes.push(ScalarField { name: name.into(), values, description: description.into() });
        let r = self.validate_attributes();
        if r.is_err() {
            self.attributes.pop();
        }
        r
    }

    /// The attribute called `name` (exact match).
    pub fn attribute(&self, name: &str) -> Option<&ScalarField> {
        self.attributes.iter().find(|a| a.name == name)
    }

    /// Checks the attributes: one value per point, valid and unique names, descriptions without line breaks.
    pub fn validate_attributes(&self) -> Result<()> {
        let n = self.len();
        let band_names = ply::band_property_names(&self.bands);
        for (k, a) in self.attributes.iter().enumerate() {
            let what = || format!("point cloud attribute `{}`", a.name);
            if a.name.is_empty() {
                return Err(OutputError::invalid(
                    format!("point cloud attribute {k}"),
                    "the name is empty".to_string(),
                ));
            }
            if let Some(c) = a.name.chars().find(|c| !(c.is_ascii_alphanumeric() || *c == '_')) {
                return Err(OutputError::invalid(
                    what(),
                    format!("the name contains {c:?}: only ASCII letters, digits and `_` are allowed"),
                ));
            }
            if a.name.len() > MAX_ATTRIBUTE_NAME_BYTES {
                return Err(OutputError::invalid(
                    what(),
                    format!(
                        "the name has {} bytes, at most {MAX_ATTRIBUTE_NAME_BYTES} fit a LAS Extra Bytes name",
                        a.name.len()
                    ),
                ));
            }
            if let Some(r) = RESERVED_ATTRIBUTE_NAMES.iter().find(|r| r.eq_ignore_ascii_case(&a.name)) {
                return Err(OutputError::invalid(
                    what(),
                    format!("the name is reserved (`{r}`: coordinates, normals and colours; case is ignored)"),
                ));
            }
            if let Some(b) = band_names.iter().find(|b| b.eq_ignore_ascii_case(&a.name)) {
                return Err(OutputError::invalid(
                    what(),
                    format!("the name clashes with the band property `{b}` (case is ignored)"),
                ));
            }
            if let Some(o) = self.attributes[..k].iter().find(|o| o.name.eq_ignore_ascii_case(&a.name)) {
                return Err(OutputError::invalid(
                    what(),
                    format!("duplicate name (attribute `{}` exists; case is ignored)", o.name),
                ));
            }
            if a.values.len() != n {
                return Err(OutputError::invalid(what(), format!("{} values for {n} points", a.values.len())));
            }
            if a.description.contains(['\n', '\r']) {
                return Err(OutputError::invalid(what(), "the description contains a line break"));
            }
        }
        Ok(())
    }

    /// Checks that every array has one entry per point, that positions are finite and that the attributes are
    /// valid ([`PointCloud::validate_attributes`]).
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
        self.validate_attributes()
    }

    /// The points at `idx`, in that order, with their band values, normals, colours and attributes (indices must
    /// be `< len()` and the cloud valid: the one selection helper of the filters, which check both).
    pub fn select(&self, idx: &[usize]) -> PointCloud {
        let nb = self.n_bands();
        PointCloud {
            positions: idx.iter().map(|&i| self.positions[i]).collect(),
            bands: self.bands.clone(),
            values: idx.iter().flat_map(|&i| self.values[i * nb..(i + 1) * nb].iter().copied()).collect(),
            normals: self.normals.as_ref().map(|n| idx.iter().map(|&i| n[i]).collect()),
            rgb: self.rgb.as_ref().map(|c| idx.iter().map(|&i| c[i]).collect()),
            attributes: self
                .attributes
                .iter()
                .map(|a| ScalarField {
                    name: a.name.clone(),
                    values: idx.iter().map(|&i| a.values[i]).collect(),
                    description: a.description.clone(),
                })
                .collect(),
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

/// `raw` (a property or Extra Bytes name from a file) made a valid attribute name that clashes with none of
/// `taken` (band property names and earlier attributes, ignoring case): characters other than ASCII letters,
/// digits and `_` become `_`, long names are cut, and a clash gets `_2`, `_3`, ... appended.
pub(crate) fn attribute_name_from(raw: &str, taken: &[String]) -> String {
    let mut base: String = raw.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' { c } else { '_' }).collect();
    if base.is_empty() {
        base = "attribute".into();
    }
    base.truncate(MAX_ATTRIBUTE_NAME_BYTES);
    let free = |n: &str| {
        !RESERVED_ATTRIBUTE_NAMES
            .iter()
            .copied()
            .chain(taken.iter().map(String::as_str))
            .any(|t| t.eq_ignore_ascii_case(n))
    };
    if free(&base) {
        return base;
    }
    (2usize..)
        .map(|k| {
            let suffix = format!("_{k}");
            let mut b = base.clone();
            b.truncate(MAX_ATTRIBUTE_NAME_BYTES - suffix.len());
            b + &suffix
        })
        .find(|n| free(n))
        .expect("some suffix is free")
}

/// Reads a `.ply` or `.las` file by extension.
pub fn read_cloud(path: &Path) -> Result<PointCloud> {
    match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("ply") => read_ply(path),
        Some("las") => read_las(path),
        _ => Err(OutputError::read(path, "unknown point cloud format: expected a .ply or .las file")),
    }
}
