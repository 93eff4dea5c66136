//! Small rigid-motion helpers shared by the stages: the log map, relative motions, angles.

use crate::BodyPoses;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Axis-angle vector `theta * axis` of a rotation, robust at `pi` and near the identity.
///
/// Goes through the quaternion: `Rotation3::scaled_axis` picks a wrong axis at exactly `pi`
/// and `Rotation3::angle` returns NaN when the trace slightly exceeds 3.
pub fn log_so3(r: &Rotation3<f64>) -> Vector3<f64> {
    UnitQuaternion::from_rotation_matrix(r).scaled_axis()
}

/// Signed rotation angle of `q` about the unit `axis`, in `(-pi, pi]`: the twist component
/// of the swing-twist decomposition.
pub fn angle_about(q: &UnitQuaternion<f64>, axis: &Vector3<f64>) -> f64 {
    let v = q.imag();
    let a = 2.0 * v.dot(axis).atan2(q.w);
    // atan2 of (s, w) gives an angle in (-2pi, 2pi]; fold into (-pi, pi].
    wrap_pi(a)
}

/// Wraps an angle into `(-pi, pi]`.
pub fn wrap_pi(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut x = a % two_pi;
    if x <= -std::f64::consts::PI {
        x += two_pi;
    } else if x > std::f64::consts::PI {
        x -= two_pi;
    }
    x
}

/// Unwraps a sequence of angles (with gaps) so consecutive known values differ by less
/// than `pi`.
pub fn unwrap_angles(angles: &mut [Option<f64>]) {
    let mut prev: Option<f64> = None;
    for a in angles.iter_mut().flatten() {
        if let Some(p) = prev {
            *a = p + wrap_pi(*a - p);
        }
        prev = Some(*a);
    }
}

/// Pose of frame `a` (the camera when `None`) in the camera frame at `frame`.
pub fn cam_from(poses: &BodyPoses, a: Option<usize>, frame: usize) -> Option<Isometry3<f64>> {
    match a {
        None => Some(Isometry3::identity()),
        Some(b) => poses.bodies[b].cam_from_body[frame],
    }
}

/// `a_from_b` at every frame: the pose of body `b` in frame `a`'s body frame, `None` where
/// either is not registered.
pub fn relative_poses(
    poses: &BodyPoses,
    a: Option<usize>,
    b: usize,
) -> Vec<Option<Isometry3<f64>>> {
    (0..poses.n_frames)
        .map(|t| {
            let ca = cam_from(poses, a, t)?;
            let cb = cam_from(poses, Some(b), t)?;
            Some(ca.inverse() * cb)
        })
        .collect()
}

