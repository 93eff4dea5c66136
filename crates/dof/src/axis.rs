//! Reference-free fit of a revolute joint's axis.
//!
//! A revolute joint leaves one direction fixed in both bodies: `R_k m = n` in every frame,
//! with `n` the axis in the parent's frame, `m` the same axis in the child's frame and `R_k`
//! the relative rotation `a_from_b`. The fit minimises the weighted residuals `R_k m - n`
//! over the unit vectors `n` and `m`, each frame weighted by the inverse covariance of its
//! relative rotation (left perturbation `delta_k`, covariance `Sigma_k`, in `a`'s frame). The
//! residual moves by `delta_k x n`, so its covariance is `[n]x Sigma_k [n]x^T`, of rank two;
//! the rotation about the axis (the joint angle) drops out, so no angle and no reference
//! frame is estimated.
//!
//! The axis from log-map columns `log(R_k R_r^T)` carries the reference frame's own rotation
//! error into every column; on random mechanisms with small or thin parents at 2-4 mm noise
//! that put the axis 10-20 deg off while the joint was otherwise right. This fit has no
//! reference frame.

use kinetree_core::geom::perpendicular_basis;
use kinetree_core::nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector3};

/// Weight of one frame's residual: the inverse of `[n]x Sigma [n]x^T` on the plane
/// perpendicular to `n`, zero along `n`.
fn residual_weight(n: &Vector3<f64>, sigma: &Matrix3<f64>) -> Matrix3<f64> {
    let (e1, e2) = perpendicular_basis(n);
    let nx = n.cross_matrix();
    let cov = nx * sigma * nx.transpose();
    let s = Matrix2::new(
        e1.dot(&(cov * e1)),
        e1.dot(&(cov * e2)),
        e2.dot(&(cov * e1)),
        e2.dot(&(cov * e2)),
    );
    let Some(inv) = s.try_inverse() else {
        return Matrix3::zeros();
    };
    let e = SMatrix::<f64, 3, 2>::from_columns(&[e1, e2]);
    e * inv * e.transpose()
}

/// The Gauss-Newton system at `(n, m)` and the cost there, from one pass over the frames.
struct Linearised {
    normal: SMatrix<f64, 4, 4>,
    rhs: SVector<f64, 4>,
    cost: f64,
    /// The bases of the planes perpendicular to `n` and `m` that the step is taken along.
    n_basis: (Vector3<f64>, Vector3<f64>),
    m_basis: (Vector3<f64>, Vector3<f64>),
}

fn linearise(
    rotations: &[Matrix3<f64>],
    covs: &[Matrix3<f64>],
    n: &Vector3<f64>,
    m: &Vector3<f64>,
) -> Linearised {
    let (n1, n2) = perpendicular_basis(n);
    let (m1, m2) = perpendicular_basis(m);
    let mut normal = SMatrix::<f64, 4, 4>::zeros();
    let mut rhs = SVector::<f64, 4>::zeros();
    let mut cost = 0.0;
    for (r, c) in rotations.iter().zip(covs) {
        let w = residual_weight(n, c);
        let res = r * m - n;
        cost += res.dot(&(w * res));
        // d(R m)/d(m_i) = R m_i and d(-n)/d(n_i) = -n_i for a step along the basis.
        let jac = SMatrix::<f64, 3, 4>::from_columns(&[-n1, -n2, r * m1, r * m2]);
        normal += jac.transpose() * w * jac;
        rhs -= jac.transpose() * w * res;
    }
    Linearised {
        normal,
        rhs,
        cost,
        n_basis: (n1, n2),
        m_basis: (m1, m2),
    }
}

/// Gauss-Newton from `(n, m)`, stopping when a step does not lower the cost; returns the
/// refined pair and its cost.
fn refine(
    rotations: &[Matrix3<f64>],
    covs: &[Matrix3<f64>],
    mut n: Vector3<f64>,
    mut m: Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>, f64) {
    let mut here = linearise(rotations, covs, &n, &m);
    for _ in 0..20 {
        let best = here.cost;
        let ((n1, n2), (m1, m2)) = (here.n_basis, here.m_basis);
        let ridge = here.normal.trace().max(1e-300) * 1e-12;
        let Some(step) = (here.normal + SMatrix::<f64, 4, 4>::identity() * ridge)
            .try_inverse()
            .map(|inv| inv * here.rhs)
        else {
            break;
        };
        let n_new = (n + n1 * step[0] + n2 * step[1]).normalize();
        let m_new = (m + m1 * step[2] + m2 * step[3]).normalize();
        let next = linearise(rotations, covs, &n_new, &m_new);
        let c = next.cost;
        if !(c.is_finite() && c < best) {
            break;
        }
        let converged = best - c <= 1e-12 * best.max(1e-300);
        n = n_new;
        m = m_new;
        here = next;
        if converged {
            break;
        }
    }
    (n, m, here.cost)
}

