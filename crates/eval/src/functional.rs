//! The functional methods of biomechanics as a baseline: SCoRE for joint centres and SARA for
//! joint axes (Ehrig et al., J. Biomech. 2006 and 2007), run on the poses of the *true*
//! segmentation, so a sweep can set kinetree's centre and axis errors beside theirs on the
//! same data.
//!
//! Both solve one linear least-squares problem over the frames where both bodies have a pose:
//! a point `x_p` fixed in the parent and `x_c` fixed in the child that coincide in the camera
//! frame, `R_p x_p + t_p = R_c x_c + t_c`. SCoRE takes its solution as the centre; for a hinge
//! the solutions form a line, and SARA takes it from the smallest singular value's vector.

use crate::axis_error_deg;
use kinetree_core::{BodyTrack, MIN_BODY_POINTS, Result, Segmentation, Tracks};
use kinetree_core::{PoseEstimator, PoseInput};
use kinetree_synth::{GroundTruth, JointType};
use nalgebra::{Isometry3, Matrix6, Point3, Vector3, Vector6};
use serde::{Deserialize, Serialize};

/// The least-squares system of two bodies' poses: its normal matrix and right-hand side in
/// the unknowns `(x_p, x_c)`, and the frames it holds.
struct Coincidence {
    normal: Matrix6<f64>,
    rhs: Vector6<f64>,
    n_frames: usize,
}

impl Coincidence {
    fn of(parent: &[Option<Isometry3<f64>>], child: &[Option<Isometry3<f64>>]) -> Self {
        let mut normal = Matrix6::zeros();
        let mut rhs = Vector6::zeros();
        let mut n_frames = 0;
        for (p, c) in parent.iter().zip(child) {
            let (Some(p), Some(c)) = (p, c) else { continue };
            // One frame's rows: [R_p, -R_c] (x_p, x_c) = t_c - t_p.
            let mut a = nalgebra::Matrix3x6::zeros();
            a.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(p.rotation.to_rotation_matrix().matrix());
            a.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&(-c.rotation.to_rotation_matrix().matrix()));
            let b = c.translation.vector - p.translation.vector;
            normal += a.transpose() * a;
            rhs += a.transpose() * b;
            n_frames += 1;
        }
        Self {
            normal,
            rhs,
            n_frames,
        }
    }

    /// The least-squares solution with the singular directions whose values are below
    /// `floor` times the largest left out (the minimum-norm solution), and the direction of
    /// the smallest singular value.
    fn solve(&self, floor: f64) -> Option<(Vector6<f64>, Vector6<f64>)> {
        if self.n_frames < 3 {
            return None;
        }
        let eig = self.normal.symmetric_eigen();
        let largest = eig.eigenvalues.max();
        if !(largest.is_finite() && largest > 0.0) {
            return None;
        }
        let mut x = Vector6::zeros();
        for k in 0..6 {
            let v = eig.eigenvectors.column(k);
            let l = eig.eigenvalues[k];
            if l > floor * largest {
                x += v * (v.dot(&self.rhs) / l);
            }
        }
        let smallest = eig.eigenvalues.imin();
        Some((x, eig.eigenvectors.column(smallest).into_owned()))
    }
}

/// A joint centre by SCoRE: the point of each body's frame that stays together with the
/// other's in every frame where both have a pose, `(in parent, in child)`; `None` with fewer
/// than three such frames or when the poses cannot fix a point (no relative rotation).
pub fn score_centre(
    parent: &[Option<Isometry3<f64>>],
    child: &[Option<Isometry3<f64>>],
) -> Option<(Point3<f64>, Point3<f64>)> {
    // A ball joint's six unknowns are all determined; only a hinge's line (one direction)
    // or no motion at all leave some of them free.
    let (x, _) = Coincidence::of(parent, child).solve(1e-12)?;
    Some((Point3::new(x[0], x[1], x[2]), Point3::new(x[3], x[4], x[5])))
}

/// A hinge axis by SARA: the line of points that stay together in both bodies' frames,
/// `(unit direction in the parent, a point on it in the parent)`: the direction from the
/// smallest singular value of the coincidence system, the point its least-squares solution
/// without that direction; `None` as for [`score_centre`].
pub fn sara_axis(
    parent: &[Option<Isometry3<f64>>],
    child: &[Option<Isometry3<f64>>],
) -> Option<(Vector3<f64>, Point3<f64>)> {
    let system = Coincidence::of(parent, child);
    let eig = system.normal.symmetric_eigen();
    let smallest = eig.eigenvalues.min();
    // Leave out exactly the smallest direction: the floor sits just above it.
    let floor = (smallest.max(0.0) * (1.0 + 1e-9) + f64::MIN_POSITIVE) / eig.eigenvalues.max();
    let (x, along) = system.solve(floor)?;
    let direction = Vector3::new(along[0], along[1], along[2]);
    let norm = direction.norm();
    (norm > 1e-9).then(|| (direction / norm, Point3::new(x[0], x[1], x[2])))
}

/// The functional methods' errors on one true joint, in the parent's true body frame (the
/// estimated parent frame aligned on the true keypoints, as
/// [`crate::JointEval::centre_error_in_parent_m`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FunctionalEval {
    /// True joint index.
    pub joint: usize,
    /// SCoRE's centre error, metres (spherical and universal joints).
    pub centre_error_in_parent_m: Option<f64>,
    /// SARA's axis error, degrees (revolute joints).
    pub axis_error_in_parent_deg: Option<f64>,
    /// Distance from the true anchor to SARA's axis line, metres (revolute joints).
    pub pivot_error_in_parent_m: Option<f64>,
}

