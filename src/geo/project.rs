//! Projecting WGS84 geodetic (GPS) or ECEF positions into a projected CRS with `proj4rs`, and the local rotation
//! that carries directions along (a projected grid's north differs from true north by the meridian convergence).

use super::crs::{Crs, CrsKind};
use super::error::CrsError;
use proj4rs::proj::Proj;

const WGS84_GEOGRAPHIC: &str = "+proj=longlat +datum=WGS84 +no_defs";
const WGS84_GEOCENTRIC: &str = "+proj=geocent +datum=WGS84 +units=m +no_defs";

/// WGS84 (geodetic or ECEF) -> a projected CRS.
pub struct Projector {
    pub crs: Crs,
    geodetic: Proj,
    geocentric: Proj,
    target: Proj,
}

impl std::fmt::Debug for Projector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Projector({})", self.crs.describe())
    }
}

impl Projector {
    /// A projector into `crs`, which must be projected and in the EPSG table (its PROJ.4 definition is needed).
    pub fn new(crs: &Crs) -> Result<Projector, CrsError> {
        let err = |reason: String| CrsError::Projection { crs: crs.describe(), reason };
        if crs.kind != CrsKind::Projected {
            return Err(err(format!("is {}, not a projected CRS in metres", crs.kind.name())));
        }
        let def = crs.proj4.as_deref().ok_or_else(|| {
            err("has no EPSG code msnerf knows, so it cannot project into it; give an EPSG code".into())
        })?;
        if def.contains("+units=") && !def.contains("+units=m ") && !def.ends_with("+units=m") {
            return Err(err(format!("is not in metres ({def})")));
        }
        let mk = |s: &str| Proj::from_proj_string(s).map_err(|e| err(format!("PROJ.4 definition {s:?}: {e}")));
        Ok(Projector {
            crs: crs.clone(),
            geodetic: mk(WGS84_GEOGRAPHIC)?,
            geocentric: mk(WGS84_GEOCENTRIC)?,
            target: mk(def)?,
        })
    }

    fn fail(&self, what: String, e: proj4rs::errors::Error) -> CrsError {
        CrsError::Projection { crs: self.crs.describe(), reason: format!("{what}: {e}") }
    }

    /// Easting, northing, height of a WGS84 position (degrees, metres above the ellipsoid; the height is kept).
    pub fn from_geodetic(&self, lat_deg: f64, lon_deg: f64, h: f64) -> Result<[f64; 3], CrsError> {
        let mut p = (lon_deg.to_radians(), lat_deg.to_radians(), h);
        proj4rs::transform::transform(&self.geodetic, &self.target, &mut p)
            .map_err(|e| self.fail(format!("latitude {lat_deg}, longitude {lon_deg}"), e))?;
        finite(self, [p.0, p.1, p.2])
    }

    /// The WGS84 latitude, longitude (degrees) and height of a projected position (the inverse of
    /// [`Projector::from_geodetic`]).
    pub fn to_geodetic(&self, p: [f64; 3]) -> Result<[f64; 3], CrsError> {
        let mut q = (p[0], p[1], p[2]);
        proj4rs::transform::transform(&self.target, &self.geodetic, &mut q)
            .map_err(|e| self.fail(format!("easting {}, northing {}", p[0], p[1]), e))?;
        finite(self, [q.1.to_degrees(), q.0.to_degrees(), q.2])
    }

    /// Easting, northing, ellipsoidal height of an ECEF position (EPSG:4978 metres).
    pub fn from_ecef(&self, xyz: [f64; 3]) -> Result<[f64; 3], CrsError> {
        let mut p = (xyz[0], xyz[1], xyz[2]);
        proj4rs::transform::transform(&self.geocentric, &self.target, &mut p)
            .map_err(|e| self.fail(format!("ECEF {xyz:?}"), e))?;
        finite(self, [p.0, p.1, p.2])
    }

    /// The rotation (row-major) taking ECEF directions at `xyz` to this CRS's (easting, northing, up) axes: the
    /// Jacobian of [`Projector::from_ecef`] there, by central differences over `step` metres, made orthonormal
    /// (it is a rotation times the grid's scale factor, about 0.9996 to 1.0004 in UTM).
    pub fn ecef_rotation(&self, xyz: [f64; 3], step: f64) -> Result<[[f64; 3]; 3], CrsError> {
        let mut cols = [[0.0; 3]; 3];
        for (k, col) in cols.iter_mut().enumerate() {
            let mut a = xyz;
            let mut b = xyz;
            a[k] -= step;
            b[k] += step;
            let (pa, pb) = (self.from_ecef(a)?, self.from_ecef(b)?);
            *col = std::array::from_fn(|i| (pb[i] - pa[i]) / (2.0 * step));
        }
        // J = [cols]; nearest rotation by two Gram-Schmidt passes on its rows (rows = easting, northing, up).
        let mut rows: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|k| cols[k][i]));
        for _ in 0..2 {
            for i in 0..3 {
                for j in 0..i {
                    let d: f64 = (0..3).map(|k| rows[i][k] * rows[j][k]).sum();
                    let rj = rows[j];
                    rows[i].iter_mut().zip(rj).for_each(|(x, y)| *x -= d * y);
                }
                let n = rows[i].iter().map(|x| x * x).sum::<f64>().sqrt();
                rows[i].iter_mut().for_each(|x| *x /= n);
            }
        }
        Ok(rows)
    }

    /// Meridian convergence at a WGS84 position: the angle (degrees, counter-clockwise) from the grid's north to
    /// true north, measured on the projected grid.
    pub fn convergence_deg(&self, lat_deg: f64, lon_deg: f64) -> Result<f64, CrsError> {
        let a = self.from_geodetic(lat_deg - 1e-4, lon_deg, 0.0)?;
        let b = self.from_geodetic(lat_deg + 1e-4, lon_deg, 0.0)?;
        Ok((-(b[0] - a[0])).atan2(b[1] - a[1]).to_degrees())
    }
}

fn finite(p: &Projector, v: [f64; 3]) -> Result<[f64; 3], CrsError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(CrsError::Projection { crs: p.crs.describe(), reason: format!("the projection gave {v:?}") })
    }
}
