//! Rank tests on centred 3 x K (or 2 x K, 1 x K) data matrices with per-column noise
//! covariances.

use kinetree_core::RankTest;
use kinetree_core::nalgebra::{DMatrix, Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// How a rank is decided.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "rule", rename_all = "snake_case")]
pub enum RankRule {
    /// The paper's thresholded SVD, made scale-free: divide each centred column by its
    /// worst-direction noise std-dev and count singular values above
    /// `kappa (sqrt(K) + sqrt(d))` (the largest singular value of a `d x K` unit-noise
    /// matrix is about `sqrt(K) + sqrt(d)`).
    Whitened {
        /// Threshold in noise std-devs of RMS amplitude.
        kappa: f64,
    },
    /// A chi-square test with the full per-column covariance: fit the best rank-`r`
    /// subspace in the Mahalanobis metric of every column and accept the smallest `r` whose
    /// residual `chi^2 / dof` is below the Wilson-Hilferty quantile at `z` standard
    /// deviations, times `slack` for the linearisations in the noise model.
    Chi2 {
        /// Standard normal quantile of the test (4: p about 3e-5).
        z: f64,
        /// Tolerance factor on `chi^2 / dof`.
        slack: f64,
        /// The residual per degree of freedom above which [`hidden_next_rank`] looks for a
        /// rotation the slack hides.
        min_excess: f64,
        /// The looser rule for a rotation the slack hides ([`HiddenHinge`]).
        hidden_hinge: HiddenHinge,
        /// A translation between two bodies that stops at rank 0 with no rotation is retried
        /// at rank 1 when its rank-0 residual per degree of freedom exceeds this many times
        /// its rank-1 residual and a nested F-test at `z` rejects rank 0 (0: never).
        #[serde(default)]
        hidden_slide_ratio: f64,
    },
}

/// A rotation test that stopped at rank 0 is retried at rank 1 when rank 0's residual per
/// degree of freedom exceeds `ratio` times rank 1's ([`hidden_next_rank_above`]), and the
/// retry is kept only as a hinge whose rotation's RMS angle above the noise is at least
/// `min_angle_rad`. `ratio` 0 turns the rule off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HiddenHinge {
    /// Least ratio of rank 0's residual to rank 1's.
    pub ratio: f64,
    /// Least RMS angle of the hinge's rotation above the noise, radians.
    pub min_angle_rad: f64,
}

pub use kinetree_core::stats::chi2_per_dof_quantile;

/// Default of [`Chi2RankParams::min_excess`](crate::Chi2RankParams::min_excess): rank `r`'s
/// residual per degree of freedom must exceed this (the nominal noise level) for
/// [`hidden_next_rank`] to look further: under it, a tiny rank `r + 1` residual can come from
/// whitened columns nearly of that rank by construction, and the ratio means nothing
/// (`docs/decisions.md`, `kinetree_dof::MIN_EXCESS`).
pub const MIN_EXCESS: f64 = 1.0;

/// Whether a chi-square rank test ([`RankRule::Chi2`] on centred columns of dimension `dim`)
/// that stopped at rank `r` hides a rank `r + 1` structure because its noise model is too
/// pessimistic. The per-frame covariances overestimate the noise of small and slender bodies
/// (rank `r + 1` residuals of 0.5-0.8 per degree of freedom are typical), and the slack on
/// top can hide a real rotation. When rank `r + 1`'s residual per degree of freedom is below
/// 1, it is the measured noise level: rank `r`'s residual must then stay within its bound in
/// that unit, and rank `r + 1` must also pass a nested F-test at `z` (it removes far more
/// than noise would). `false` at full rank or without chi-square values.
///
/// Measured on the rotation test: revolute joints of slender bodies called prismatic had
/// residuals of 2.4-3.0 at rank 0 against 0.6-0.76 at rank 1 (ratios 3.7-4.6, above a
/// bound of about 3.2); prismatic joints whose poses carry a motion-dependent bias (box
/// corners occluded as they move) had 1.3-1.6 against 0.7 (ratios 1.8-2.3), and noise alone
/// about 1.1. Rank `r`'s residual must also exceed the nominal noise level (1): a rank `r + 1`
/// residual far below 1 can come from whitened columns that are nearly of rank `r + 1` by
/// construction (a 2 cm, 4-point body's rotation covariance leaving one direction), and a
/// ratio to it then means nothing (see [`MIN_EXCESS`]).
pub fn hidden_next_rank(test: &RankTest, dim: usize, z: f64, min_excess: f64) -> bool {
    test.chi2_bound
        .get(test.rank)
        .is_some_and(|&bound| hidden_next_rank_above(test, dim, z, min_excess, bound))
}

