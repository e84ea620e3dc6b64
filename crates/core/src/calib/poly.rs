//! The least-squares polynomial z(d) of a fitted calibration, solved in a
//! centred and scaled form, with its prediction variance.

use super::{CalibError, FitStats, MAX_CONDITION_NUMBER};

#[derive(Clone, Debug, PartialEq)]
pub(super) struct CenteredPoly {
    pub(super) center_px: f64,
    pub(super) scale_px: f64,
    pub(super) coefficients: Vec<f64>,
}

impl CenteredPoly {
    pub(super) fn eval(&self, d: f64) -> f64 {
        let u = (d - self.center_px) / self.scale_px;
        self.coefficients.iter().rev().fold(0.0, |acc, &b| acc * u + b)
    }

    /// The same polynomial in powers of `d` itself.
    pub(super) fn monomial(&self) -> Vec<f64> {
        let m = self.center_px;
        let t = 1.0 / self.scale_px;
        let b = &self.coefficients;
        match b.len() {
            2 => vec![b[0] - b[1] * m * t, b[1] * t],
            3 => {
                let t2 = t * t;
                vec![
                    b[0] - b[1] * m * t + b[2] * m * m * t2,
                    b[1] * t - 2.0 * b[2] * m * t2,
                    b[2] * t2,
                ]
            }
            _ => unreachable!("degree is validated to 1 or 2"),
        }
    }
}

/// Solves the small symmetric system `a x = b` by Gaussian elimination with
/// partial pivoting; `None` when it is singular.
/// A fitted calibration's design and residual variance (see
/// [`Calibration::fit_variance`]).
pub(super) struct FitVariance {
    pub(super) s2: f64,
    pub(super) center_px: f64,
    pub(super) scale_px: f64,
    pub(super) terms: usize,
    pub(super) xtx: Vec<Vec<f64>>,
}

impl FitVariance {
    /// The design row at a disparity across the axis.
    pub(super) fn row(&self, d: f64) -> Vec<f64> {
        let u = (d - self.center_px) / self.scale_px;
        (0..self.terms).map(|k| u.powi(k as i32)).collect()
    }

    /// `x' (X'X)^-1 x`.
    pub(super) fn leverage(&self, x: &[f64]) -> Option<f64> {
        let solved = solve(self.xtx.clone(), x.to_vec())?;
        Some(solved.iter().zip(x).map(|(a, b)| a * b).sum())
    }
}

pub(super) fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for k in 0..n {
        let pivot = (k..n).max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))?;
        if a[pivot][k].abs() < 1e-300 {
            return None;
        }
        a.swap(k, pivot);
        b.swap(k, pivot);
        let (top, rest) = a.split_at_mut(k + 1);
        let pivot_row = &top[k];
        for (i, row) in rest.iter_mut().enumerate() {
            let m = row[k] / pivot_row[k];
            for (x, p) in row[k..].iter_mut().zip(&pivot_row[k..]) {
                *x -= m * p;
            }
            b[k + 1 + i] -= m * b[k];
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|j| a[i][j] * x[j]).sum();
        x[i] = (b[i] - s) / a[i][i];
    }
    Some(x)
}

/// Number of groups of values, where sorted neighbours closer than `tol` join a group.
pub(super) fn count_distinct(values: &[f64], tol: f64) -> usize {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let mut count = 0;
    let mut last = f64::NEG_INFINITY;
    for x in v {
        if x - last > tol {
            count += 1;
        }
        last = x;
    }
    count
}

