//! Body poses over time and the per-pair relative-motion tests.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// How well one body was registered in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseQuality {
    /// Visible points used for the fit.
    pub n_visible: usize,
    /// RMS distance between the fitted reference shape and the observations, metres.
    pub rms_residual_m: f64,
    /// Standard deviation of the rotation (worst axis, radians) per metre of per-coordinate
    /// noise: multiply by `sigma` to get radians. From the inertia of the visible points.
    pub rot_std_per_sigma: f64,
    /// Standard deviation of the body origin's position (per coordinate) per unit of
    /// per-coordinate noise, dimensionless.
    pub trans_std_per_sigma: f64,
    /// Covariance of the rotation error (a body-frame rotation vector) per unit noise
    /// variance: `J^-1`, with `J = sum (|q|^2 I - q q^T)` over the visible points centred on
    /// their centroid. Multiply by `sigma^2` to get rad^2.
    pub rot_cov_per_sigma2: Matrix3<f64>,
    /// Covariance of the body origin's position error (body frame) per unit noise variance:
    /// `I / n + [c]x J^-1 [c]x^T`, with `c` the visible points' centroid.
    pub origin_cov_per_sigma2: Matrix3<f64>,
}

impl PoseQuality {
    /// From the fit's visible points, their RMS residual (metres) and the covariances of the
    /// rotation and origin errors (body frame, per unit noise variance); the worst-direction
    /// standard deviations are the square roots of their largest eigenvalues.
    pub fn from_covariances(
        n_visible: usize,
        rms_residual_m: f64,
        rot_cov_per_sigma2: Matrix3<f64>,
        origin_cov_per_sigma2: Matrix3<f64>,
    ) -> Self {
        let worst = |m: &Matrix3<f64>| crate::geom::symmetric_eigenvalues_3x3(m)[0].max(0.0).sqrt();
        Self {
            n_visible,
            rms_residual_m,
            rot_std_per_sigma: worst(&rot_cov_per_sigma2),
            trans_std_per_sigma: worst(&origin_cov_per_sigma2),
            rot_cov_per_sigma2,
            origin_cov_per_sigma2,
        }
    }
}

/// One body's reference shape and its pose in every frame.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyTrack {
    /// The body's points (indices into the tracks), ascending.
    pub points: Vec<usize>,
    /// Reference shape in the body frame, one entry per point of `points`. The body frame has
    /// its origin at the shape's centroid and the camera's orientation at `reference_frame`.
    pub shape: Vec<Point3<f64>>,
    /// Whether each point of `points` could be placed in the shape (a point never seen with
    /// three placed points of its body is not; its `shape` entry is then meaningless).
    pub placed: Vec<bool>,
    /// Frame at which the body frame is aligned with the camera axes (frame 0 where the body
    /// can be registered there, else the first frame where it can).
    pub reference_frame: usize,
    /// `camera_from_body` per frame, `None` where the body cannot be registered.
    pub cam_from_body: Vec<Option<Isometry3<f64>>>,
    /// Fit quality per frame, `None` where no pose.
    pub quality: Vec<Option<PoseQuality>>,
    /// Frames skipped because fewer than three points were visible.
    pub frames_too_few_points: usize,
    /// Frames skipped because the visible points were (nearly) collinear.
    pub frames_degenerate: usize,
}

impl BodyTrack {
    /// Number of frames with a pose.
    pub fn n_registered(&self) -> usize {
        self.cam_from_body.iter().filter(|p| p.is_some()).count()
    }

    /// Median over registered frames of the fit's RMS residual, metres.
    pub fn median_residual_m(&self) -> Option<f64> {
        self.median_quality(|q| q.rms_residual_m)
    }

    /// Median over registered frames of `value` of the fit's quality (the upper middle one
    /// for an even count); `None` without a registered frame.
    pub fn median_quality(&self, value: impl Fn(&PoseQuality) -> f64) -> Option<f64> {
        let mut v: Vec<f64> = self.quality.iter().flatten().map(value).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    }
}

