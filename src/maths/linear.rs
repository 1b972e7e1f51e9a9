//! Dense linear systems: Gaussian elimination with partial pivoting for the few small systems the importer's
//! registration (8x8 homography normal equations) and the point-to-plane ICP (7x7) solve. A linear-algebra crate for
//! these would cost more build time than these lines.

/// Solves `a x = b` (n x n, row-major, Gaussian elimination with partial pivoting); `None` when singular.
pub fn solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| a[i * n + c].abs().total_cmp(&a[j * n + c].abs()))?;
        let pivot = a[p * n + c].abs();
        if pivot.is_nan() || pivot <= 1e-300 {
            return None;
        }
        if p != c {
            for k in 0..n {
                a.swap(c * n + k, p * n + k);
            }
            b.swap(c, p);
        }
        for r in c + 1..n {
            let f = a[r * n + c] / a[c * n + c];
            if f != 0.0 {
                for k in c..n {
                    a[r * n + k] -= f * a[c * n + k];
                }
                b[r] -= f * b[c];
            }
        }
    }
    let mut x = vec![0.0; n];
    for c in (0..n).rev() {
        let s: f64 = (c + 1..n).map(|k| a[c * n + k] * x[k]).sum();
        x[c] = (b[c] - s) / a[c * n + c];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Solves `a x = b` for a symmetric positive definite `a` (n x n, row-major; the lower triangle is read) by
/// Cholesky's factorisation, row by row so that the inner products run over contiguous memory (the bundle
/// adjustment's reduced camera system: up to a few thousand unknowns). `None` when `a` is not positive definite.
pub fn cholesky_solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    if a.len() != n * n {
        return None;
    }
    for i in 0..n {
        let (done, rest) = a.split_at_mut(i * n);
        let row = &mut rest[..n];
        for j in 0..i {
            let lj = &done[j * n..j * n + j];
            let dot: f64 = row[..j].iter().zip(lj).map(|(x, y)| x * y).sum();
            row[j] = (row[j] - dot) / done[j * n + j];
        }
        let d = row[i] - row[..i].iter().map(|x| x * x).sum::<f64>();
        if !(d.is_finite() && d > 0.0) {
            return None;
        }
        row[i] = d.sqrt();
    }
    // L y = b, then L^T x = y.
    for i in 0..n {
        let s: f64 = (0..i).map(|k| a[i * n + k] * b[k]).sum();
        b[i] = (b[i] - s) / a[i * n + i];
    }
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|k| a[k * n + i] * b[k]).sum();
        b[i] = (b[i] - s) / a[i * n + i];
    }
    b.iter().all(|v| v.is_finite()).then_some(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_agrees_with_elimination() {
        let n = 7;
        // A = M M^T + n I, symmetric positive definite.
        let m: Vec<f64> = (0..n * n).map(|k| ((k * 37 % 11) as f64 - 5.0) / 3.0).collect();
        let a: Vec<f64> = (0..n * n)
            .map(|k| {
                let (i, j) = (k / n, k % n);
                (0..n).map(|t| m[i * n + t] * m[j * n + t]).sum::<f64>() + if i == j { n as f64 } else { 0.0 }
            })
            .collect();
        let b: Vec<f64> = (0..n).map(|i| i as f64 - 2.5).collect();
        let x = cholesky_solve(a.clone(), b.clone()).unwrap();
        let y = solve(a, b).unwrap();
        assert!(x.iter().zip(&y).all(|(p, q)| (p - q).abs() < 1e-10), "{x:?} {y:?}");
        assert!(cholesky_solve(vec![1.0, 2.0, 2.0, 1.0], vec![1.0, 1.0]).is_none(), "indefinite");
    }
}
