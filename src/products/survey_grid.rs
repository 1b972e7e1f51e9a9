//! The grid a survey product is made on: another raster's (`--align-to`), or cells of a given size over given
//! bounds (default: the ground the training cameras saw). One place for the rules the commands share: square cells,
//! the same EPSG code as the dataset, a cap on the number of cells, bounds that overlap what was seen.

use std::path::PathBuf;

use super::ProductError;
use crate::nerf::survey::SurveyGrid;

/// How the grid is asked for.
#[derive(Debug, Clone, PartialEq)]
pub enum GridSpec {
    /// Another raster's grid (its origin, cell size and extent).
    AlignTo(PathBuf),
    /// Cells of `gsd` over `bounds` (xmin, ymin, xmax, ymax; None: the ground the cameras saw).
    Cells { gsd: f64, bounds: Option<[f64; 4]> },
}

/// `xmin,ymin,xmax,ymax` as four numbers; the error names `--bounds`.
pub fn parse_bounds(text: &str) -> Result<[f64; 4], ProductError> {
    let bad = || ProductError::option("--bounds", format!("`{text}`: expected four numbers xmin,ymin,xmax,ymax"));
    let v: Vec<f64> = text.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|_| bad())?;
    match v[..] {
        [a, b, c, d] if v.iter().all(|x| x.is_finite()) && a < c && b < d => Ok([a, b, c, d]),
        _ => Err(bad()),
    }
}

/// The grid `spec` asks for, with at most `max_cells` cells; `crs` is the dataset's (an aligned raster must share
/// its EPSG code), `seen` the ground the training cameras saw (called only when needed).
pub fn choose_grid(
    spec: &GridSpec,
    max_cells: usize,
    crs: Option<&crate::geo::Crs>,
    seen: impl FnOnce() -> Result<[f64; 4], ProductError>,
) -> Result<SurveyGrid, ProductError> {
    match spec {
        GridSpec::AlignTo(path) => {
            let g = crate::output::raster::geotiff_read::read_grid(path)?;
            let fail =
                |reason: String| Err(ProductError::option("--align-to", format!("{}: {reason}", path.display())));
            if (g.pixel_size[0] - g.pixel_size[1]).abs() > 1e-9 * g.pixel_size[0] {
                return fail(format!("cells of {} x {} are not square", g.pixel_size[0], g.pixel_size[1]));
            }
            if let (Some(a), Some(c)) = (g.epsg, crs.and_then(|c| c.epsg)) {
                if a as u32 != c {
                    return fail(format!("EPSG:{a}, but the dataset is in EPSG:{c}"));
                }
            }
            if g.width * g.height > max_cells {
                return fail(format!("{} x {} cells, more than --max-cells {max_cells}", g.width, g.height));
            }
            Ok(SurveyGrid { origin: g.origin, gsd: g.pixel_size[0], width: g.width, height: g.height })
        }
        GridSpec::Cells { gsd, bounds } => {
            if !(gsd.is_finite() && *gsd > 0.0) {
                return Err(ProductError::option("--gsd", format!("must be > 0, got {gsd}")));
            }
            let seen = seen()?;
            let b = match bounds {
                Some(b) => {
                    let overlap = b[0] < seen[2] && b[2] > seen[0] && b[1] < seen[3] && b[3] > seen[1];
                    if !overlap {
                        return Err(ProductError::option(
                            "--bounds",
                            format!(
                                "{},{},{},{} lie outside the ground the training cameras saw ({:.2},{:.2},{:.2},{:.2})",
                                b[0], b[1], b[2], b[3], seen[0], seen[1], seen[2], seen[3]
                            ),
                        ));
                    }
                    *b
                }
                None => seen,
            };
            Ok(SurveyGrid::covering(b, *gsd, max_cells)?)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_parse_and_bad_ones_name_the_flag() {
        assert_eq!(parse_bounds("1, 2,3.5,4").unwrap(), [1.0, 2.0, 3.5, 4.0]);
        for bad in ["1,2,3", "1,2,3,x", "3,2,1,4", "1,2,3,nan"] {
            let e = parse_bounds(bad).unwrap_err().to_string();
            assert!(e.starts_with("--bounds") && e.contains(bad), "{e}");
        }
    }

    #[test]
    fn cells_cover_the_bounds_or_what_was_seen() {
        let seen = [0.0, 0.0, 10.0, 5.0];
        let g = choose_grid(&GridSpec::Cells { gsd: 0.5, bounds: None }, 1000, None, || Ok(seen)).unwrap();
        assert_eq!((g.width, g.height, g.origin), (20, 10, [0.0, 5.0]));
        let b = Some([2.0, 1.0, 4.0, 2.0]);
        let g = choose_grid(&GridSpec::Cells { gsd: 0.5, bounds: b }, 1000, None, || Ok(seen)).unwrap();
        assert_eq!((g.width, g.height), (4, 2));
        let far = Some([20.0, 20.0, 30.0, 30.0]);
        let e = choose_grid(&GridSpec::Cells { gsd: 0.5, bounds: far }, 1000, None, || Ok(seen)).unwrap_err();
        assert!(e.to_string().contains("lie outside the ground the training cameras saw"), "{e}");
        let e = choose_grid(&GridSpec::Cells { gsd: -1.0, bounds: None }, 1000, None, || Ok(seen)).unwrap_err();
        assert!(e.to_string().starts_with("--gsd"), "{e}");
        assert!(choose_grid(&GridSpec::Cells { gsd: 0.01, bounds: None }, 1000, None, || Ok(seen)).is_err());
    }
}