/// The axis of a revolute joint in `a`'s frame from the relative rotations `a_from_b` and
/// their covariances (rad^2, left perturbation in `a`'s frame). `initial` is an axis guess in
/// `a`'s frame (for example from log-map columns); the fit also starts from the top singular
/// vectors of `sum_k R_k / tr(Sigma_k)` and keeps the better of the two. Returns `None` for
/// fewer than two frames or a non-finite result.
pub fn fixed_axis(
    rotations: &[Matrix3<f64>],
    covs: &[Matrix3<f64>],
    initial: Option<Vector3<f64>>,
) -> Option<Vector3<f64>> {
    if rotations.len() < 2 || rotations.len() != covs.len() {
        return None;
    }
    let mut starts = Vec::with_capacity(2);
    let sum: Matrix3<f64> = rotations
        .iter()
        .zip(covs)
        .map(|(r, c)| r / c.trace().max(1e-300))
        .sum();
    let svd = sum.svd(true, true);
    if let (Some(u), Some(v_t)) = (svd.u, svd.v_t) {
        let i = svd.singular_values.imax();
        let n = u.column(i).into_owned();
        let m = v_t.row(i).transpose();
        starts.push((n, m));
    }
    if let Some(n) = initial.and_then(|v| v.try_normalize(1e-12)) {
        // The same axis in b's frame: the mean of R_k^T n, which a fixed axis leaves constant.
        let m: Vector3<f64> = rotations.iter().map(|r| r.transpose() * n).sum();
        if let Some(m) = m.try_normalize(1e-12) {
            starts.push((n, m));
        }
    }
    starts
        .into_iter()
        .map(|(n, m)| refine(rotations, covs, n, m))
        .filter(|(n, _, c)| c.is_finite() && n.iter().all(|x| x.is_finite()))
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map(|(n, _, _)| n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinetree_core::nalgebra::{Rotation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn recovers_an_exact_axis_from_any_start() {
        let n = Vector3::new(0.3, -0.5, 0.8).normalize();
        let c = Rotation3::from_euler_angles(0.4, -1.1, 2.0);
        let rotations: Vec<Matrix3<f64>> = (0..40)
            .map(|k| {
                let theta = 0.05 * k as f64;
                (Rotation3::from_scaled_axis(n * theta) * c).into_inner()
            })
            .collect();
        let covs = vec![Matrix3::identity() * 1e-4; rotations.len()];
        for start in [None, Some(Vector3::x()), Some(n)] {
            let got = fixed_axis(&rotations, &covs, start).expect("axis");
            assert!(got.cross(&n).norm() < 1e-9, "{start:?}: {got}");
        }
    }

    #[test]
    fn ignores_a_noisy_reference_frame() {
        // One very noisy frame (as a reference frame could be) among precise ones: weighted
        // by its covariance it cannot pull the axis.
        let n = Vector3::new(1.0, 2.0, -0.5).normalize();
        let c = Rotation3::from_euler_angles(-0.3, 0.7, 0.1);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut rotations = Vec::new();
        let mut covs = Vec::new();
        for k in 0..100 {
            let theta = (k as f64 * 0.1).sin();
            let std: f64 = if k == 0 { 0.2 } else { 0.002 };
            let noise = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0) * std * 3f64.sqrt());
            let r = UnitQuaternion::from_scaled_axis(noise)
                * UnitQuaternion::from_scaled_axis(n * theta)
                * UnitQuaternion::from_rotation_matrix(&c);
            rotations.push(r.to_rotation_matrix().into_inner());
            covs.push(Matrix3::identity() * std * std);
        }
        let got = fixed_axis(&rotations, &covs, None).expect("axis");
        let err = got.cross(&n).norm().asin().to_degrees();
        assert!(err < 0.2, "axis error {err} deg");
    }
}
