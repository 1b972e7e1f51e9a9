//! Reflectance spectra and band integration.
//!
//! A spectrum is a table of (wavelength nm, reflectance) knots, linearly interpolated and held constant beyond
//! its first and last knot (scene files cover 400-900 nm). A band's spectral response is a Gaussian (centre,
//! FWHM) or a table of (nm, weight) knots (linear, zero outside). The band value of a spectrum r is the
//! response-weighted mean
//!
//! ```text
//! r_b = ∫ w(λ) r(λ) dλ / ∫ w(λ) dλ
//! ```
//!
//! evaluated by the trapezoid rule on a fine grid (step = min(FWHM / 200, 0.25 nm); a Gaussian is cut at
//! ±6σ, which loses 2e-9 of its weight). It is computed as `r(c) + Σ ŵᵢ (r(λᵢ) − r(c))` with normalised
//! weights ŵ and a reference value r(c) at the band centre, so a flat spectrum r gives exactly r (no rounding).

/// A piecewise-linear function of wavelength (nm).
#[derive(Debug, Clone, PartialEq)]
pub struct Spectrum {
    /// (nm, value), strictly increasing in nm, at least one knot.
    knots: Vec<(f64, f64)>,
}

impl Spectrum {
    /// A spectrum from knots; `Err` names the problem (unsorted, empty or non-finite knots).
    pub fn new(knots: Vec<(f64, f64)>) -> Result<Spectrum, String> {
        if knots.is_empty() {
            return Err("needs at least one [nm, value] pair".into());
        }
        if knots.iter().any(|(l, v)| !l.is_finite() || !v.is_finite()) {
            return Err("values must be finite".into());
        }
        if knots.windows(2).any(|w| w[1].0 <= w[0].0) {
            return Err("wavelengths must be strictly increasing".into());
        }
        Ok(Spectrum { knots })
    }

    /// A flat spectrum.
    pub fn flat(value: f64) -> Spectrum {
        Spectrum { knots: vec![(550.0, value)] }
    }

    /// The value at `nm` (linear between knots, constant outside).
    pub fn eval(&self, nm: f64) -> f64 {
        let k = &self.knots;
        if nm <= k[0].0 {
            return k[0].1;
        }
        let last = k[k.len() - 1];
        if nm >= last.0 {
            return last.1;
        }
        let i = k.partition_point(|&(l, _)| l <= nm);
        let (l0, v0) = k[i - 1];
        let (l1, v1) = k[i];
        if v0 == v1 {
            return v0;
        }
        v0 + (v1 - v0) * (nm - l0) / (l1 - l0)
    }
}

/// A band's spectral response.
#[derive(Debug, Clone, PartialEq)]
pub enum Response {
    /// Gaussian with this centre and full width at half maximum (nm).
    Gaussian { center_nm: f64, fwhm_nm: f64 },
    /// Tabulated (nm, weight), linear, zero outside the table.
    Table(Vec<(f64, f64)>),
}

/// Full width at half maximum to standard deviation: FWHM = 2 sqrt(2 ln 2) σ.
pub fn fwhm_to_sigma(fwhm: f64) -> f64 {
    fwhm / (2.0 * (2.0 * std::f64::consts::LN_2).sqrt())
}

impl Response {
    /// Quadrature nodes and normalised weights (sum 1) for this response.
    pub fn quadrature(&self) -> Vec<(f64, f64)> {
        let (lo, hi, step, w): (f64, f64, f64, Box<dyn Fn(f64) -> f64 + '_>) = match self {
            Response::Gaussian { center_nm, fwhm_nm } => {
                let s = fwhm_to_sigma(*fwhm_nm);
                let c = *center_nm;
                (
                    c - 6.0 * s,
                    c + 6.0 * s,
                    (fwhm_nm / 200.0).min(0.25),
                    Box::new(move |l| (-0.5 * ((l - c) / s).powi(2)).exp()),
                )
            }
            Response::Table(t) => {
                let lo = t[0].0;
                let hi = t[t.len() - 1].0;
                let min_gap = t.windows(2).map(|p| p[1].0 - p[0].0).fold(f64::INFINITY, f64::min);
                let sp = Spectrum { knots: t.clone() };
                let step = (min_gap / 20.0).clamp(1e-3, 0.25);
                (lo, hi, step, Box::new(move |l| if l < lo || l > hi { 0.0 } else { sp.eval(l) }))
            }
        };
        let n = (((hi - lo) / step).ceil() as usize).max(1);
        let h = (hi - lo) / n as f64;
        let mut nodes: Vec<(f64, f64)> = (0..=n)
            .map(|i| {
                let l = lo + h * i as f64;
                let end = if i == 0 || i == n { 0.5 } else { 1.0 };
                (l, w(l) * end)
            })
            .filter(|&(_, w)| w > 0.0)
            .collect();
        let total: f64 = nodes.iter().map(|n| n.1).sum();
        if total > 0.0 {
            nodes.iter_mut().for_each(|n| n.1 /= total);
        }
        nodes
    }

    /// The reference wavelength of the band (its centre, or the table's weighted mean).
    pub fn center_nm(&self) -> f64 {
        match self {
            Response::Gaussian { center_nm, .. } => *center_nm,
            Response::Table(_) => self.quadrature().iter().map(|(l, w)| l * w).sum(),
        }
    }

    /// Full width at half maximum: the Gaussian's, or measured on the table.
    pub fn fwhm_nm(&self) -> f64 {
        match self {
            Response::Gaussian { fwhm_nm, .. } => *fwhm_nm,
            Response::Table(t) => {
                let peak = t.iter().map(|k| k.1).fold(0.0, f64::max);
                let above: Vec<f64> = t.iter().filter(|k| k.1 >= 0.5 * peak).map(|k| k.0).collect();
                above.last().copied().unwrap_or(0.0) - above.first().copied().unwrap_or(0.0)
            }
        }
    }
}

/// Precomputed integration of spectra against one band.
#[derive(Debug, Clone)]
pub struct BandIntegrator {
    nodes: Vec<(f64, f64)>,
    center: f64,
}

impl BandIntegrator {
    pub fn new(r: &Response) -> BandIntegrator {
        BandIntegrator { nodes: r.quadrature(), center: r.center_nm() }
    }

    /// The band value of `s` (a flat spectrum gives exactly its value).
    pub fn integrate(&self, s: &Spectrum) -> f64 {
        let r0 = s.eval(self.center);
        r0 + self.nodes.iter().map(|&(l, w)| w * (s.eval(l) - r0)).sum::<f64>()
    }
}

/// Band value of spectrum `s` for response `r` (see the module doc).
pub fn band_value(s: &Spectrum, r: &Response) -> f64 {
    BandIntegrator::new(r).integrate(s)
}
