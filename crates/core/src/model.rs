//! The discovered kinematic model: what `kinetree discover` writes as JSON.
//!
//! The schema is documented in `docs/model-schema.md`; bump [`SCHEMA_VERSION`] on any change
//! that breaks readers.

mod check;

use crate::{PairDof, Warning};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

/// Version of the model JSON schema.
pub const SCHEMA_VERSION: u32 = 5;

/// Where the noise level came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseSource {
    /// Given by the user or the experiment config.
    Given,
    /// Estimated from the data.
    Estimated,
}

/// The noise level used by every test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoiseInfo {
    /// Per-coordinate std-dev of the keypoint noise, metres.
    pub sigma_m: f64,
    /// Variance of a point-to-point distance, `2 sigma^2`, m^2.
    pub distance_variance_m2: f64,
    /// Given or estimated.
    pub source: NoiseSource,
}

/// When the whole-tree fit reports a joint position as unknown, and when it smooths one
/// (`[pipeline.positions]`); the model carries them so that a later observation of new frames
/// reports positions as the discovery did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PositionLimits {
    /// A revolute position whose standard deviation exceeds this is reported unknown, radians
    /// (default 0.5: a position known to half a radian tells little of the configuration).
    pub max_std_rad: f64,
    /// A prismatic position whose standard deviation exceeds this at 1 mm of noise is
    /// reported unknown, metres; the per-frame bound scales with the model's noise level
    /// (default 0.1, that is 100 sigma).
    pub max_std_m: f64,
    /// Fewest frames with a position and its standard deviation for a joint's positions to be
    /// smoothed (default 3: the smoother's state has two entries).
    pub min_smoothed_frames: usize,
    /// A joint's type is identifiable when the coordinates that tell it from the other types
    /// spread over the frames, RMS about their mean, by at least this many of their
    /// per-frame standard deviations; below, a `joint_not_identifiable` warning names the
    /// types the data fit as well (default 3; `docs/decisions.md`).
    pub min_identifiable_spread_in_std: f64,
    /// A revolute joint whose child turns off the axis, relative to the parent, by at least
    /// this many standard deviations of the keypoint noise (the RMS about the mean of the
    /// largest principal direction, each frame's off-axis rotation whitened by the two
    /// bodies' rotation precision in that frame) gets a `joint_not_identifiable` warning
    /// naming the ball and universal joints: the pair tests took that motion for model error
    /// (default 2; pure noise gives about 1; `docs/decisions.md`).
    pub min_off_axis_spread_in_std: f64,
}

impl Default for PositionLimits {
    fn default() -> Self {
        Self {
            max_std_rad: 0.5,
            max_std_m: 0.1,
            min_smoothed_frames: 3,
            min_identifiable_spread_in_std: 3.0,
            min_off_axis_spread_in_std: 2.0,
        }
    }
}

impl PositionLimits {
    /// Checks the ranges; `section` names the config section or model field in the error.
    ///
    /// # Errors
    /// [`crate::Error::InvalidParameter`] naming `<section>.<parameter>`.
    pub fn validate(&self, section: &str) -> crate::Result<()> {
        let bad = |field: &str, message: String| crate::Error::InvalidParameter {
            name: format!("{section}.{field}"),
            message,
        };
        for (field, v) in [
            ("max_std_rad", self.max_std_rad),
            ("max_std_m", self.max_std_m),
            (
                "min_identifiable_spread_in_std",
                self.min_identifiable_spread_in_std,
            ),
            (
                "min_off_axis_spread_in_std",
                self.min_off_axis_spread_in_std,
            ),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(field, format!("must be finite and positive, got {v}")));
            }
        }
        crate::limits::check_count(
            &format!("{section}.min_smoothed_frames"),
            self.min_smoothed_frames,
            3,
            1_000_000,
        )
    }
}

/// Names of the stages that produced the model.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct StageNames {
    /// Dissimilarity measure.
    pub dissimilarity: String,
    /// Clustering method.
    pub clustering: String,
    /// Pose estimator.
    pub pose: String,
    /// DoF tester.
    pub dof: String,
}

/// One rigid body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Body {
    /// Body id (0-based; the root of the tree is body 0).
    pub id: usize,
    /// Its points, ascending.
    pub points: Vec<usize>,
    /// Whether it is static relative to the camera.
    pub is_static: bool,
    /// Parent in the kinematic tree, `None` for the root.
    pub parent: Option<usize>,
    /// Frames in which it has a pose.
    pub frames_registered: usize,
    /// Median over frames of the RMS distance between the fitted shape and the observed
    /// points, metres; about `1.2-1.6 sigma` for a rigid body, far more when the body mixes
    /// points of bodies that move apart.
    pub median_residual_m: Option<f64>,
    /// Reference shape: each point's position in the body frame, metres, in the order of
    /// `points` (null for a point that could not be placed). The body frame has its origin at
    /// the shape's centroid. Used by the observer.
    #[serde(default)]
    pub shape: Vec<Option<[f64; 3]>>,
    /// Median and 90th percentile of the dissimilarity between this body's points (observed
    /// pairs), on the measure's scale: under the F-test a rigid body has a median near 0.5.
    #[serde(default)]
    pub internal_dissimilarity: Option<[f64; 2]>,
}

