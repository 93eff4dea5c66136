//! The paper's SVD rank tests, with thresholds from the noise propagated through each pose.

use crate::rank::{principal_direction, rank_test};
use kinetree_core::geom::{angle_about, canonical_sign, log_so3, relative_poses};
use kinetree_core::nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use kinetree_core::{BodyPoses, DofInput, DofTester, Error, JointKind, PairDof, RankTest, Result};
use serde::{Deserialize, Serialize};

/// Parameters of [`SvdRank`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SvdRankParams {
    /// A direction counts when its RMS amplitude exceeds this many noise std-devs
    /// (see [`crate::rank_test`]).
    pub kappa: f64,
    /// Frames whose relative rotation is below this angle (radians) are skipped for the centre
    /// of rotation, where `(R - I)` is ill-conditioned.
    pub min_centre_angle_rad: f64,
    /// ... and so are frames whose rotation is below this many rotation-noise std-devs.
    pub min_centre_angle_in_std: f64,
}

impl Default for SvdRankParams {
    fn default() -> Self {
        Self {
            kappa: 3.0,
            min_centre_angle_rad: 0.05,
            min_centre_angle_in_std: 5.0,
        }
    }
}

impl SvdRankParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a non-positive or non-finite value.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("kappa", self.kappa),
            ("min_centre_angle_rad", self.min_centre_angle_rad),
            ("min_centre_angle_in_std", self.min_centre_angle_in_std),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::InvalidParameter {
                    name: name.into(),
                    message: format!("must be finite and positive, got {v}"),
                });
            }
        }
        Ok(())
    }
}

/// Relative-motion DoF test by SVD ranks (the paper's Sec. III-B), with noise-derived
/// thresholds.
///
/// For body `b` relative to frame `a` (camera or body) over the frames where both have a
/// pose, with `X_k = a_from_b(k)` and the reference frame `r` (the common frame with the most
/// precise poses):
/// - translation columns `u_k = y_k - y_r`, the displacement of `b`'s origin (its centroid) in
///   `a`'s body frame; rank 0 rigid, 1 prismatic, 2 for a circle;
/// - rotation columns `log(R_k R_r^T)`, axis-angle via quaternions; rank 1 for a fixed axis;
/// - centre columns `(R_k R_r^T - I)^+ u_k` over frames with enough rotation; rank 0 when the
///   centre of rotation is fixed (since `u_k = (R - I)(y_r - c)`);
/// - sliding: the translation along the rotation axis (rank 1 for screw or cylindrical motion).
///
/// Each column is divided by its predicted noise std-dev, from the per-frame pose precision
/// ([`kinetree_core::PoseQuality`]) times `noise_sigma_m`; see [`crate::rank_test`].
///
/// Complexity: O(T) per pair.
#[derive(Debug, Clone)]
pub struct SvdRank {
    params: SvdRankParams,
}

impl SvdRank {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SvdRankParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

/// Per-frame (rotation, translation-of-origin) std-dev per unit noise of frame `a`.
fn precision(poses: &BodyPoses, a: Option<usize>, t: usize) -> (f64, f64) {
    match a {
        None => (0.0, 0.0),
        Some(b) => poses.bodies[b].quality[t].map_or((f64::INFINITY, f64::INFINITY), |q| {
            (q.rot_std_per_sigma, q.trans_std_per_sigma)
        }),
    }
}

impl DofTester for SvdRank {
    fn name(&self) -> &str {
        "svd_rank"
    }

