//! Order statistics shared across layers, in the two conventions the code uses: [`median`] (the mean of the two
//! middle values for an even count, as numpy and CloudCompare report it) and [`upper_median`] (the upper middle
//! value: an element of the data, for robust estimators that must return one of their inputs' values). Both sort a
//! copy by `total_cmp` and return NaN for no values; [`quantile`] interpolates between order statistics as numpy does,
//! [`nearest_rank`] picks the order statistic nearest the quantile (an element of the data).

/// Median: the middle value, or the mean of the two middle values for an even count; NaN when empty.
pub fn median(values: &[f64]) -> f64 {
    let mut s = values.to_vec();
    s.sort_by(f64::total_cmp);
    median_of_sorted(&s)
}

/// [`median`] of values already sorted ascending.
pub fn median_of_sorted(s: &[f64]) -> f64 {
    if s.is_empty() {
        return f64::NAN;
    }
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        (s[m - 1] + s[m]) / 2.0
    }
}

/// The upper middle value (`sorted[n / 2]`); NaN when empty.
pub fn upper_median(values: &[f64]) -> f64 {
    let mut s = values.to_vec();
    s.sort_by(f64::total_cmp);
    s.get(s.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The `q` quantile (0..=1) by linear interpolation between the order statistics (numpy's default); NaN when
/// empty.
pub fn quantile(values: &[f64], q: f64) -> f64 {
    let mut s = values.to_vec();
    s.sort_by(f64::total_cmp);
    quantile_of_sorted(&s, q)
}

/// [`quantile`] of values already sorted ascending.
pub fn quantile_of_sorted(s: &[f64], q: f64) -> f64 {
    if s.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (s.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos - pos.floor());
    if i + 1 < s.len() {
        s[i] + f * (s[i + 1] - s[i])
    } else {
        s[i]
    }
}

/// The order statistic nearest the `q` quantile (0..=1): `sorted[round((n - 1) q)]`, sorting `values` in place; NaN
/// when empty.
pub fn nearest_rank(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize]
}