/// Poses of every body over every frame, produced by a [`PoseEstimator`](crate::PoseEstimator).
#[derive(Debug, Clone, PartialEq)]
pub struct BodyPoses {
    /// Number of frames `T`.
    pub n_frames: usize,
    /// One track per body, in segmentation order.
    pub bodies: Vec<BodyTrack>,
}

/// One rank decision on a 3 x K (or 2 x K, 1 x K) data matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RankTest {
    /// Singular values of the centred matrix in physical units (metres or radians),
    /// descending.
    pub singular_values: Vec<f64>,
    /// Singular values after each column was divided by its worst-direction noise std-dev.
    pub whitened: Vec<f64>,
    /// Threshold on the whitened singular values (the thresholded-SVD rule); `None` for the
    /// chi-square rule or when there was no data.
    pub threshold: Option<f64>,
    /// The decided rank.
    pub rank: usize,
    /// Number of columns (frames) used.
    pub n_columns: usize,
    /// Chi-square rule: weighted residual per degree of freedom of the best rank-`r` fit,
    /// for `r = 0, 1, ..`; empty for the thresholded-SVD rule.
    #[serde(default)]
    pub chi2_per_dof: Vec<f64>,
    /// Chi-square rule: the bound each `chi2_per_dof[r]` had to meet for rank `r`.
    #[serde(default)]
    pub chi2_bound: Vec<f64>,
}

impl RankTest {
    /// A test with no data (no usable frames): rank 0, no values.
    pub fn empty() -> Self {
        Self {
            singular_values: Vec::new(),
            whitened: Vec::new(),
            threshold: None,
            rank: 0,
            n_columns: 0,
            chi2_per_dof: Vec::new(),
            chi2_bound: Vec::new(),
        }
    }

    /// How close the decision came to the next rank: below 1 when the decision is clear,
    /// near 1 when it almost went the other way. Thresholded SVD: the largest rejected
    /// whitened singular value over the threshold. Chi-square: the accepted rank's misfit over
    /// its bound (0 when the full rank was needed).
    pub fn next_rank_ratio(&self) -> f64 {
        if !self.chi2_per_dof.is_empty() {
            return match (
                self.chi2_per_dof.get(self.rank),
                self.chi2_bound.get(self.rank),
            ) {
                (Some(s), Some(b)) if *b > 0.0 => s / b,
                _ => 0.0,
            };
        }
        match (self.whitened.get(self.rank), self.threshold) {
            (Some(s), Some(t)) if t > 0.0 => s / t,
            _ => 0.0,
        }
    }
}

/// The relative joint type found between two frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum JointKind {
    /// No relative motion.
    Rigid,
    /// One rotational DoF about a fixed axis. Both vectors in frame `a`'s body frame.
    Revolute {
        /// Unit axis direction.
        axis: Vector3<f64>,
        /// A point on the axis.
        pivot: Point3<f64>,
    },
    /// One translational DoF along a fixed axis (unit vector in frame `a`'s body frame).
    Prismatic {
        /// Unit axis direction.
        axis: Vector3<f64>,
    },
    /// Three rotational DoF about a centre fixed in both bodies (a ball joint).
    Spherical {
        /// The centre in frame `a`'s body frame.
        centre: Point3<f64>,
    },
    /// Two rotational DoF about intersecting axes (a universal or Cardan joint): `axis`
    /// fixed in `a`, `child_axis` fixed in `b`, at a fixed angle to each other, through a
    /// centre fixed in both.
    Universal {
        /// The first axis (unit), fixed in `a`, in `a`'s body frame.
        axis: Vector3<f64>,
        /// The second axis (unit), fixed in `b`, in `b`'s body frame.
        child_axis: Vector3<f64>,
        /// The axes' intersection in `a`'s body frame.
        centre: Point3<f64>,
    },
    /// More than one DoF (or a motion no single-DoF type explains); see the ranks.
    MultiDof,
}