/// [`hidden_next_rank`] with the bound on the ratio of rank `r`'s residual to rank `r + 1`'s
/// given (`ratio`) instead of rank `r`'s chi-square bound.
pub fn hidden_next_rank_above(
    test: &RankTest,
    dim: usize,
    z: f64,
    min_excess: f64,
    ratio: f64,
) -> bool {
    let r = test.rank;
    if r + 1 >= dim || test.chi2_per_dof.len() < r + 2 || test.n_columns < 2 {
        return false;
    }
    // Rank `r + 1` must leave degrees of freedom: with too few columns its residual is zero
    // by construction, and whether rounding leaves 0 or 1e-16 there follows the order of
    // the sums over a body's points, not the motion.
    let (d, kf) = (dim as f64, (test.n_columns - 1) as f64);
    let unclamped = |r: f64| (d - r) * kf - r * (d - r);
    if unclamped(r as f64 + 1.0) < 1.0 {
        return false;
    }
    let level = test.chi2_per_dof[r + 1];
    let residual = test.chi2_per_dof[r];
    if !(level > 0.0 && level < 1.0 && residual > min_excess && residual > ratio * level) {
        return false;
    }
    let dof = |r: f64| unclamped(r).max(1.0);
    let (dof_r, dof_next) = (dof(r as f64), dof(r as f64 + 1.0));
    nested_f_rejects(
        test.chi2_per_dof[r] * dof_r,
        dof_r,
        level * dof_next,
        dof_next,
        z,
    )
}

/// Whether the fit with fewer parameters (residual `chi2_small` on `dof_small` degrees of
/// freedom) is rejected against the nested fit with more (`chi2_large` on `dof_large`): the F
/// statistic of the residual removed per degree of freedom against the residual left, above
/// its upper quantile at `z` standard normal deviations.
fn nested_f_rejects(
    chi2_small: f64,
    dof_small: f64,
    chi2_large: f64,
    dof_large: f64,
    z: f64,
) -> bool {
    use statrs::distribution::{ContinuousCDF, FisherSnedecor, Normal};
    let d1 = dof_small - dof_large;
    if !(d1 > 0.0 && dof_large > 0.0 && chi2_large > 0.0 && chi2_small.is_finite()) {
        return false;
    }
    let f = ((chi2_small - chi2_large) / d1) / (chi2_large / dof_large);
    // statrs panics on NaN input and saturates its cdf; rank on the survival function.
    let (Ok(dist), Ok(normal)) = (FisherSnedecor::new(d1, dof_large), Normal::new(0.0, 1.0)) else {
        return false;
    };
    f.is_finite() && dist.sf(f) < normal.sf(z)
}

fn sorted_singular_values(m: DMatrix<f64>) -> Vec<f64> {
    let mut s: Vec<f64> = m.singular_values().iter().copied().collect();
    s.sort_by(|a, b| b.total_cmp(a));
    s
}

fn worst_std(cov: &Matrix3<f64>, dim: usize) -> f64 {
    let v = match dim {
        1 => cov[(0, 0)],
        2 => cov.fixed_view::<2, 2>(0, 0).symmetric_eigenvalues().max(),
        _ => kinetree_core::geom::symmetric_eigenvalues_3x3(cov)[0],
    };
    v.max(1e-300).sqrt()
}