/// A rigid transform as a unit quaternion `[x, y, z, w]` and a translation in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigidTransform {
    /// Rotation as a unit quaternion, `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
    /// Translation, metres.
    pub translation: [f64; 3],
}

impl RigidTransform {
    /// The transform of an isometry (the one place the model's transforms are made from
    /// nalgebra's).
    pub fn from_isometry(x: &Isometry3<f64>) -> Self {
        let (r, t) = (x.rotation, x.translation.vector);
        Self {
            rotation_xyzw: [r.i, r.j, r.k, r.w],
            translation: [t.x, t.y, t.z],
        }
    }

    /// The isometry (the quaternion normalised); `None` when the rotation is not a usable
    /// quaternion (a norm that is zero or not finite).
    pub fn to_isometry(&self) -> Option<Isometry3<f64>> {
        let [x, y, z, w] = self.rotation_xyzw;
        let q = Quaternion::new(w, x, y, z);
        let t = self.translation;
        (q.norm().is_finite() && q.norm() > 1e-9 && t.iter().all(|v| v.is_finite())).then(|| {
            Isometry3::from_parts(
                Translation3::new(t[0], t[1], t[2]),
                UnitQuaternion::from_quaternion(q),
            )
        })
    }
}

/// Joint ranks, as decided by the DoF tester.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ranks {
    /// Rank of the relative translations.
    pub translation: usize,
    /// Rank of the relative axis-angle rotations.
    pub rotation: usize,
    /// Rank of the centre-of-rotation estimates.
    pub centre: usize,
    /// Rank of the translation along the rotation axis.
    pub sliding: usize,
}

/// A joint's type, written in the model as `rigid`, `revolute`, `prismatic`, `spherical`,
/// `universal` or `multi_dof`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JointType {
    /// No relative motion.
    Rigid,
    /// One rotation about a fixed axis through a fixed pivot.
    Revolute,
    /// One translation along a fixed axis.
    Prismatic,
    /// Three rotations about a centre fixed in both bodies (a ball joint).
    Spherical,
    /// Two rotations about intersecting axes, one fixed in the parent and one in the child
    /// (a universal or Cardan joint).
    Universal,
    /// More than one degree of freedom that no other type explains (the ranks tell more).
    MultiDof,
}

impl JointType {
    /// The name the model writes.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Rigid => "rigid",
            Self::Revolute => "revolute",
            Self::Prismatic => "prismatic",
            Self::Spherical => "spherical",
            Self::Universal => "universal",
            Self::MultiDof => "multi_dof",
        }
    }

    /// Whether the joint has exactly one degree of freedom.
    pub fn is_single_dof(self) -> bool {
        matches!(self, Self::Revolute | Self::Prismatic)
    }

    /// Number of coordinates in a frame's configuration: 0 (rigid, and multi-DoF joints,
    /// which have no parametrisation), 1 (revolute, prismatic), 2 (universal, its two
    /// angles) or 3 (spherical, the rotation vector).
    pub fn n_coordinates(self) -> usize {
        match self {
            Self::Rigid | Self::MultiDof => 0,
            Self::Revolute | Self::Prismatic => 1,
            Self::Universal => 2,
            Self::Spherical => 3,
        }
    }
}

impl std::fmt::Display for JointType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How the whole-tree fit treats a joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JointFit {
    /// In the fit, as typed by its pair test.
    #[default]
    Followed,
    /// Not in the fit: its child is posed freely, and its positions come from the two
    /// bodies' fitted poses (the fit could not follow it).
    Freed,
    /// In the fit, with the type the fit gave it (its pair test typed it otherwise).
    TypedByFit,
}