/// Least squares `z = sum_k b_k u^k`, `u = (d - mean d) / max |d - mean d|`, by
/// Householder QR of the design matrix (no normal equations).
pub(super) fn fit_polynomial(
    d: &[f64],
    z: &[f64],
    degree: u8,
) -> Result<(CenteredPoly, FitStats), CalibError> {
    let n = d.len();
    let p = degree as usize + 1;
    let center_px = d.iter().sum::<f64>() / n as f64;
    let scale_px = d.iter().map(|x| (x - center_px).abs()).fold(0.0, f64::max);
    if scale_px.is_nan() || scale_px <= 0.0 {
        return Err(CalibError::DegenerateFit(
            "all disparity_px values are equal".into(),
        ));
    }
    let u: Vec<f64> = d.iter().map(|x| (x - center_px) / scale_px).collect();
    // Columns of the design matrix: 1, u, u^2.
    let mut cols: Vec<Vec<f64>> = (0..p)
        .map(|k| u.iter().map(|x| x.powi(k as i32)).collect())
        .collect();
    let mut y = z.to_vec();
    for k in 0..p {
        let norm = cols[k][k..].iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm == 0.0 {
            return Err(singular());
        }
        let alpha = if cols[k][k] > 0.0 { -norm } else { norm };
        let mut v: Vec<f64> = cols[k][k..].to_vec();
        v[0] -= alpha;
        let vv: f64 = v.iter().map(|x| x * x).sum();
        if vv > 0.0 {
            let reflect = |c: &mut [f64]| {
                let s = 2.0 * v.iter().zip(c.iter()).map(|(a, b)| a * b).sum::<f64>() / vv;
                c.iter_mut().zip(&v).for_each(|(ci, vi)| *ci -= s * vi);
            };
            for col in cols.iter_mut().skip(k) {
                reflect(&mut col[k..]);
            }
            reflect(&mut y[k..]);
        }
    }
    // R is upper triangular: r[i][j] = cols[j][i] for i <= j.
    let r = |i: usize, j: usize| cols[j][i];
    let cond = condition_number_1(p, &r);
    if cond.is_nan() || cond > MAX_CONDITION_NUMBER {
        return Err(CalibError::DegenerateFit(format!(
            "the design matrix is ill-conditioned (condition number {cond:.3e} > {MAX_CONDITION_NUMBER:e}): the \
             disparity_px values are too close together for a degree-{degree} fit; spread the samples over a \
             wider range of heights"
        )));
    }
    let mut b = vec![0.0; p];
    for i in (0..p).rev() {
        let s: f64 = (i + 1..p).map(|j| r(i, j) * b[j]).sum();
        b[i] = (y[i] - s) / r(i, i);
    }
    let poly = CenteredPoly {
        center_px,
        scale_px,
        coefficients: b,
    };
    let ss_res: f64 = d
        .iter()
        .zip(z)
        .map(|(&di, &zi)| (zi - poly.eval(di)).powi(2))
        .sum();
    let z_mean = z.iter().sum::<f64>() / n as f64;
    let ss_tot: f64 = z.iter().map(|zi| (zi - z_mean).powi(2)).sum();
    let z_max = z.iter().map(|x| x.abs()).fold(0.0, f64::max);
    // Sums of squares at the level of rounding noise count as zero.
    let noise = n as f64 * (16.0 * f64::EPSILON * z_max).powi(2);
    let r_squared = if ss_tot <= noise {
        1.0
    } else {
        (1.0 - ss_res / ss_tot).clamp(0.0, 1.0)
    };
    let residual_rms_um = (ss_res / n as f64).sqrt();
    if !residual_rms_um.is_finite() {
        return Err(singular());
    }
    Ok((
        poly,
        FitStats {
            residual_rms_um,
            r_squared,
        },
    ))
}

pub(super) fn singular() -> CalibError {
    CalibError::DegenerateFit(
        "the design matrix is singular; spread the samples over a wider range of heights".into(),
    )
}

/// 1-norm condition number of a p x p upper-triangular matrix given by `r(i, j)`;
/// infinite when a diagonal entry is zero.
pub(super) fn condition_number_1(p: usize, r: &dyn Fn(usize, usize) -> f64) -> f64 {
    if (0..p).any(|i| r(i, i) == 0.0) {
        return f64::INFINITY;
    }
    let col_norm = |m: &dyn Fn(usize, usize) -> f64| {
        (0..p)
            .map(|j| (0..p).map(|i| m(i, j).abs()).sum::<f64>())
            .fold(0.0, f64::max)
    };
    // Inverse by back substitution, column by column.
    let mut inv = vec![vec![0.0; p]; p];
    for (j, inv_col) in inv.iter_mut().enumerate() {
        for i in (0..p).rev() {
            let e = if i == j { 1.0 } else { 0.0 };
            let s: f64 = (i + 1..p).map(|k| r(i, k) * inv_col[k]).sum();
            inv_col[i] = (e - s) / r(i, i);
        }
    }
    col_norm(r) * col_norm(&|i, j| inv[j][i])
}
