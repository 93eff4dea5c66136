//! The Kabsch-Umeyama least-squares rigid registration (the fit itself lives in
//! `kinetree_core::geom`, so the observer can use it) and the fit's precision.

pub use kinetree_core::geom::{centroid, kabsch};
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

/// Rotation-error covariance per unit noise variance for a Kabsch fit on `p`: `J^-1` with
/// `J = sum (|q|^2 I - q q^T)` over the points centred on their centroid (the inverse Fisher
/// information of the rotation, linearised). `None` when `J` is singular (collinear points).
pub fn rotation_cov_per_sigma2(p: &[Point3<f64>]) -> Option<Matrix3<f64>> {
    let c = centroid(p);
    let mut j = Matrix3::zeros();
    for q in p {
        let d = q - c;
        j += Matrix3::identity() * d.norm_squared() - d * d.transpose();
    }
    j.try_inverse()
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
