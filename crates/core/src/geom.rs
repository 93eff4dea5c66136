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
/// about their line is undetermined. The check reuses the fit's own SVD.
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
    let svd = h.svd(true, true);
    let mut sv = svd.singular_values;
    sv.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if min_ratio > 0.0 && (sv[1].is_nan() || sv[1] <= min_ratio * sv[0]) {
        return None;
    }
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
