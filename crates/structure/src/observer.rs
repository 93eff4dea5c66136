//! The observer: joint positions of new frames from a discovered model.

use kinetree_core::geom::{angle_about, kabsch_with_rank_check};
use kinetree_core::nalgebra::{
    Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3,
};
use kinetree_core::{Error, Model, Result};

#[derive(Debug, Clone)]
struct ObservedBody {
    /// `(point index, position in the body frame)` for every placed point.
    shape: Vec<(usize, Point3<f64>)>,
}

#[derive(Debug, Clone, Copy)]
enum Measure {
    /// Axis and a point on it, both in the parent's body frame.
    Revolute(Vector3<f64>, Point3<f64>),
    Prismatic(Vector3<f64>),
    /// Not a single-DoF joint, or no reference pose: no position.
    None,
}

#[derive(Debug, Clone)]
struct ObservedJoint {
    parent: usize,
    child: usize,
    measure: Measure,
    reference: Isometry3<f64>,
}

/// Estimates joint positions of new frames from a discovered [`Model`]: every body's pose by
/// Kabsch-Umeyama on its visible, placed points (at least three, not collinear), then each
/// joint's position from the child's pose in the parent's frame, measured from the model's
/// reference pose exactly as the batch run measures it. Revolute angles are returned wrapped
/// to `(-pi, pi]`; unwrap a sequence with [`kinetree_core::geom::unwrap_angles`].
///
/// Complexity: one 3 x 3 SVD per body per frame.
#[derive(Debug, Clone)]
pub struct Observer {
    n_points: usize,
    bodies: Vec<ObservedBody>,
    joints: Vec<ObservedJoint>,
}

