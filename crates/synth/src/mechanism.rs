//! Mechanisms: boxes joined by a tree of revolute, prismatic and spherical joints.

use kinetree_core::{Error, Result};
use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// An axis-aligned box in its body's frame (world coordinates at the zero configuration).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BoxShape {
    /// Centre, metres.
    pub centre: [f64; 3],
    /// Half extents along x, y, z, metres.
    pub half_extents: [f64; 3],
}

impl BoxShape {
    /// The eight corners, in binary order of (x, y, z) signs (- before +).
    pub fn corners(&self) -> [Point3<f64>; 8] {
        let c = Vector3::from(self.centre);
        let h = Vector3::from(self.half_extents);
        std::array::from_fn(|k| {
            let s = Vector3::new(
                if k & 4 == 0 { -1.0 } else { 1.0 },
                if k & 2 == 0 { -1.0 } else { 1.0 },
                if k & 1 == 0 { -1.0 } else { 1.0 },
            );
            Point3::from(c + s.component_mul(&h))
        })
    }

    /// Entry parameter of the segment `o + s d`, `s` in `[0, 1]`, into the box shrunk by
    /// `shrink`; `None` when the segment misses it.
    pub fn segment_entry(&self, o: &Point3<f64>, d: &Vector3<f64>, shrink: f64) -> Option<f64> {
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for i in 0..3 {
            let min = self.centre[i] - self.half_extents[i] + shrink;
            let max = self.centre[i] + self.half_extents[i] - shrink;
            if d[i].abs() < 1e-15 {
                if o[i] < min || o[i] > max {
                    return None;
                }
                continue;
            }
            let (mut a, mut b) = ((min - o[i]) / d[i], (max - o[i]) / d[i]);
            if a > b {
                std::mem::swap(&mut a, &mut b);
            }
            lo = lo.max(a);
            hi = hi.min(b);
            if lo > hi {
                return None;
            }
        }
        Some(lo)
    }
}

/// One rigid body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BodySpec {
    /// Name for reports.
    pub name: String,
    /// Its shape.
    pub shape: BoxShape,
    /// Corners left without a keypoint (indices 0-7 as in [`BoxShape::corners`]).
    #[serde(default)]
    pub skip_corners: Vec<usize>,
    /// Extra keypoints at random places on the box surface.
    #[serde(default)]
    pub extra_points: usize,
    /// Keypoints at random places inside the box (general position; use without
    /// self-occlusion, which would always hide them).
    #[serde(default)]
    pub interior_points: usize,
    /// Keypoints at given places (world coordinates at the zero configuration), after the
    /// others: markers on a joint's axis or centre, rigid with both bodies it joins.
    #[serde(default)]
    pub marked_points: Vec<[f64; 3]>,
}

/// Joint type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JointType {
    /// Rotation about the axis through the anchor.
    Revolute,
    /// Translation along the axis.
    Prismatic,
    /// Rotation about the anchor, any axis: three coordinates, the rotation vector (radians,
    /// world axes at the zero configuration); the spec's axis is not used.
    Spherical,
    /// Rotation about the axis and then the second axis, both through the anchor: two
    /// coordinates, the angle about the axis (fixed in the parent) and about the second axis
    /// (fixed in the child; world coordinates at the zero configuration).
    Universal,
    /// Any motion: six coordinates, the translation (metres, world axes) and then the rotation
    /// vector about the anchor (radians, world axes at the zero configuration); a floating
    /// body's motion against the base, which then carries no keypoints. The spec's axis is not
    /// used.
    Free,
}

impl JointType {
    /// Number of coordinates of a joint of this type.
    pub fn n_coordinates(self) -> usize {
        match self {
            Self::Revolute | Self::Prismatic => 1,
            Self::Universal => 2,
            Self::Spherical => 3,
            Self::Free => 6,
        }
    }
}

/// A joint; axis and anchor (a point on a revolute axis, a spherical joint's centre) in world
/// coordinates at the zero configuration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JointSpec {
    /// Parent body index.
    pub parent: usize,
    /// Child body index.
    pub child: usize,
    /// Joint type.
    #[serde(rename = "type")]
    pub joint_type: JointType,
    /// Axis direction (normalised on use).
    pub axis: [f64; 3],
    /// A point on the axis (revolute), metres.
    pub anchor: [f64; 3],
    /// A universal joint's second axis, fixed in the child (normalised on use); absent for
    /// other joints.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_axis: Option<[f64; 3]>,
}