/// Inverse of a covariance restricted to its first `dim` coordinates (identity elsewhere).
fn information(cov: &Matrix3<f64>, dim: usize) -> Matrix3<f64> {
    let mut c = *cov;
    for i in dim..3 {
        for j in 0..3 {
            c[(i, j)] = if i == j { 1.0 } else { 0.0 };
            c[(j, i)] = if i == j { 1.0 } else { 0.0 };
        }
    }
    c.try_inverse().unwrap_or_else(Matrix3::zeros)
}

fn top_eigenvector(m: &Matrix3<f64>, largest: bool) -> Vector3<f64> {
    let e = m.symmetric_eigen();
    let i = if largest {
        e.eigenvalues.imax()
    } else {
        e.eigenvalues.imin()
    };
    e.eigenvectors.column(i).into_owned()
}

/// Alternating-least-squares rounds at most in [`mahalanobis_line`].
const LINE_MAX_ROUNDS: usize = 30;

/// [`mahalanobis_line`] stops once a round turns the unit direction by at most this much (its
/// change's norm, about the angle in radians): far below any axis precision the tests state,
/// and reached in a few rounds where the weights are nearly isotropic.
const LINE_TOLERANCE: f64 = 1e-13;

/// Direction of the line through the origin that best fits the columns `x`, each weighted by
/// its information matrix (inverse covariance) `omega`: alternating least squares on
/// `x_k = c_k u`, started from the unweighted principal direction. Unlike a fit with one scalar
/// weight per column, it follows anisotropic noise (a slender body's rotation is poorly known
/// about its long axis).
pub fn mahalanobis_line(x: &[Vector3<f64>], omega: &[Matrix3<f64>]) -> Vector3<f64> {
    let scatter: Matrix3<f64> = x.iter().map(|x| x * x.transpose()).sum();
    let mut u = top_eigenvector(&scatter, true);
    for _ in 0..LINE_MAX_ROUNDS {
        let mut a = Matrix3::zeros();
        let mut b = Vector3::zeros();
        for (x, o) in x.iter().zip(omega) {
            let den = u.dot(&(o * u));
            if den <= 0.0 {
                continue;
            }
            let c = u.dot(&(o * x)) / den;
            a += o * (c * c);
            b += o * x * c;
        }
        match a.try_inverse() {
            Some(inv) => {
                let next = inv * b;
                if next.norm() > 0.0 && next.iter().all(|v| v.is_finite()) {
                    let next = next.normalize();
                    let turned = (next - u).norm();
                    u = next;
                    if turned <= LINE_TOLERANCE {
                        break;
                    }
                }
            }
            None => break,
        }
    }
    u
}

/// Best-fitting line through the origin of `cols` with full per-column covariances `covs`
/// ([`mahalanobis_line`]); `None` for degenerate input.
pub fn weighted_direction(cols: &[Vector3<f64>], covs: &[Matrix3<f64>]) -> Option<Vector3<f64>> {
    let omega: Vec<Matrix3<f64>> = covs.iter().map(|c| information(c, 3)).collect();
    let u = mahalanobis_line(cols, &omega);
    (u.norm() > 0.0 && u.iter().all(|x| x.is_finite())).then(|| u.normalize())
}

/// Weighted residuals of the best rank-0, 1 and 2 subspaces (through the origin) of the
/// centred columns, each column weighted by its information matrix `omega`. Returns
/// `(chi2 for r = 0..dim, best line direction)`.
fn weighted_residuals(
    x: &[Vector3<f64>],
    omega: &[Matrix3<f64>],
    cov: &[Matrix3<f64>],
    dim: usize,
) -> (Vec<f64>, Vector3<f64>) {
    let s0: f64 = x.iter().zip(omega).map(|(x, o)| x.dot(&(o * x))).sum();
    let scatter: Matrix3<f64> = x.iter().map(|x| x * x.transpose()).sum();
    let u = mahalanobis_line(x, omega);
    let s1: f64 = x
        .iter()
        .zip(omega)
        .map(|(x, o)| {
            let den = u.dot(&(o * u));
            let num = u.dot(&(o * x));
            x.dot(&(o * x)) - if den > 0.0 { num * num / den } else { 0.0 }
        })
        .sum::<f64>()
        .max(0.0);
    let mut out = vec![s0, s1];
    if dim == 3 {
        // r = 2: the plane's normal, by reweighted smallest eigenvectors.
        let mut n = top_eigenvector(&scatter, false);
        for _ in 0..30 {
            let m: Matrix3<f64> = x
                .iter()
                .zip(cov)
                .map(|(x, c)| x * x.transpose() / n.dot(&(c * n)).max(1e-300))
                .sum();
            n = top_eigenvector(&m, false);
        }
        let s2: f64 = x
            .iter()
            .zip(cov)
            .map(|(x, c)| n.dot(x).powi(2) / n.dot(&(c * n)).max(1e-300))
            .sum();
        out.push(s2);
    }
    out.truncate(dim);
    (out, u)
}

