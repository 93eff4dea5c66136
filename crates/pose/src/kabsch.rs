//! The Kabsch-Umeyama least-squares rigid registration and its precision (the fit and its
//! rotation covariance live in `kinetree_core::geom`, so the observer and the whole-tree
//! fit's checks can use them).

pub use kinetree_core::geom::{centroid, kabsch, rotation_cov_per_sigma2};
use kinetree_core::nalgebra::{Matrix3, Point3};

/// Spread of a point set: square roots of the eigenvalues of its scatter matrix divided by
/// the number of points (RMS extent along each principal axis), descending.
pub fn spread(p: &[Point3<f64>]) -> [f64; 3] {
    if p.is_empty() {
        return [0.0; 3];
    }
    let c = centroid(p);
    let mut s = Matrix3::zeros();
    for q in p {
        let d = q - c;
        s += d * d.transpose();
    }
    kinetree_core::geom::symmetric_eigenvalues_3x3(&s).map(|x| (x.max(0.0) / p.len() as f64).sqrt())
}

/// Worst-axis rotation std-dev per unit of per-coordinate noise for a fit on `p`:
/// `sqrt(lambda_max(J^-1))`, infinite for collinear points.
pub fn rotation_std_per_sigma(p: &[Point3<f64>]) -> f64 {
    rotation_cov_per_sigma2(p).map_or(f64::INFINITY, |c| {
        kinetree_core::geom::symmetric_eigenvalues_3x3(&c)[0]
            .max(0.0)
            .sqrt()
    })
}
