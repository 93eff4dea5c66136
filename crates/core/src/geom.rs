//! Small rigid-motion helpers shared by the stages: the log map, relative motions, angles.

use crate::BodyPoses;
use nalgebra::{Isometry3, Rotation3, UnitQuaternion, Vector3};

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

/// Flips `v` so that its component of largest magnitude is positive (a deterministic sign for
/// axes, which are only defined up to sign).
pub fn canonical_sign(v: Vector3<f64>) -> Vector3<f64> {
    let i = v.iamax();
    if v[i] < 0.0 { -v } else { v }
}