    fn test_pair(&self, input: &DofInput<'_>, a: Option<usize>, b: usize) -> Result<PairDof> {
        let poses = input.poses;
        let n_bodies = poses.bodies.len();
        if b >= n_bodies || a.is_some_and(|a| a >= n_bodies || a == b) {
            return Err(Error::InvalidParameter {
                name: "pair".into(),
                message: format!("no pair ({a:?}, {b}) among {n_bodies} bodies"),
            });
        }
        let sigma = input.noise_sigma_m;
        if !(sigma.is_finite() && sigma > 0.0) {
            return Err(Error::InvalidParameter {
                name: "noise_sigma_m".into(),
                message: format!("must be finite and positive, got {sigma}"),
            });
        }
        let x = relative_poses(poses, a, b);
        let frames: Vec<usize> = (0..poses.n_frames).filter(|&t| x[t].is_some()).collect();
        if frames.len() < 2 {
            return Err(Error::Degenerate(format!(
                "frames {a:?} and body {b} have poses together in {} frame(s); two are needed",
                frames.len()
            )));
        }
        // Per-frame rotation and origin std-devs (metres of noise -> radians, metres).
        let prec: Vec<((f64, f64), (f64, f64))> = frames
            .iter()
            .map(|&t| (precision(poses, a, t), precision(poses, Some(b), t)))
            .collect();
        let rot_std: Vec<f64> = prec
            .iter()
            .map(|((ra, _), (rb, _))| sigma * (ra * ra + rb * rb).sqrt())
            .collect();
        let r = (0..frames.len())
            .min_by(|&i, &j| rot_std[i].total_cmp(&rot_std[j]))
            .unwrap_or(0);
        let reference_frame = frames[r];
        let x_ref =
            x[reference_frame].ok_or_else(|| Error::Numerical("lost reference pose".into()))?;
        let y_ref = x_ref.translation.vector;
        let mut u = Vec::with_capacity(frames.len());
        let mut u_std = Vec::with_capacity(frames.len());
        let mut rot = Vec::with_capacity(frames.len());
        let mut q_rel = Vec::with_capacity(frames.len());
        for (i, &t) in frames.iter().enumerate() {
            let Some(xk) = x[t] else { continue };
            let y = xk.translation.vector;
            let ((ra, ta), (_, tb)) = prec[i];
            u.push(y - y_ref);
            u_std.push(
                sigma
                    * (ta * ta + tb * tb + (ra * y.norm()).powi(2))
                        .sqrt()
                        .max(1e-12),
            );
            let q: UnitQuaternion<f64> = xk.rotation * x_ref.rotation.inverse();
            rot.push(log_so3(&q.to_rotation_matrix()));
            q_rel.push(q);
        }
        let rot_std: Vec<f64> = rot_std.iter().map(|s| s.max(1e-12)).collect();
        let kappa = self.params.kappa;
        let translation = rank_test(&u, &u_std, 3, kappa);
        let rotation = rank_test(&rot, &rot_std, 3, kappa);
        let mut centre = RankTest::empty();
        let mut sliding = RankTest::empty();
        let mut joint = JointKind::MultiDof;
        let dof;
        let fit_ratio;
        match rotation.rank {
            0 => {
                dof = translation.rank;
                fit_ratio = rotation
                    .next_rank_ratio()
                    .max(translation.next_rank_ratio());
                if translation.rank == 0 {
                    joint = JointKind::Rigid;
                } else if translation.rank == 1 {
                    let axis = principal_direction(&u, &u_std)
                        .ok_or_else(|| Error::Numerical("prismatic axis".into()))?;
                    joint = JointKind::Prismatic {
                        axis: canonical_sign(axis),
                    };
                }
            }
            1 => {
                let axis = canonical_sign(
                    principal_direction(&rot, &rot_std)
                        .ok_or_else(|| Error::Numerical("rotation axis".into()))?,
                );
                let mut w = Vec::new();
                let mut w_std = Vec::new();
                let mut a_mat = Matrix3::zeros();
                let mut b_vec = Vector3::zeros();
                for k in 0..u.len() {
                    let theta = angle_about(&q_rel[k], &axis);
                    let m = q_rel[k].to_rotation_matrix().into_inner() - Matrix3::identity();
                    let wk = 1.0 / (u_std[k] * u_std[k]);
                    a_mat += m.transpose() * m * wk;
                    b_vec += m.transpose() * u[k] * wk;
                    let min_angle = self
                        .params
                        .min_centre_angle_rad
                        .max(self.params.min_centre_angle_in_std * rot_std[k]);
                    if theta.abs() < min_angle {
                        continue;
                    }
                    let gain = 2.0 * (theta.abs() / 2.0).sin();
                    if let Ok(pinv) = m.pseudo_inverse(0.5 * gain) {
                        w.push(pinv * u[k]);
                        w_std.push(u_std[k] / gain);
                    }
                }
                centre = rank_test(&w, &w_std, 3, kappa);
                let z: Vec<Vector3<f64>> = u
                    .iter()
                    .map(|uk| Vector3::new(axis.dot(uk), 0.0, 0.0))
                    .collect();
                sliding = rank_test(&z, &u_std, 1, kappa);
                dof = (1 + centre.rank + sliding.rank).min(6);
                fit_ratio = rotation
                    .next_rank_ratio()
                    .max(centre.next_rank_ratio())
                    .max(sliding.next_rank_ratio());
                if centre.rank == 0 && sliding.rank == 0 {
                    // Least-squares centre: u_k = (R_k - I)(y_ref - c), regularised along the
                    // axis so the pivot is the point of the axis level with b's origin.
                    let scale = a_mat.trace().max(1e-300);
                    let reg = a_mat + axis * axis.transpose() * scale;
                    let v = reg
                        .try_inverse()
                        .map(|inv| inv * b_vec)
                        .unwrap_or_else(Vector3::zeros);
                    let pivot = Point3::from(y_ref - v);
                    joint = JointKind::Revolute { axis, pivot };
                }
            }
            _ => {
                dof = (rotation.rank + translation.rank).min(6);
                fit_ratio = rotation.next_rank_ratio();
            }
        }
        Ok(PairDof {
            a,
            b,
            reference_frame,
            translation,
            rotation,
            centre,
            sliding,
            dof,
            joint,
            fit_ratio,
        })
    }
}