/// One joint of the kinematic tree.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Joint {
    /// Parent body id.
    pub parent: usize,
    /// Child body id.
    pub child: usize,
    /// `rigid`, `revolute`, `prismatic`, `spherical`, `universal` or `multi_dof` (with the
    /// ranks telling more).
    #[serde(rename = "type")]
    pub joint_type: JointType,
    /// Unit axis in the camera frame at `reference_frame` (a universal joint's first axis,
    /// fixed in the parent; null for `spherical` and `multi_dof`).
    pub axis: Option<[f64; 3]>,
    /// A point on the axis (revolute), or the centre (spherical, universal), in the camera
    /// frame at `reference_frame`, metres.
    pub point: Option<[f64; 3]>,
    /// The same axis in the parent's body frame.
    pub axis_in_parent: Option<[f64; 3]>,
    /// The same point in the parent's body frame.
    pub point_in_parent: Option<[f64; 3]>,
    /// A universal joint's second axis, fixed in the child, in the camera frame at
    /// `reference_frame` (absent for other joints).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_axis: Option<[f64; 3]>,
    /// The same in the parent's body frame at joint position zero (`reference_pose`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_axis_in_parent: Option<[f64; 3]>,
    /// Frame at which the joint position is zero.
    pub reference_frame: usize,
    /// The child's body frame in the parent's body frame at joint position zero, estimated from
    /// every frame (each frame's relative pose carried back to zero through its position);
    /// joint positions are measured from it (used by the observer). For a multi-DoF joint, the
    /// relative pose at `reference_frame`.
    #[serde(default)]
    pub reference_pose: Option<RigidTransform>,
    /// Joint position at every frame, from a kinematic fit of the whole tree to the frame's
    /// visible keypoints: radians (revolute, unwrapped) or metres (prismatic), zero at
    /// `reference_frame`; null where the frame does not determine it (no visible point below
    /// the joint, or a standard deviation above 0.5 rad or 0.1 m).
    pub positions: Vec<Option<f64>>,
    /// Standard deviation of each position from the whole-tree fit at the model's noise
    /// level (same units as `positions`); null where the position is null or does not come
    /// from that fit (a joint the fit does not follow, measured from two fitted poses, or a
    /// multi-DoF joint). Weights for anyone averaging or smoothing the positions.
    #[serde(default)]
    pub position_std: Vec<Option<f64>>,
    /// The positions smoothed over time (`kinetree_fit::smooth_positions`: a
    /// constant-velocity Kalman smoother weighting each position by `position_std`, its
    /// process noise chosen by maximum likelihood), from the first to the last frame with a
    /// position and a standard deviation, gaps bridged; null outside, where the smoothed
    /// standard deviation exceeds 0.5 rad or 0.1 m, and for a joint with fewer than three
    /// such frames. A prior on the motion, not a per-frame estimate.
    #[serde(default)]
    pub smoothed_positions: Vec<Option<f64>>,
    /// Standard deviation of each smoothed position.
    #[serde(default)]
    pub smoothed_std: Vec<Option<f64>>,
    /// The coordinates of a joint with more than one ([`JointType::n_coordinates`]), per
    /// frame; empty for other joints, whose coordinate is in `positions`. A spherical joint's
    /// are its rotation vector: the child's rotation about the centre from `reference_pose`,
    /// in the parent's body frame, radians, zero at `reference_frame`. A universal joint's
    /// are its two angles, radians, zero at `reference_frame`: the child turns from
    /// `reference_pose` about `second_axis_in_parent` by the second, then about
    /// `axis_in_parent` by the first, both through `point_in_parent`. Null where the frame
    /// does not determine them, as for `positions`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub coordinates: Vec<Option<Vec<f64>>>,
    /// Standard deviation of each coordinate from the whole-tree fit (for a spherical joint,
    /// of the rotation about each of the parent's axes), as `position_std`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub coordinate_std: Vec<Option<Vec<f64>>>,
    /// The coordinates smoothed over time, each on its own as `smoothed_positions`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub smoothed_coordinates: Vec<Option<Vec<f64>>>,
    /// Standard deviation of each smoothed coordinate.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub smoothed_coordinate_std: Vec<Option<Vec<f64>>>,
    /// Observed range `[min, max]` of the positions (for a spherical or universal joint, of
    /// its rotation angle from the reference pose).
    pub range: Option<[f64; 2]>,
    /// Standard deviation of the axis direction (the RMS angle between the estimated and the
    /// true axis), degrees: the Cramér-Rao bound from the whole-tree fit of every frame at the
    /// model's noise level, with every frame's configuration and the other joints' parameters
    /// as nuisances and the reference shapes taken as exact; a universal joint's first axis.
    /// Null for joints the fit does not follow, for ball and multi-DoF joints, and in files
    /// written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis_std_deg: Option<f64>,
    /// The same bound for a revolute axis line's position across the axis (RMS distance),
    /// metres; null otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pivot_std_m: Option<f64>,
    /// The same bound for a ball or universal joint's centre in the parent's frame (RMS
    /// distance), metres; null otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub centre_std_m: Option<f64>,
    /// The same bound for a universal joint's second axis in the child's frame (RMS angle),
    /// degrees; null otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_axis_std_deg: Option<f64>,
    /// Estimated relative DoF.
    pub dof: usize,
    /// Rank decisions behind the type.
    pub ranks: Ranks,
    /// Largest rejected-singular-value / threshold ratio (below 1: decision holds).
    pub fit_ratio: f64,
    /// How the whole-tree fit treats the joint (absent in files of schema 1, whose
    /// `joint_not_followed` warnings name the freed joints).
    #[serde(default)]
    pub fit: JointFit,
}

