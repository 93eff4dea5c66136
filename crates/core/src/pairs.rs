//! Pairwise quantities over points, stored as a condensed upper triangle.

use serde::{Deserialize, Serialize};

/// Index of the pair `(i, j)`, `i != j`, in a condensed upper triangle over `n` points
/// (the layout of `scipy.spatial.distance.squareform` and of kodama).
#[inline]
pub fn condensed_index(n: usize, i: usize, j: usize) -> usize {
    debug_assert!(i != j && i < n && j < n);
    let (a, b) = if i < j { (i, j) } else { (j, i) };
    a * n - a * (a + 1) / 2 + (b - a - 1)
}

/// Number of unordered pairs over `n` points.
#[inline]
pub fn n_pairs(n: usize) -> usize {
    n * n.saturating_sub(1) / 2
}

/// Per-pair statistics of the distance between two points over the frames in which both are
/// visible: the paper's `T_ij`, mean distance and sample variance `s_ij^2` (eq. 1-3).
#[derive(Debug, Clone, PartialEq)]
pub struct PairStats {
    /// Number of points `N`.
    pub n_points: usize,
    /// `T_ij`: frames in which both points are visible, condensed.
    pub count: Vec<u32>,
    /// Mean distance in metres (NaN when `count == 0`), condensed.
    pub mean_m: Vec<f64>,
    /// Sample variance of the distance in m^2 (NaN when `count < 2`), condensed.
    pub var_m2: Vec<f64>,
}

impl PairStats {
    /// `T_ij` for the pair.
    #[inline]
    pub fn count(&self, i: usize, j: usize) -> u32 {
        self.count[condensed_index(self.n_points, i, j)]
    }

    /// Sample variance of the pair's distance, `None` with fewer than two joint observations.
    #[inline]
    pub fn var(&self, i: usize, j: usize) -> Option<f64> {
        let v = self.var_m2[condensed_index(self.n_points, i, j)];
        v.is_finite().then_some(v)
    }

    /// Rigidity of a group of points from the pairs' statistics: the distances of the points
    /// seen together, about their means, as `(chi^2 / dof, dof)` against their noise
    /// (`2 sigma^2`): `sum (T_ij - 1) s_ij^2 / (2 sigma^2)` over `sum (T_ij - 1)`, the pairs
    /// seen together twice or more. `(0, 0)` with no such pair, `(inf, 0)` when `sigma` is
    /// not a positive number. The same value as `kinetree_pose::group_rigidity` on the tracks
    /// these statistics came from, in O(m^2) for m points instead of O(T m^2).
    pub fn rigidity(&self, points: &[usize], sigma: f64) -> (f64, f64) {
        if !(sigma.is_finite() && sigma > 0.0) {
            return (f64::INFINITY, 0.0);
        }
        let (mut chi2, mut dof) = (0.0, 0.0);
        for (x, &i) in points.iter().enumerate() {
            for &j in points[x + 1..].iter().filter(|&&j| j != i) {
                let Some(v) = self.var(i, j) else { continue };
                let k = f64::from(self.count(i, j)) - 1.0;
                chi2 += k * v / (2.0 * sigma * sigma);
                dof += k;
            }
        }
        (if dof > 0.0 { chi2 / dof } else { 0.0 }, dof)
    }
}

/// A dissimilarity between every pair of points, produced by a
/// [`Dissimilarity`](crate::Dissimilarity) stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DissimilarityMatrix {
    /// Number of points `N`.
    pub n_points: usize,
    /// Condensed values; NaN marks a pair with no value (never seen together twice).
    pub values: Vec<f64>,
    /// The value at which a pair (or an average over pairs) stops looking rigid, on this
    /// measure's own scale; clusterers use it as their default cut.
    pub suggested_cut: f64,
    /// Name of the measure, for reports.
    pub measure: String,
}

impl DissimilarityMatrix {
    /// Value for the pair, `None` when unknown.
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> Option<f64> {
        // A point is no pair with itself (a point shared by two bodies meets itself).
        if i == j {
            return None;
        }
        let v = self.values[condensed_index(self.n_points, i, j)];
        (!v.is_nan()).then_some(v)
    }
}