impl JointKind {
    /// Whether this is a single-DoF joint (revolute or prismatic).
    pub fn is_single_dof(&self) -> bool {
        matches!(
            self,
            JointKind::Revolute { .. } | JointKind::Prismatic { .. }
        )
    }

    /// Short name: `rigid`, `revolute`, `prismatic`, `spherical`, `multi_dof`.
    pub fn name(&self) -> &'static str {
        self.joint_type().as_str()
    }

    /// The model's joint type of this kind.
    pub fn joint_type(&self) -> crate::model::JointType {
        use crate::model::JointType;
        match self {
            JointKind::Rigid => JointType::Rigid,
            JointKind::Revolute { .. } => JointType::Revolute,
            JointKind::Prismatic { .. } => JointType::Prismatic,
            JointKind::Spherical { .. } => JointType::Spherical,
            JointKind::Universal { .. } => JointType::Universal,
            JointKind::MultiDof => JointType::MultiDof,
        }
    }
}

/// Relative-motion test between frame `a` (the camera when `None`) and body `b`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairDof {
    /// Reference frame: `None` is the camera, `Some(k)` body `k`.
    pub a: Option<usize>,
    /// The moving body.
    pub b: usize,
    /// Frame at which the relative motion is taken as zero.
    pub reference_frame: usize,
    /// Translation of `b` in `a`'s body frame (the paper's script-T matrix).
    pub translation: RankTest,
    /// Axis-angle rotation of `b` relative to `a` (the paper's script-R matrix).
    pub rotation: RankTest,
    /// Centre-of-rotation estimates over frames with enough rotation.
    pub centre: RankTest,
    /// Translation along the rotation axis (a screw or cylindrical motion when rank 1).
    pub sliding: RankTest,
    /// The centre-of-rotation estimates themselves, not centred: the paper's C matrix. Each
    /// column is the centre relative to `b`'s origin at the reference frame, so a fixed
    /// centre gives rank 1 (its distance times the square root of the frames) and a moving
    /// one rank 2. Table I prints these; `centre` decides.
    #[serde(default = "RankTest::empty")]
    pub centre_uncentred: RankTest,
    /// For a pair that turns about more than one axis about a fixed centre: the two-axis test,
    /// rank 0 when an axis fixed in `a` and one fixed in `b`, at a fixed angle, explain its
    /// rotations (a universal joint); its `chi2_per_dof` and `chi2_bound` tell by how much
    /// (empty otherwise, and in files written before it existed).
    #[serde(default = "RankTest::empty")]
    pub axes: RankTest,
    /// Estimated number of relative degrees of freedom.
    pub dof: usize,
    /// The joint type the ranks support.
    pub joint: JointKind,
    /// Largest `rejected singular value / threshold` among the tests behind `joint`: below 1
    /// the decision holds; the smaller, the clearer.
    pub fit_ratio: f64,
    /// Median distance between the two bodies' origins (the centroids of their keypoints)
    /// over the frames tested, metres; `None` for a pair with the camera and in files
    /// written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distance_m: Option<f64>,
    /// RMS distance, metres, between the two ends of the best point fixed in both bodies
    /// (a ball joint's centre fitted to the relative poses by unweighted least squares, as
    /// SCoRE fits one) over the frames tested: a few skin-motion millimetres between
    /// neighbouring segments, a limb's swing between bodies a joint apart or more. `None` for
    /// a pair with the camera, under three frames, and in files written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ball_fit_rms_m: Option<f64>,
    /// How far that best point lies from the bodies: the larger of its distances, metres,
    /// from the two bodies' origins (their keypoints' centroids). A joint passes near both
    /// bodies it joins; a body rigid with one's neighbour fits a ball as well, but about a
    /// centre far from its own keypoints. `None` where `ball_fit_rms_m` is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ball_reach_m: Option<f64>,
}
