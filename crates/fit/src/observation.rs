//! Joint positions of new frames from a discovered model, with each frame's fit: what
//! `kinetree observe` writes and the Python package's `observe` returns.

use crate::solver::Scratch;
use crate::{Observer, smooth_fitted_positions};
use kinetree_core::nalgebra::Isometry3;
use kinetree_core::{Error, Model, Result, Tracks};

/// A model's re-prediction RMS in sigma when the file does not say (the paper arm's, from
/// per-body poses and joints: see `Model::reprediction_rms_in_sigma`).
pub const TYPICAL_REPREDICTION_IN_SIGMA: f64 = 1.6;

/// Default of [`ObserveOptions::unexplained_factor`].
pub const DEFAULT_UNEXPLAINED_FACTOR: f64 = 3.0;

/// How [`observe`] reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserveOptions {
    /// Give the positions smoothed over the frames (a constant-velocity Kalman smoother
    /// weighting each frame's position by its standard deviation, as the model's
    /// `smoothed_positions`) instead of each frame's own estimate.
    pub smooth: bool,
    /// A frame is not explained by the model when its residual exceeds this many times the
    /// model's own re-prediction RMS (at least 1).
    pub unexplained_factor: f64,
}

impl Default for ObserveOptions {
    fn default() -> Self {
        Self {
            smooth: false,
            unexplained_factor: DEFAULT_UNEXPLAINED_FACTOR,
        }
    }
}

/// The joint positions of every frame of some tracks, from a model.
#[derive(Debug, Clone)]
pub struct Observation {
    /// Each column's name. When the model's root is not static, its pose comes first:
    /// `root_<id>_x`, `_y`, `_z` (its origin in the camera frame, metres) and `_rx`, `_ry`,
    /// `_rz` (its rotation vector from the camera's axes, radians), each frame's fit, not
    /// smoothed and without a standard deviation. Then the joints in the model's order:
    /// `<type>_<parent>_<child>` for a joint of one coordinate (and for rigid and multi-DoF
    /// joints, whose column is empty), with `_rx`, `_ry`, `_rz` for a spherical joint's three
    /// (its rotation vector in the parent's frame from the reference pose, as the model's
    /// `coordinates`) and `_q1`, `_q2` for a universal joint's two angles. A row is then the
    /// mechanism's whole configuration.
    pub joint_names: Vec<String>,
    /// Each joint's first column, in the model's joint order.
    pub joint_columns: Vec<usize>,
    /// Per column, per frame: the position (radians, unwrapped over the frames, or metres);
    /// `None` where the frame does not determine it.
    pub positions: Vec<Vec<Option<f64>>>,
    /// Per column, per frame: the standard deviation of the position.
    pub std: Vec<Vec<Option<f64>>>,
    /// Per frame: the RMS distance of its keypoints from the fitted model in units of the
    /// model's noise; `None` for a frame with no visible placed keypoint.
    pub residual_in_sigma: Vec<Option<f64>>,
    /// Per frame, per body: `camera_from_body` of the fitted configuration (the body frame
    /// of the model's `shape`: origin at the body's centroid, the camera's axes at the body's
    /// reference frame).
    pub poses: Vec<Vec<Option<Isometry3<f64>>>>,
    /// Per frame, per body: the standard deviation of that pose at the model's noise level,
    /// `[rotation (radians), origin (metres)]`, each in its worst direction, from the whole
    /// fit's normal equations; `None` where the pose is, or the frame's equations are
    /// singular.
    pub pose_std: Vec<Vec<Option<[f64; 2]>>>,
    /// The residual above which a frame is not explained by the model, in sigma.
    pub unexplained_bound: f64,
    /// The model's own re-prediction RMS in sigma the bound is a multiple of.
    pub own_rms_in_sigma: f64,
    /// The frames whose residual exceeds the bound: their positions are not to be trusted.
    pub unexplained: Vec<usize>,
}