/// How the root body moves against the camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RootJoint {
    /// The root is the static body: no coordinates.
    Fixed,
    /// Nothing is static and the root moves freely: six coordinates, its position and
    /// rotation vector in the camera frame (`kinetree_fit::Observation`'s `root_<b>_x` to
    /// `root_<b>_rz`), first in the configuration vector.
    Free,
}

impl RootJoint {
    /// The root joint of a model with this static body: fixed to it, or free without one.
    pub fn of(static_body: Option<usize>) -> Self {
        if static_body.is_some() {
            Self::Fixed
        } else {
            Self::Free
        }
    }
}

/// The whole discovered model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Model {
    /// Schema version, [`SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Program and version that wrote the file.
    pub generator: String,
    /// Number of frames of the input.
    pub n_frames: usize,
    /// Number of points of the input.
    pub n_points: usize,
    /// Point labels, when the input had them.
    pub point_labels: Option<Vec<String>>,
    /// Noise level used.
    pub noise: NoiseInfo,
    /// When a joint position is reported unknown, and when positions are smoothed.
    #[serde(default)]
    pub position_limits: PositionLimits,
    /// Stage names.
    pub stages: StageNames,
    /// Body of every point, -1 for discarded points.
    pub point_body: Vec<i64>,
    /// Points that belong to a second body as well, as `[point, body]`, ascending: a marker
    /// on a joint's axis, rigid with both bodies it joins, which both bodies' `points` list
    /// and both poses use. `point_body` names its first body. Empty in files written before
    /// it existed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub shared_points: Vec<[usize; 2]>,
    /// How clearly each point belongs to its body: the mean dissimilarity to the nearest other
    /// body minus that to its own (observed pairs, the measure's scale); null for discarded
    /// points. Near zero or negative: the point could belong elsewhere.
    #[serde(default)]
    pub point_confidence: Vec<Option<f64>>,
    /// The static body, when one is.
    pub static_body: Option<usize>,
    /// Root of the kinematic tree (body 0).
    pub root_body: usize,
    /// The root's joint to the camera: `fixed` to the static body, or `free` when nothing is
    /// static; absent in files before schema 5, where [`RootJoint::of`] the static body
    /// gives it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub root_joint: Option<RootJoint>,
    /// Bodies, by id.
    pub bodies: Vec<Body>,
    /// Joints, one per non-root body, in body order of the child.
    pub joints: Vec<Joint>,
    /// The kinematic chain from the paper's procedure, when the structure is a chain.
    pub chain: Option<Vec<usize>>,
    /// Every pair's test (the cells of the paper's Table I): camera against each body, then
    /// each body pair `a < b`; singular values in metres and radians.
    pub pairs: Vec<PairDof>,
    /// RMS distance between observed keypoints and their positions predicted by the model
    /// fitted to each frame (the root's pose and every joint position; see
    /// `kinetree_fit::Observer::fit`), in units of `noise.sigma_m`: 1.2-1.6 from
    /// per-body poses alone, a little more from the model (1.6 on the paper arm, with axis
    /// errors of 0.3 and 0.7 deg over sweeps of 3-6 rad), far more with a wrong joint.
    #[serde(default)]
    pub reprediction_rms_in_sigma: Option<f64>,
    /// Degenerate situations met on the way.
    pub warnings: Vec<Warning>,
    /// Every change the repairs made, in order ([`crate::TraceEntry`]).
    #[serde(default)]
    pub trace: Vec<crate::TraceEntry>,
    /// The companion `.npy` file, beside the model file, with every body's fitted pose in
    /// every frame (`kinetree_fit::Observation::pose_table`); `None` when none was written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body_poses_file: Option<String>,
}

impl Model {
    /// The test between `a` (camera when `None`) and `b`, in either order for bodies.
    pub fn pair(&self, a: Option<usize>, b: usize) -> Option<&PairDof> {
        self.pairs
            .iter()
            .find(|p| (p.a == a && p.b == b) || (a.is_some() && p.a == Some(b) && Some(p.b) == a))
    }

    /// The root's joint to the camera, as written or as the static body implies.
    pub fn root_joint(&self) -> RootJoint {
        self.root_joint
            .unwrap_or_else(|| RootJoint::of(self.static_body))
    }

    /// The joint whose child is `child`.
    pub fn joint_to(&self, child: usize) -> Option<&Joint> {
        self.joints.iter().find(|j| j.child == child)
    }

    /// Whether body `body` is a link put in between two hinges (an `unseen_link` warning
    /// names it).
    pub fn is_unseen_link(&self, body: usize) -> bool {
        self.warnings
            .iter()
            .any(|w| matches!(w, Warning::UnseenLink { body: b, .. } if *b == body))
    }
}