/// Rank of the centred columns `cols` (only their first `dim` coordinates carry data) with
/// per-column noise covariances `covs`, by `rule`.
///
/// Centring makes the test affine: a line that misses the origin still has rank 1, and a
/// constant error in the reference frame does not add a rank. The singular values are
/// always reported (raw, and after dividing each column by its worst-direction std-dev);
/// for [`RankRule::Chi2`] the test also reports `chi2_per_dof` and `chi2_bound` for every
/// rank below `dim`.
pub fn rank_test(
    cols: &[Vector3<f64>],
    covs: &[Matrix3<f64>],
    dim: usize,
    rule: RankRule,
) -> RankTest {
    rank_test_about(cols, covs, dim, rule, true)
}

/// [`rank_test`] on the columns as they are, without removing their mean: the rank of the
/// subspace through the origin that holds them (a constant non-zero column gives rank 1).
pub fn rank_test_uncentred(
    cols: &[Vector3<f64>],
    covs: &[Matrix3<f64>],
    dim: usize,
    rule: RankRule,
) -> RankTest {
    rank_test_about(cols, covs, dim, rule, false)
}

fn rank_test_about(
    cols: &[Vector3<f64>],
    covs: &[Matrix3<f64>],
    dim: usize,
    rule: RankRule,
    centre: bool,
) -> RankTest {
    let k = cols.len();
    if k < 2 {
        return RankTest::empty();
    }
    let mean: Vector3<f64> = if centre {
        cols.iter().sum::<Vector3<f64>>() / k as f64
    } else {
        Vector3::zeros()
    };
    let centred: Vec<Vector3<f64>> = cols.iter().map(|c| c - mean).collect();
    let stds: Vec<f64> = covs.iter().map(|c| worst_std(c, dim)).collect();
    let singular_values = sorted_singular_values(DMatrix::from_fn(dim, k, |r, c| centred[c][r]));
    let whitened = sorted_singular_values(DMatrix::from_fn(dim, k, |r, c| centred[c][r] / stds[c]));
    let kf = if centre { (k - 1) as f64 } else { k as f64 };
    match rule {
        RankRule::Whitened { kappa } => {
            let threshold = kappa * ((k as f64).sqrt() + (dim as f64).sqrt());
            let rank = whitened.iter().filter(|&&s| s > threshold).count();
            RankTest {
                singular_values,
                whitened,
                threshold: Some(threshold),
                rank,
                n_columns: k,
                chi2_per_dof: Vec::new(),
                chi2_bound: Vec::new(),
            }
        }
        RankRule::Chi2 { z, slack, .. } => {
            let omega: Vec<Matrix3<f64>> = covs.iter().map(|c| information(c, dim)).collect();
            let (chi2, _) = weighted_residuals(&centred, &omega, covs, dim);
            let d = dim as f64;
            let mut per_dof = Vec::with_capacity(dim);
            let mut bound = Vec::with_capacity(dim);
            for (r, s) in chi2.iter().enumerate() {
                let rf = r as f64;
                let dof = ((d - rf) * kf - rf * (d - rf)).max(1.0);
                per_dof.push(s / dof);
                bound.push(slack * chi2_per_dof_quantile(dof, z));
            }
            let rank = (0..dim).find(|&r| per_dof[r] <= bound[r]).unwrap_or(dim);
            RankTest {
                singular_values,
                whitened,
                threshold: None,
                rank,
                n_columns: k,
                chi2_per_dof: per_dof,
                chi2_bound: bound,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chi2_test(per_dof: [f64; 3], n_columns: usize) -> RankTest {
        let kf = (n_columns - 1) as f64;
        let bound = (0..3)
            .map(|r| {
                let r = r as f64;
                2.5 * chi2_per_dof_quantile((3.0 - r) * kf - r * (3.0 - r), 4.0)
            })
            .collect();
        RankTest {
            singular_values: Vec::new(),
            whitened: Vec::new(),
            threshold: None,
            rank: 0,
            n_columns,
            chi2_per_dof: per_dof.to_vec(),
            chi2_bound: bound,
        }
    }

    /// The residuals measured on a slender revolute link's rotation stand out; those of a
    /// biased prismatic child, of noise alone, of a noise level above 1, or of a few frames
    /// do not.
    #[test]
    fn a_hidden_rotation_stands_out_against_the_measured_noise() {
        assert!(hidden_next_rank(
            &chi2_test([2.39, 0.59, 0.61], 150),
            3,
            4.0,
            MIN_EXCESS
        ));
        assert!(hidden_next_rank(
            &chi2_test([2.80, 0.76, 0.48], 150),
            3,
            4.0,
            MIN_EXCESS
        ));
        assert!(!hidden_next_rank(
            &chi2_test([1.62, 0.71, 0.75], 173),
            3,
            4.0,
            MIN_EXCESS
        ));
        assert!(!hidden_next_rank(
            &chi2_test([0.53, 0.47, 0.45], 200),
            3,
            4.0,
            MIN_EXCESS
        ));
        assert!(!hidden_next_rank(
            &chi2_test([3.0, 1.1, 1.0], 150),
            3,
            4.0,
            MIN_EXCESS
        ));
        // A rotation over a near-zero rank-1 level stands out; a rank-0 residual under the
        // nominal noise does not, however small rank 1's (a slide under a 2 cm, 4-point
        // parent).
        assert!(hidden_next_rank(
            &chi2_test([1.42, 0.03, 0.01], 120),
            3,
            4.0,
            MIN_EXCESS
        ));
        assert!(!hidden_next_rank(
            &chi2_test([0.12, 0.003, 0.0], 120),
            3,
            4.0,
            MIN_EXCESS
        ));
        // Three frames: the bound is too wide.
        assert!(!hidden_next_rank(
            &chi2_test([2.39, 0.59, 0.61], 3),
            3,
            4.0,
            MIN_EXCESS
        ));
        // Two frames: rank 1 leaves no degree of freedom, so its residual is rounding
        // (0 or 1e-16 with the order of the points) and must not decide.
        assert!(!hidden_next_rank(
            &chi2_test([1.23, 2.2e-16, 5.8e-32], 2),
            3,
            4.0,
            MIN_EXCESS
        ));
        // At full rank or without values.
        let mut full = chi2_test([2.39, 0.59, 0.61], 150);
        full.rank = 2;
        assert!(!hidden_next_rank(&full, 3, 4.0, MIN_EXCESS));
        assert!(!hidden_next_rank(&RankTest::empty(), 3, 4.0, MIN_EXCESS));
    }

    /// A distal phalanx's hinge measured on a hand (rank 0's residual 2.25 against a level of
    /// 0.63, under the bound) stands out at the hidden-hinge ratio of 1.8 and not at the
    /// chi-square bound; noise alone (a ratio near 1.1) stands out at neither.
    #[test]
    fn a_hinge_under_the_bound_stands_out_at_a_given_ratio() {
        let hinge = chi2_test([2.25, 0.63, 0.50], 63);
        assert!(!hidden_next_rank(&hinge, 3, 4.0, MIN_EXCESS));
        assert!(hidden_next_rank_above(&hinge, 3, 4.0, MIN_EXCESS, 1.8));
        assert!(!hidden_next_rank_above(&hinge, 3, 4.0, MIN_EXCESS, 4.0));
        let noise = chi2_test([1.09, 0.98, 0.95], 200);
        assert!(!hidden_next_rank_above(&noise, 3, 4.0, MIN_EXCESS, 1.8));
    }
}