/// Fits `model` to every frame of `tracks`, each frame starting from the frames before it
/// (so revolute positions come out unwrapped).
///
/// # Errors
/// [`Error::Shape`] when the tracks do not have the model's points,
/// [`Error::InvalidParameter`] for an `unexplained_factor` below 1 or not finite, and the
/// observer's errors for a model it cannot fit.
pub fn observe(model: &Model, tracks: &Tracks, options: ObserveOptions) -> Result<Observation> {
    let factor = options.unexplained_factor;
    if !(factor.is_finite() && factor >= 1.0) {
        return Err(Error::InvalidParameter {
            name: "unexplained_factor".into(),
            message: format!("must be a finite number of at least 1, got {factor}"),
        });
    }
    if tracks.n_points() != model.n_points {
        return Err(Error::Shape {
            expected: format!("tracks of the model's {} points", model.n_points),
            found: format!("{} points", tracks.n_points()),
        });
    }
    let observer = Observer::new(model)?;
    let sigma = model.noise.sigma_m;
    let mut scratch = Scratch::default();
    let mut pose_std = Vec::with_capacity(tracks.n_frames());
    let fits = observer.fit_sequence_with(tracks, |descent, visible| {
        let qualities = observer.pose_qualities(&descent, &visible, &mut scratch);
        pose_std.push(
            qualities
                .iter()
                .map(|q| q.map(|q| [q.rot_std_per_sigma * sigma, q.trans_std_per_sigma * sigma]))
                .collect(),
        );
    })?;
    let mut joint_names = Vec::new();
    let mut positions: Vec<Vec<Option<f64>>> = Vec::new();
    let mut std: Vec<Vec<Option<f64>>> = Vec::new();
    let mut angular = Vec::new();
    // The root's pose when nothing static anchors it: part of the configuration.
    let free_root = model.static_body.is_none() && model.root_body < model.bodies.len();
    if free_root {
        let root = model.root_body;
        for (i, axis) in ["x", "y", "z", "rx", "ry", "rz"].iter().enumerate() {
            joint_names.push(format!("root_{root}_{axis}"));
            positions.push(
                fits.iter()
                    .map(|f| {
                        f.poses[root].map(|p| {
                            if i < 3 {
                                p.translation.vector[i]
                            } else {
                                p.rotation.scaled_axis()[i - 3]
                            }
                        })
                    })
                    .collect(),
            );
            std.push(vec![None; fits.len()]);
            angular.push(i >= 3);
        }
    }
    let first_joint_column = joint_names.len();
    let mut joint_columns = Vec::with_capacity(model.joints.len());
    for (k, j) in model.joints.iter().enumerate() {
        joint_columns.push(joint_names.len());
        let name = format!("{}_{}_{}", j.joint_type, j.parent, j.child);
        if observer.is_universal(k) {
            for (i, axis) in ["q1", "q2"].iter().enumerate() {
                joint_names.push(format!("{name}_{axis}"));
                positions.push(fits.iter().map(|f| f.angles[k].map(|v| v[i])).collect());
                std.push(fits.iter().map(|f| f.angle_std[k].map(|s| s[i])).collect());
                angular.push(true);
            }
        } else if observer.is_spherical(k) {
            for (i, axis) in ["rx", "ry", "rz"].iter().enumerate() {
                joint_names.push(format!("{name}_{axis}"));
                positions.push(fits.iter().map(|f| f.rotations[k].map(|v| v[i])).collect());
                std.push(
                    fits.iter()
                        .map(|f| f.rotation_std[k].map(|s| s[i]))
                        .collect(),
                );
                angular.push(true);
            }
        } else {
            joint_names.push(name);
            positions.push(fits.iter().map(|f| f.positions[k]).collect());
            std.push(fits.iter().map(|f| f.std[k]).collect());
            angular.push(observer.is_revolute(k));
        }
    }
    if options.smooth {
        for c in first_joint_column..positions.len() {
            (positions[c], std[c]) = smooth_fitted_positions(
                &positions[c],
                &std[c],
                angular[c],
                &model.position_limits,
            )?;
        }
    }
    let residual_in_sigma: Vec<Option<f64>> = fits
        .iter()
        .map(|f| {
            (f.n_points > 0).then(|| (f.sum_sq_m2 / f.n_points as f64).sqrt() / model.noise.sigma_m)
        })
        .collect();
    let own = model
        .reprediction_rms_in_sigma
        .unwrap_or(TYPICAL_REPREDICTION_IN_SIGMA);
    let bound = factor * own;
    let unexplained = (0..residual_in_sigma.len())
        .filter(|&t| residual_in_sigma[t].is_some_and(|r| r.is_nan() || r > bound))
        .collect();
    Ok(Observation {
        joint_names,
        joint_columns,
        positions,
        std,
        residual_in_sigma,
        poses: fits.into_iter().map(|f| f.poses).collect(),
        pose_std,
        unexplained_bound: bound,
        own_rms_in_sigma: own,
        unexplained,
    })
}

/// The columns of [`Observation::pose_table`], per frame and body.
pub const POSE_COLUMNS: [&str; 9] = [
    "qx",
    "qy",
    "qz",
    "qw",
    "x",
    "y",
    "z",
    "rotation_std_rad",
    "origin_std_m",
];

impl Observation {
    /// Every body's pose in every frame as one `(T, B, 9)` array in C order, with the columns
    /// [`POSE_COLUMNS`]: `camera_from_body` as a unit quaternion (`x, y, z, w`) and the body
    /// origin in the camera frame (metres), then the pose's two standard deviations
    /// ([`Observation::pose_std`]); NaN where unknown. Returns the array and its shape.
    pub fn pose_table(&self) -> (Vec<f64>, [usize; 3]) {
        let n_bodies = self.poses.first().map_or(0, Vec::len);
        let mut out = Vec::with_capacity(self.poses.len() * n_bodies * POSE_COLUMNS.len());
        for (frame, std) in self.poses.iter().zip(&self.pose_std) {
            for (pose, sd) in frame.iter().zip(std) {
                match pose {
                    Some(p) => {
                        let q = p.rotation.coords;
                        let t = p.translation.vector;
                        out.extend([q.x, q.y, q.z, q.w, t.x, t.y, t.z]);
                    }
                    None => out.extend([f64::NAN; 7]),
                }
                out.extend(sd.filter(|_| pose.is_some()).unwrap_or([f64::NAN; 2]));
            }
        }
        (out, [self.poses.len(), n_bodies, POSE_COLUMNS.len()])
    }
}