/// `count` unit vectors spread evenly over the half sphere `z >= 0` (a Fibonacci spiral): a
/// direction and its opposite are one axis.
pub fn hemisphere(count: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..count)
        .map(|i| {
            let z = (i as f64 + 0.5) / count as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * i as f64;
            Vector3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Two unit vectors `(e1, e2)` spanning the plane perpendicular to the unit vector `v`, with
/// `(e1, e2, v)` right-handed: `e1 = v x x` normalised (`v x y` when `v` is within 26 deg of
/// x, where that cross product would be short).
pub fn perpendicular_basis(v: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if v.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = v.cross(&helper).normalize();
    (e1, v.cross(&e1))
}

/// Flips `v` so that its component of largest magnitude is positive (a deterministic sign for
/// axes, which are only defined up to sign).
pub fn canonical_sign(v: Vector3<f64>) -> Vector3<f64> {
    let i = v.iamax();
    if v[i] < 0.0 { -v } else { v }
}

/// Centroid of a non-empty point set.
pub fn centroid(p: &[Point3<f64>]) -> Point3<f64> {
    let s: Vector3<f64> = p.iter().map(|q| q.coords).sum();
    Point3::from(s / p.len() as f64)
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

/// The rigid transform `T` minimising `sum |T src_i - dst_i|^2` (rotation with det +1).
///
/// Returns `None` with fewer than three pairs or when the SVD fails. Degenerate (collinear)
/// sets give an arbitrary rotation about their line; check with `spread` first.
///
/// Reference: Kabsch (1976), Umeyama (1991), without scale.
pub fn kabsch(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Option<Isometry3<f64>> {
    kabsch_with_rank_check(src, dst, 0.0)
}

/// [`kabsch`], returning `None` also when the cross-covariance `H` is nearly rank one (its
/// second singular value below `min_ratio` times the first): collinear points, whose rotation
/// about their line is undetermined.
///
/// The rotation is the proper polar factor of `H` by Newton's iteration
/// ([`proper_rotation_of`]); the SVD is the fallback where that iteration does not apply. The
/// rank check bounds the singular values' ratio through `H`'s norm and its cofactor matrix's,
/// and takes the SVD's singular values only when those bounds leave the answer open.
pub fn kabsch_with_rank_check(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    min_ratio: f64,
) -> Option<Isometry3<f64>> {
    if src.len() != dst.len() || src.len() < 3 {
        return None;
    }
    let cs = centroid(src);
    let cd = centroid(dst);
    let mut h = Matrix3::zeros();
    for (s, d) in src.iter().zip(dst) {
        h += (s - cs) * (d - cd).transpose();
    }
    let r = match rank_one_by_norms(&h, min_ratio) {
        Some(true) => return None,
        Some(false) => proper_rotation_of(&h).or_else(|| kabsch_rotation_by_svd(&h, 0.0))?,
        None => kabsch_rotation_by_svd(&h, min_ratio)?,
    };
    if !r.iter().all(|x| x.is_finite()) {
        return None;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = cd.coords - rot * cs.coords;
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

/// Whether `H`'s second singular value is at most `min_ratio` times its first, decided from
/// `n = |H|_F` and `c = |cof H|_F` alone, `None` where those bounds leave it open (or `H` is
/// not finite). `sigma_2 / sigma_1` lies in `[c / (sqrt(3) n^2), 3 c / n^2]`, because
/// `sigma_1 <= n <= sqrt(3) sigma_1` and `sigma_1 sigma_2 <= c <= sqrt(3) sigma_1 sigma_2`.
fn rank_one_by_norms(h: &Matrix3<f64>, min_ratio: f64) -> Option<bool> {
    if min_ratio <= 0.0 {
        return Some(false);
    }
    let n2 = h.norm_squared();
    let c = cofactor(h).norm();
    if !(n2.is_finite() && c.is_finite()) || n2 == 0.0 {
        return None;
    }
    if 3.0 * c < min_ratio * n2 {
        Some(true)
    } else if c > 3f64.sqrt() * min_ratio * n2 {
        Some(false)
    } else {
        None
    }
}

/// The Kabsch rotation of the cross-covariance `H` through its SVD (nalgebra's), `None` when
/// the SVD fails or (for `min_ratio > 0`) `H` is nearly rank one: the fallback of
/// [`kabsch_with_rank_check`] and the reference its tests and benchmark hold
/// [`proper_rotation_of`] to.
pub fn kabsch_rotation_by_svd(h: &Matrix3<f64>, min_ratio: f64) -> Option<Matrix3<f64>> {
    let svd = h.svd(true, true);
    let mut sv = svd.singular_values;
    sv.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if min_ratio > 0.0 && (sv[1].is_nan() || sv[1] <= min_ratio * sv[0]) {
        return None;
    }
    let u = svd.u?;
    let v = svd.v_t?.transpose();
    let d = (v * u.transpose()).determinant().signum();
    Some(v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose())
}

/// The cofactor matrix of `m`, `det(m) m^-T`, whose columns are cross products of `m`'s.
fn cofactor(m: &Matrix3<f64>) -> Matrix3<f64> {
    Matrix3::from_columns(&[
        m.column(1).cross(&m.column(2)),
        m.column(2).cross(&m.column(0)),
        m.column(0).cross(&m.column(1)),
    ])
}

/// Newton steps at most before [`proper_rotation_of`] gives up; it takes 3-6 on point sets
/// that are not nearly collinear.
const POLAR_MAX_STEPS: usize = 30;

/// [`proper_rotation_of`] stops when a step moves the iterate by at most this (Frobenius
/// norm); Newton's iteration converges quadratically, so the last iterate is then exact to
/// float rounding.
const POLAR_STEP_TOLERANCE: f64 = 1e-9;

/// The rotation `R` maximising `trace(R H)` (so `R` maps the source points of
/// `H = sum (s - c_s)(d - c_d)^T` onto the destination's), by the scaled Newton iteration for
/// the polar factor (Higham 1986), `None` where it does not apply.
///
/// With `H = U S V^T`, the Kabsch rotation is `V diag(1, 1, det(U V^T)) U^T`. The matrix
/// `M = H + cof(H) / |H|_F` is `U diag(s1 + e s2 s3 / k, s2 + e s1 s3 / k, s3 + e s1 s2 / k) V^T`
/// with `e = det(U V^T)` and `k = |H|_F`, so its polar factor's transpose is that rotation
/// whenever `det M > 0`; where the two smaller singular values are too close for the sign to
/// come out right (`s2 < sqrt(3) s3` at worst) `det M` is not positive and this returns
/// `None`. Adding the cofactor keeps `M` well conditioned for flat point sets, whose `H` is
/// nearly singular. The iteration is about 2.7 times faster than nalgebra's 3 x 3 SVD for
/// the same rotation; with the SVD, Kabsch fits are a fifth of a long recording's discovery
/// (`docs/decisions.md`).
pub fn proper_rotation_of(h: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let k = h.norm();
    if !(k > 0.0 && k.is_finite()) {
        return None;
    }
    let m = h + cofactor(h) / k;
    let det = m.determinant();
    if det.is_nan() || det <= 0.0 {
        return None;
    }
    let mut x = m.transpose();
    for _ in 0..POLAR_MAX_STEPS {
        let inv = x.try_inverse()?;
        let gamma = (inv.norm() / x.norm()).sqrt();
        let next = (x * gamma + inv.transpose() / gamma) * 0.5;
        let moved = (next - x).norm();
        x = next;
        if moved <= POLAR_STEP_TOLERANCE {
            return Some(x);
        }
        if !moved.is_finite() {
            return None;
        }
    }
    None
}

/// Eigenvalues of a symmetric 3 x 3 matrix (its lower triangle is read), largest first, in
/// closed form (Smith's trigonometric solution of the characteristic cubic).
///
/// nalgebra's iterative solver (`symmetric_eigenvalues`) is the general tool; this one is
/// for the per-frame checks that call it millions of times on long recordings, where the
/// iterative solver was a fifth of a 200 000-frame discovery. The largest eigenvalue is
/// accurate to a few ulps of the matrix's norm; where two eigenvalues nearly coincide the
/// others can lose up to half the digits, which no threshold of ours is near.
pub fn symmetric_eigenvalues_3x3(m: &Matrix3<f64>) -> [f64; 3] {
    let (a00, a11, a22) = (m[(0, 0)], m[(1, 1)], m[(2, 2)]);
    let (a10, a20, a21) = (m[(1, 0)], m[(2, 0)], m[(2, 1)]);
    let off = a10 * a10 + a20 * a20 + a21 * a21;
    let q = (a00 + a11 + a22) / 3.0;
    let (d0, d1, d2) = (a00 - q, a11 - q, a22 - q);
    let p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * off;
    if off == 0.0 || p2 == 0.0 || !p2.is_finite() {
        let mut e = [a00, a11, a22];
        e.sort_by(|a, b| b.total_cmp(a));
        return e;
    }
    let p = (p2 / 6.0).sqrt();
    // det((A - q I) / p) / 2, the cosine of three times the angle.
    let det =
        d0 * (d1 * d2 - a21 * a21) - a10 * (a10 * d2 - a21 * a20) + a20 * (a10 * a21 - d1 * a20);
    let r = (det / (2.0 * p * p * p)).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let largest = q + 2.0 * p * phi.cos();
    let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    let middle = 3.0 * q - largest - smallest;
    [largest, middle.clamp(smallest, largest), smallest]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// nalgebra's eigenvalues, largest first.
    fn iterative(m: &Matrix3<f64>) -> [f64; 3] {
        let mut e: Vec<f64> = m.symmetric_eigenvalues().iter().copied().collect();
        e.sort_by(|a, b| b.total_cmp(a));
        [e[0], e[1], e[2]]
    }

    /// Pairs of point sets, source and noisy destination: in general position, flat, of three
    /// points, nearly collinear, and so noisy that the best rotation is close to a
    /// reflection's.
    type PointSets = Vec<(Vec<Point3<f64>>, Vec<Point3<f64>>)>;

    fn point_set_pairs() -> PointSets {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
        let mut sets = Vec::new();
        for case in 0..4000 {
            let n = 3 + case % 9;
            let flat = [1.0, 1e-3, 0.0, 1.0][case % 4];
            // Every seventh set nearly collinear, from 1e-7 to 1e-2 across its line.
            let thin = if case % 7 == 0 {
                10f64.powf(-7.0 + 0.25 * ((case / 7) % 21) as f64)
            } else {
                1.0
            };
            let noise = [1e-4, 1e-2, 0.5][case % 3];
            let src: Vec<Point3<f64>> = (0..n)
                .map(|_| Point3::new(normal(), thin * normal(), flat * thin * normal()))
                .collect();
            let rot = UnitQuaternion::from_scaled_axis(Vector3::new(normal(), normal(), normal()));
            let shift = Vector3::new(normal(), normal(), normal());
            let dst = src
                .iter()
                .map(|p| rot * p + shift + Vector3::new(normal(), normal(), normal()) * noise)
                .collect();
            sets.push((src, dst));
        }
        sets
    }

    fn cross_covariance(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Matrix3<f64> {
        let (cs, cd) = (centroid(src), centroid(dst));
        src.iter()
            .zip(dst)
            .map(|(s, d)| (s - cs) * (d - cd).transpose())
            .sum()
    }

    #[test]
    fn the_polar_rotation_is_the_svds() {
        let mut newton = 0;
        for (src, dst) in point_set_pairs() {
            let h = cross_covariance(&src, &dst);
            let by_svd = kabsch_rotation_by_svd(&h, 0.0).expect("an SVD of a finite matrix");
            let Some(r) = proper_rotation_of(&h) else {
                continue;
            };
            newton += 1;
            assert!(
                (r.transpose() * r - Matrix3::identity()).norm() < 1e-14,
                "{r}"
            );
            assert!((r.determinant() - 1.0).abs() < 1e-14, "{r}");
            // Never a worse fit than the SVD's, beyond rounding.
            let k = h.norm();
            assert!((r * h).trace() >= (by_svd * h).trace() - 1e-14 * k, "{h}");
            // The same rotation wherever it is well determined. (Where the two smaller
            // singular values are close, nalgebra's SVD, which goes through `H^T H`, loses
            // digits the iteration keeps: 1e-10 apart at a gap of 1e-3 times the largest.)
            let sv = h.singular_values();
            let mut sv: Vec<f64> = sv.iter().copied().collect();
            sv.sort_by(|a, b| b.total_cmp(a));
            if sv[1] - sv[2] > 0.05 * sv[0] {
                assert!((r - by_svd).norm() < 1e-12, "{r} against {by_svd}");
            }
        }
        // The iteration, not the fallback, gives most of them.
        assert!(newton > 3000, "{newton}");
    }

    #[test]
    fn the_rank_check_decides_as_the_svd() {
        for min_ratio in [1e-6, 1e-3] {
            for (src, dst) in point_set_pairs() {
                let h = cross_covariance(&src, &dst);
                let fitted = kabsch_with_rank_check(&src, &dst, min_ratio);
                let by_svd = kabsch_rotation_by_svd(&h, min_ratio);
                assert_eq!(fitted.is_some(), by_svd.is_some(), "{h}");
                if let (Some(fitted), Some(by_svd)) = (fitted, by_svd) {
                    let fitted = fitted.rotation.to_rotation_matrix().into_inner();
                    let (k, score) = (h.norm(), |r: &Matrix3<f64>| (r * h).trace());
                    assert!(score(&fitted) >= score(&by_svd) - 1e-12 * k, "{h}");
                }
            }
        }
        // Collinear points: no rotation with the check, some rotation without it.
        let line: Vec<Point3<f64>> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(kabsch_with_rank_check(&line, &line, 1e-6).is_none());
        assert!(kabsch(&line, &line).is_some());
    }

    #[test]
    fn closed_form_eigenvalues_agree_with_the_iterative_solver() {
        let mut cases: Vec<Matrix3<f64>> = Vec::new();
        // Scatter matrices of point sets: general, flat, nearly collinear, and a few exact
        // degenerate ones (diagonal, rank one, a double and a triple eigenvalue).
        for k in 0..200 {
            let a = k as f64;
            let pts: Vec<Vector3<f64>> = (0..6)
                .map(|i| {
                    let b = a * 0.37 + i as f64;
                    let squash = [1.0, 1e-3, 1e-7][k % 3];
                    Vector3::new(b.sin(), (1.7 * b).cos() * 0.5, squash * (2.3 * b).sin())
                })
                .collect();
            let r = Rotation3::from_scaled_axis(Vector3::new(0.3 * a, -0.2, 0.1 * a.cos()));
            cases.push(pts.iter().map(|p| (r * p) * (r * p).transpose()).sum());
        }
        cases.push(Matrix3::from_diagonal(&Vector3::new(2.0, -1.0, 5.0)));
        let v = Vector3::new(1.0, 2.0, -0.5);
        cases.push(v * v.transpose());
        cases.push(Matrix3::identity() * 3.0 + v * v.transpose());
        cases.push(Matrix3::identity() * 0.25);
        for m in &cases {
            let ours = symmetric_eigenvalues_3x3(m);
            let theirs = iterative(m);
            let scale = theirs[0].abs().max(theirs[2].abs());
            assert!(
                (ours[0] - theirs[0]).abs() <= 1e-13 * scale,
                "{ours:?} against {theirs:?}"
            );
            for k in 1..3 {
                assert!(
                    (ours[k] - theirs[k]).abs() <= 1e-7 * scale,
                    "{ours:?} against {theirs:?}"
                );
            }
            assert!(ours[0] >= ours[1] && ours[1] >= ours[2], "{ours:?}");
        }
    }
}