/// SCoRE on every true spherical and universal joint and SARA on every revolute one, on the poses that
/// `pose` (a pose stage) gives the true segmentation of `tracks` at noise level
/// `noise_sigma_m`.
///
/// # Errors
/// The pose stage's, and [`kinetree_core::Error::Shape`] when the truth is not of `tracks`.
pub fn functional_errors(
    tracks: &Tracks,
    truth: &GroundTruth,
    pose: &dyn PoseEstimator,
    noise_sigma_m: f64,
) -> Result<Vec<FunctionalEval>> {
    if truth.point_body.len() != tracks.n_points() {
        return Err(kinetree_core::Error::Shape {
            expected: format!("the truth's {} points", truth.point_body.len()),
            found: format!("tracks of {} points", tracks.n_points()),
        });
    }
    let raw: Vec<Option<usize>> = truth.point_body.iter().copied().map(Some).collect();
    let segmentation = Segmentation::from_raw(&raw, MIN_BODY_POINTS);
    let poses = pose.estimate(&PoseInput {
        tracks,
        segmentation: &segmentation,
        noise_sigma_m,
    })?;
    // The segmentation numbers bodies by first point; index its tracks by true body.
    let mut of_true: Vec<Option<&BodyTrack>> = vec![None; truth.n_bodies()];
    for (point, &b) in truth.point_body.iter().enumerate() {
        if let (Some(slot), Some(id)) = (of_true.get_mut(b), segmentation.body_of(point)) {
            *slot = poses.bodies.get(id);
        }
    }
    Ok(errors_on(&of_true, truth))
}

/// [`functional_errors`] on the tracks of each true body.
fn errors_on(of_true: &[Option<&BodyTrack>], truth: &GroundTruth) -> Vec<FunctionalEval> {
    truth
        .mechanism
        .joints
        .iter()
        .enumerate()
        .map(|(k, spec)| {
            let mut e = FunctionalEval {
                joint: k,
                centre_error_in_parent_m: None,
                axis_error_in_parent_deg: None,
                pivot_error_in_parent_m: None,
            };
            let (Some(Some(p)), Some(Some(c))) =
                (of_true.get(spec.parent), of_true.get(spec.child))
            else {
                return e;
            };
            let Some(align) = crate::truth::shape_alignment(
                &p.points,
                p.shape
                    .iter()
                    .zip(&p.placed)
                    .map(|(s, &ok)| ok.then_some(*s)),
                truth,
                spec.parent,
            ) else {
                return e;
            };
            let anchor = Point3::from(spec.anchor);
            match spec.joint_type {
                JointType::Spherical | JointType::Universal => {
                    e.centre_error_in_parent_m = score_centre(&p.cam_from_body, &c.cam_from_body)
                        .map(|(centre, _)| (align * centre - anchor).norm());
                }
                JointType::Revolute => {
                    if let Some((axis, point)) = sara_axis(&p.cam_from_body, &c.cam_from_body) {
                        let axis = align.rotation * axis;
                        e.axis_error_in_parent_deg =
                            Some(axis_error_deg(&axis, &Vector3::from(spec.axis).normalize()));
                        e.pivot_error_in_parent_m =
                            Some(crate::point_line_distance(&anchor, &(align * point), &axis));
                    }
                }
                JointType::Prismatic | JointType::Free => {}
            }
            e
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// One body's pose per frame.
    type Track = Vec<Option<Isometry3<f64>>>;

    /// Poses of a parent and a child joined at `centre_p` (parent frame) / `centre_c` (child
    /// frame), the child turned by `turn(k)` about the joint in each frame.
    fn joined(
        turn: impl Fn(usize) -> UnitQuaternion<f64>,
        centre_p: Point3<f64>,
        centre_c: Point3<f64>,
    ) -> (Track, Track) {
        (0..40)
            .map(|k| {
                let t = k as f64;
                let parent = Isometry3::from_parts(
                    Translation3::new(0.1 * t.sin(), 0.2, 0.01 * t),
                    UnitQuaternion::from_euler_angles(0.1 * t.cos(), 0.05 * t, 0.3),
                );
                // child_from_parent maps centre_p to centre_c after the turn.
                let at_p = Translation3::from(centre_p.coords);
                let at_c = Translation3::from(centre_c.coords);
                let child = parent * at_p * turn(k) * at_c.inverse();
                (Some(parent), Some(child))
            })
            .unzip()
    }

    #[test]
    fn score_finds_a_ball_centre_in_both_frames() {
        let (cp, cc) = (Point3::new(0.1, -0.2, 0.3), Point3::new(-0.05, 0.4, 0.0));
        let (p, c) = joined(
            |k| {
                let t = k as f64;
                UnitQuaternion::from_euler_angles(0.5 * (0.3 * t).sin(), 0.4 * t.cos(), 0.1 * t)
            },
            cp,
            cc,
        );
        let (xp, xc) = score_centre(&p, &c).expect("centre");
        assert!((xp - cp).norm() < 1e-9, "{xp}");
        assert!((xc - cc).norm() < 1e-9, "{xc}");
        // Too few frames: none.
        assert!(score_centre(&p[..2], &c[..2]).is_none());
    }

    #[test]
    fn sara_finds_a_hinge_axis() {
        let axis = Vector3::new(0.2, 0.9, -0.3).normalize();
        let (cp, cc) = (Point3::new(0.1, -0.2, 0.3), Point3::new(-0.05, 0.4, 0.0));
        let (p, c) = joined(
            |k| UnitQuaternion::from_scaled_axis(axis * (0.2 * k as f64).sin()),
            cp,
            cc,
        );
        let (a, point) = sara_axis(&p, &c).expect("axis");
        assert!(axis_error_deg(&a, &axis) < 1e-6, "{a}");
        assert!(crate::point_line_distance(&cp, &point, &a) < 1e-9);
    }
}
