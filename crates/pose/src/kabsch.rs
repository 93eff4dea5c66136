//! The Kabsch-Umeyama least-squares rigid registration.

use kinetree_core::nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};

/// Centroid of a non-empty point set.
pub fn centroid(p: &[Point3<f64>]) -> Point3<f64> {
    let s: Vector3<f64> = p.iter().map(|q| q.coords).sum();
    Point3::from(s / p.len() as f64)
}

/// The rigid transform `T` minimising `sum |T src_i - dst_i|^2` (rotation with det +1).
///
/// Returns `None` with fewer than three pairs or when the SVD fails. Degenerate (collinear)
/// sets give an arbitrary rotation about their line; check with [`spread`] first.
///
/// Reference: Kabsch (1976), Umeyama (1991), without scale.
pub fn kabsch(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Option<Isometry3<f64>> {
    if src.len() != dst.len() || src.len() < 3 {
        return None;
    }
    let cs = centroid(src);
    let cd = centroid(dst);
    let mut h = Matrix3::zeros();
    for (s, d) in src.iter().zip(dst) {
        h += (s - cs) * (d - cd).transpose();
    }
    let svd = h.svd(true, true);
    let u = svd.u?;
    let v_t = svd.v_t?;
    let v = v_t.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let r = v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    if !r.iter().all(|x| x.is_finite()) {
        return None;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = cd.coords - rot * cs.coords;
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

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
    let mut e: Vec<f64> = s
        .symmetric_eigenvalues()
        .iter()
        .map(|x| (x.max(0.0) / p.len() as f64).sqrt())
        .collect();
    e.sort_by(|a, b| b.total_cmp(a));
    [e[0], e[1], e[2]]
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
        c.symmetric_eigenvalues().max().max(0.0).sqrt()
    })
}
