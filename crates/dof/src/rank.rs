//! Noise-whitened rank tests on 3 x K and 1 x K data matrices.

use kinetree_core::RankTest;
use kinetree_core::nalgebra::{DMatrix, Vector3};

/// Rank of the centred columns `cols` after dividing each by its noise std-dev `stds[k]`.
///
/// For a `d x K` matrix of independent unit-variance noise the largest singular value is about
/// `sqrt(K) + sqrt(d)`; a direction counts when its whitened singular value exceeds
/// `kappa (sqrt(K) + sqrt(d))`, i.e. when its RMS amplitude exceeds `kappa` noise std-devs.
/// Centring makes the test affine: a line that misses the origin still has rank 1, and a
/// constant error in the reference frame does not add a rank.
pub fn rank_test(cols: &[Vector3<f64>], stds: &[f64], dim: usize, kappa: f64) -> RankTest {
    let k = cols.len();
    if k < 2 {
        return RankTest::empty();
    }
    let mean: Vector3<f64> = cols.iter().sum::<Vector3<f64>>() / k as f64;
    let raw = DMatrix::from_fn(dim, k, |r, c| cols[c][r] - mean[r]);
    let white = DMatrix::from_fn(dim, k, |r, c| (cols[c][r] - mean[r]) / stds[c]);
    let sv = |m: DMatrix<f64>| -> Vec<f64> {
        let mut s: Vec<f64> = m.singular_values().iter().copied().collect();
        s.sort_by(|a, b| b.total_cmp(a));
        s
    };
    let singular_values = sv(raw);
    let whitened = sv(white);
    let threshold = kappa * ((k as f64).sqrt() + (dim as f64).sqrt());
    let rank = whitened.iter().filter(|&&s| s > threshold).count();
    RankTest {
        singular_values,
        whitened,
        threshold,
        rank,
        n_columns: k,
    }
}

/// Leading left singular vector of the (uncentred) columns weighted by `1 / stds`: the
/// best-fitting line through the origin.
pub fn principal_direction(cols: &[Vector3<f64>], stds: &[f64]) -> Option<Vector3<f64>> {
    let mut m = kinetree_core::nalgebra::Matrix3::zeros();
    for (c, s) in cols.iter().zip(stds) {
        let w = c / *s;
        m += w * w.transpose();
    }
    let eig = m.symmetric_eigen();
    let i = eig.eigenvalues.imax();
    let v: Vector3<f64> = eig.eigenvectors.column(i).into_owned();
    (v.norm() > 0.0 && v.iter().all(|x| x.is_finite())).then(|| v.normalize())
}
