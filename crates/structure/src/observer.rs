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
    Revolute(Vector3<f64>),
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
                        let measure = match j.joint_type.as_str() {
                            "revolute" => Measure::Revolute(axis),
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
        let poses = self.body_poses(frame);
        Ok(self
            .joints
            .iter()
            .map(|j| {
                let x = poses[j.parent]?.inverse() * poses[j.child]?;
                match j.measure {
                    Measure::Revolute(axis) => Some(angle_about(
                        &(x.rotation * j.reference.rotation.inverse()),
                        &axis,
                    )),
                    Measure::Prismatic(axis) => {
                        Some(axis.dot(&(x.translation.vector - j.reference.translation.vector)))
                    }
                    Measure::None => None,
                }
            })
            .collect())
    }
}