/// A mechanism: body 0 is the base; joints form a tree over the bodies.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mechanism {
    /// Bodies.
    pub bodies: Vec<BodySpec>,
    /// Joints, each child appearing once, parents before children.
    pub joints: Vec<JointSpec>,
}

impl Mechanism {
    /// Checks that the joints form a tree rooted at body 0 with parents listed first.
    ///
    /// # Errors
    /// [`Error::Config`] naming the first problem.
    pub fn validate(&self) -> Result<()> {
        let n = self.bodies.len();
        if n == 0 {
            return Err(Error::Config("a mechanism needs at least one body".into()));
        }
        if self.joints.len() != n - 1 {
            return Err(Error::Config(format!(
                "{n} bodies need {} joints, found {}",
                n - 1,
                self.joints.len()
            )));
        }
        let mut placed = vec![false; n];
        placed[0] = true;
        for (k, j) in self.joints.iter().enumerate() {
            if j.parent >= n || j.child >= n || !placed[j.parent] || placed[j.child] {
                return Err(Error::Config(format!(
                    "joint {k} ({} -> {}) must attach a new child to an earlier body",
                    j.parent, j.child
                )));
            }
            if Vector3::from(j.axis).norm() < 1e-12 {
                return Err(Error::Config(format!("joint {k} has a zero axis")));
            }
            if j.joint_type == JointType::Universal
                && j.second_axis
                    .is_none_or(|a| Vector3::from(a).norm() < 1e-12)
            {
                return Err(Error::Config(format!(
                    "joint {k} is universal and needs a second axis"
                )));
            }
            placed[j.child] = true;
        }
        Ok(())
    }

    /// The parent of body `body`: the body its joint hangs it on (`None` for the base or a
    /// body no joint names).
    pub fn parent_of(&self, body: usize) -> Option<usize> {
        self.joints
            .iter()
            .find(|j| j.child == body)
            .map(|j| j.parent)
    }

    /// Number of joint coordinates: [`JointType::n_coordinates`] summed over the joints.
    pub fn n_coordinates(&self) -> usize {
        self.joints
            .iter()
            .map(|j| j.joint_type.n_coordinates())
            .sum()
    }

    /// Index of each joint's first coordinate in the configuration vector (joints in order,
    /// each with [`JointType::n_coordinates`] entries).
    pub fn coordinate_offsets(&self) -> Vec<usize> {
        self.joints
            .iter()
            .scan(0, |next, j| {
                let at = *next;
                *next += j.joint_type.n_coordinates();
                Some(at)
            })
            .collect()
    }

    /// `world_from_body` for every body at the configuration `q` (radians or metres, laid out
    /// as [`Mechanism::coordinate_offsets`] says); missing coordinates count as zero.
    pub fn forward(&self, q: &[f64]) -> Vec<Isometry3<f64>> {
        let mut pose = vec![Isometry3::identity(); self.bodies.len()];
        let mut next = 0;
        for j in &self.joints {
            let n = j.joint_type.n_coordinates();
            let coordinate = |i: usize| q.get(next + i).copied().unwrap_or(0.0);
            let a = Vector3::from(j.anchor);
            let about_anchor =
                |turn: UnitQuaternion<f64>| Translation3::from(a) * turn * Translation3::from(-a);
            let local = match j.joint_type {
                JointType::Revolute => about_anchor(UnitQuaternion::from_axis_angle(
                    &Unit::new_normalize(Vector3::from(j.axis)),
                    coordinate(0),
                )),
                JointType::Prismatic => Isometry3::from_parts(
                    Translation3::from(Vector3::from(j.axis).normalize() * coordinate(0)),
                    UnitQuaternion::identity(),
                ),
                JointType::Spherical => about_anchor(UnitQuaternion::from_scaled_axis(
                    Vector3::new(coordinate(0), coordinate(1), coordinate(2)),
                )),
                JointType::Free => {
                    Translation3::new(coordinate(0), coordinate(1), coordinate(2))
                        * about_anchor(UnitQuaternion::from_scaled_axis(Vector3::new(
                            coordinate(3),
                            coordinate(4),
                            coordinate(5),
                        )))
                }
                JointType::Universal => {
                    let second = j.second_axis.map_or_else(Vector3::z, Vector3::from);
                    about_anchor(
                        UnitQuaternion::from_axis_angle(
                            &Unit::new_normalize(Vector3::from(j.axis)),
                            coordinate(0),
                        ) * UnitQuaternion::from_axis_angle(
                            &Unit::new_normalize(second),
                            coordinate(1),
                        ),
                    )
                }
            };
            next += n;
            pose[j.child] = pose[j.parent] * local;
        }
        pose
    }
}