fn vector(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

impl Observer {
    /// Builds the observer from a model.
    ///
    /// # Errors
    /// [`Error::Config`] when the model has no reference shapes (written by an older version)
    /// or a joint names a body that does not exist.
    pub fn new(model: &Model) -> Result<Self> {
        let bodies = model
            .bodies
            .iter()
            .map(|b| {
                if b.shape.len() != b.points.len() {
                    return Err(Error::Config(format!(
                        "body {} has {} shape entries for {} points; rediscover with this version",
                        b.id,
                        b.shape.len(),
                        b.points.len()
                    )));
                }
                let shape = b
                    .points
                    .iter()
                    .zip(&b.shape)
                    .filter_map(|(&i, s)| s.map(|s| (i, Point3::from(vector(s)))))
                    .collect();
                Ok(ObservedBody { shape })
            })
            .collect::<Result<Vec<_>>>()?;
        let joints = model
            .joints
            .iter()
            .map(|j| {
                if j.parent >= bodies.len() || j.child >= bodies.len() {
                    return Err(Error::Config(format!(
                        "joint {} -> {} names a missing body",
                        j.parent, j.child
                    )));
                }
                let (measure, reference) = match (j.reference_pose, j.axis_in_parent) {
                    (Some(r), Some(axis)) => {
                        let [x, y, z, w] = r.rotation_xyzw;
                        let rotation = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
                        let reference = Isometry3::from_parts(
                            Translation3::from(vector(r.translation)),
                            rotation,
                        );
                        let axis = vector(axis);
                        let pivot = Point3::from(vector(j.point_in_parent.unwrap_or([0.0; 3])));
                        let measure = match j.joint_type.as_str() {
                            "revolute" => Measure::Revolute(axis, pivot),
                            "prismatic" => Measure::Prismatic(axis),
                            _ => Measure::None,
                        };
                        (measure, reference)
                    }
                    _ => (Measure::None, Isometry3::identity()),
                };
                Ok(ObservedJoint {
                    parent: j.parent,
                    child: j.child,
                    measure,
                    reference,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            n_points: model.n_points,
            bodies,
            joints,
        })
    }

    /// Number of joints (the length of [`Observer::observe`]'s result).
    pub fn n_joints(&self) -> usize {
        self.joints.len()
    }

    /// Every body's `camera_from_body` in one frame, `None` with fewer than three visible
    /// placed points or collinear ones.
    pub fn body_poses(&self, frame: &[Option<Point3<f64>>]) -> Vec<Option<Isometry3<f64>>> {
        self.bodies
            .iter()
            .map(|b| {
                let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = b
                    .shape
                    .iter()
                    .filter_map(|&(i, s)| frame.get(i).copied().flatten().map(|p| (s, p)))
                    .unzip();
                kabsch_with_rank_check(&src, &dst, 1e-6)
            })
            .collect()
    }

    /// Joint positions in one frame (radians wrapped to `(-pi, pi]`, or metres), `None` where
    /// either body has no pose or the joint is not single-DoF.
    ///
    /// # Errors
    /// [`Error::Shape`] when the frame does not have the model's number of points.
    pub fn observe(&self, frame: &[Option<Point3<f64>>]) -> Result<Vec<Option<f64>>> {
        if frame.len() != self.n_points {
            return Err(Error::Shape {
                expected: format!("{} points per frame", self.n_points),
                found: format!("{} points", frame.len()),
            });
        }
        Ok(self.positions(&self.body_poses(frame)))
    }

    /// Joint positions from body poses (see [`Observer::observe`]).
    fn positions(&self, poses: &[Option<Isometry3<f64>>]) -> Vec<Option<f64>> {
        self.joints
            .iter()
            .map(|j| {
                let x = poses[j.parent]?.inverse() * poses[j.child]?;
                match j.measure {
                    Measure::Revolute(axis, _) => Some(angle_about(
                        &(x.rotation * j.reference.rotation.inverse()),
                        &axis,
                    )),
                    Measure::Prismatic(axis) => {
                        Some(axis.dot(&(x.translation.vector - j.reference.translation.vector)))
                    }
                    Measure::None => None,
                }
            })
            .collect()
    }

    /// `parent_from_child` at joint position `q` (None for a joint with no single DoF).
    fn joint_transform(j: &ObservedJoint, q: f64) -> Option<Isometry3<f64>> {
        match j.measure {
            Measure::Revolute(axis, pivot) => {
                let unit = kinetree_core::nalgebra::Unit::new_normalize(axis);
                let turn = Translation3::from(pivot.coords)
                    * UnitQuaternion::from_axis_angle(&unit, q)
                    * Translation3::from(-pivot.coords);
                // The reference pose carries the child to q = 0; the rotation about the pivot
                // line then moves it to q.
                Some(turn * j.reference)
            }
            Measure::Prismatic(axis) => Some(Translation3::from(axis * q) * j.reference),
            Measure::None => None,
        }
    }

    /// RMS distance, in units of `sigma`, between every observed keypoint and its position
    /// re-predicted from the model: the root's pose (fitted per frame) carried down the tree
    /// by the joint positions alone. Bodies below a joint with no single DoF keep their own
    /// fitted pose. Fitted poses alone give about 1.2-1.6; each joint adds its axis and pivot
    /// errors times the motion (the paper arm, whose joints sweep 3-6 rad, measures 4.0 with
    /// 0.2 and 0.8 deg axis errors), and a wrong joint makes it far larger. `None` with no
    /// usable frame.
    ///
    /// # Errors
    /// [`Error::Shape`] when the tracks do not have the model's points.
    pub fn reprediction_rms_in_sigma(
        &self,
        tracks: &kinetree_core::Tracks,
        sigma: f64,
    ) -> Result<Option<f64>> {
        if tracks.n_points() != self.n_points {
            return Err(Error::Shape {
                expected: format!("{} points", self.n_points),
                found: format!("{} points", tracks.n_points()),
            });
        }
        let (mut sum, mut count) = (0.0, 0usize);
        for t in 0..tracks.n_frames() {
            let frame: Vec<Option<Point3<f64>>> =
                (0..self.n_points).map(|i| tracks.get(t, i)).collect();
            let fitted = self.body_poses(&frame);
            let q = self.positions(&fitted);
            // Joints are listed with parents before children (tree order).
            let mut predicted = fitted.clone();
            for (j, qj) in self.joints.iter().zip(&q) {
                let via_joint = match (predicted[j.parent], qj) {
                    (Some(parent), Some(qv)) => Self::joint_transform(j, *qv).map(|x| parent * x),
                    _ => None,
                };
                predicted[j.child] = via_joint.or(fitted[j.child]);
            }
            for (b, pose) in self.bodies.iter().zip(&predicted) {
                let Some(pose) = pose else { continue };
                for &(i, s) in &b.shape {
                    if let Some(p) = frame[i] {
                        sum += (pose * s - p).norm_squared();
                        count += 1;
                    }
                }
            }
        }
        Ok((count > 0 && sigma > 0.0).then(|| (sum / count as f64).sqrt() / sigma))
    }
}
