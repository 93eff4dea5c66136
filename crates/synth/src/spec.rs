//! Mechanism specifications for property tests: every random choice is a field, so a
//! failing case shrinks to a minimal mechanism.

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, Scenario, Trajectory};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// One joint and the body it carries.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointDraw {
    /// Which earlier body is the parent, as a fraction of the bodies so far (chains ignore it).
    pub parent_pick: f64,
    /// Revolute or prismatic.
    pub revolute: bool,
    /// Axis direction (normalised on use; a near-zero vector becomes z).
    pub axis: [f64; 3],
    /// Length of the carried body, metres (2-50 cm).
    pub size_m: f64,
    /// Keypoints on the carried body (4-12), placed in general position inside its box.
    pub n_points: usize,
    /// Motion amplitude as a fraction of the range (0-1): revolute 0.5-1.5 rad, prismatic
    /// 5-15 cm.
    pub amplitude: f64,
    /// Sine phase, radians.
    pub phase: f64,
}

/// A mechanism and how it is observed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MechanismSpec {
    /// Joints in order; joint `k` carries body `k + 1` (body 0 is the static base).
    pub joints: Vec<JointDraw>,
    /// Attach bodies by `parent_pick` (a tree) instead of to the previous body (a chain).
    pub tree: bool,
    /// Per-coordinate noise, metres (0-5 mm), clamped by the identifiability rule.
    pub noise_sigma_m: f64,
    /// Random burst occlusion (0-40 %).
    pub dropout: f64,
    /// Seed of the keypoint positions, the noise and the occlusion.
    pub seed: u64,
}

/// Frames of every specified scenario (30 Hz).
pub const SPEC_FRAMES: usize = 150;

impl MechanismSpec {
    /// The noise actually simulated: `noise_sigma_m`, but at most 1/20 of the smallest body
    /// (a 2 cm body with 5 mm noise has no measurable shape).
    pub fn effective_noise_sigma_m(&self) -> f64 {
        let smallest = self
            .joints
            .iter()
            .map(|j| j.size_m.clamp(0.02, 0.5))
            .fold(0.4, f64::min);
        self.noise_sigma_m.clamp(0.0, 0.005).min(smallest / 20.0)
    }

    /// The scenario.
    ///
    /// Identifiability rule, stated so tolerances can follow it: a prismatic joint whose parent
    /// joint is prismatic is at least 20 deg from parallel to it; every joint moves along its
    /// own sine, at least 0.5 rad (revolute) or 5 cm (prismatic) in amplitude, with a
    /// frequency distinct from every other joint's (0.15-0.45 Hz, so each sweeps at least two
    /// thirds of a period in 150 frames). The noise is at most 1/20 of the smallest body.
    /// Keypoints lie in general position inside their box, and occlusion comes only from
    /// random bursts (no self-occlusion), so every body keeps most of its points in most
    /// frames.
    pub fn scenario(&self) -> Scenario {
        let mut bodies = vec![BodySpec {
            name: "base".into(),
            shape: BoxShape {
                centre: [0.0, 0.0, -0.05],
                half_extents: [0.2, 0.2, 0.05],
            },
            skip_corners: Vec::new(),
            extra_points: 0,
            interior_points: 0,
            marked_points: Vec::new(),
        }];
        let mut tips = vec![[0.0, 0.0, 0.0]];
        let mut joints = Vec::new();
        let mut trajectories = Vec::new();
        let n = self.joints.len().max(1);
        for (k, d) in self.joints.iter().enumerate() {
            let parent = if self.tree {
                ((d.parent_pick.clamp(0.0, 0.999)) * (k + 1) as f64) as usize
            } else {
                k
            };
            let anchor = tips[parent];
            let size = d.size_m.clamp(0.02, 0.5);
            // Grow outwards and upwards, alternating directions so bodies do not stack.
            let dirs = [
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [-1.0, 0.0, 0.0],
                [0.0, -1.0, 0.0],
            ];
            let dir = dirs[k % dirs.len()];
            let half: [f64; 3] = std::array::from_fn(|i| {
                if dir[i] != 0.0 {
                    size / 2.0
                } else {
                    (size / 4.0).max(0.01)
                }
            });
            let centre: [f64; 3] =
                std::array::from_fn(|i| anchor[i] + dir[i] * (0.01 + size / 2.0));
            let tip: [f64; 3] = std::array::from_fn(|i| anchor[i] + dir[i] * (0.01 + size));
            bodies.push(BodySpec {
                name: format!("link{}", k + 1),
                shape: BoxShape {
                    centre,
                    half_extents: half,
                },
                skip_corners: (0..8).collect(),
                extra_points: 0,
                interior_points: d.n_points.clamp(4, 12),
                marked_points: Vec::new(),
            });
            tips.push(tip);
            let axis = Vector3::from(d.axis);
            let kf = k as f64;
            let mut axis = if axis.norm() < 1e-3 {
                // A distinct default per joint, so shrunk cases do not all share one axis.
                Vector3::new(kf.cos(), kf.sin(), 0.5).normalize()
            } else {
                axis.normalize()
            };
            // Two prismatic joints in series along (nearly) one direction are one DoF seen
            // twice: the grandchild also moves with one DoF relative to the grandparent.
            if !d.revolute && parent > 0 {
                let pj: &JointSpec = &joints[parent - 1];
                let pa = Vector3::from(pj.axis);
                if pj.joint_type == JointType::Prismatic
                    && axis.dot(&pa).abs() > 20f64.to_radians().cos()
                {
                    let side = if pa.x.abs() < 0.9 {
                        Vector3::x()
                    } else {
                        Vector3::y()
                    };
                    axis = pa.cross(&side).normalize();
                }
            }
            joints.push(JointSpec {
                parent,
                child: k + 1,
                joint_type: if d.revolute {
                    JointType::Revolute
                } else {
                    JointType::Prismatic
                },
                axis: [axis.x, axis.y, axis.z],
                anchor,
                second_axis: None,
            });
            let a = d.amplitude.clamp(0.0, 1.0);
            trajectories.push(Trajectory::Sine {
                offset: 0.0,
                amplitude: if d.revolute { 0.5 + a } else { 0.05 + 0.1 * a },
                frequency_hz: 0.15 + 0.3 * k as f64 / n as f64,
                phase_rad: d.phase,
            });
        }
        Scenario {
            mechanism: Mechanism { bodies, joints },
            trajectories,
            n_frames: SPEC_FRAMES,
            frame_rate_hz: 30.0,
            camera: Camera::looking_at([2.0, -2.2, 1.6], [0.0, 0.0, 0.3], 100.0, 90.0),
            noise_sigma_m: self.effective_noise_sigma_m(),
            dropout: self.dropout.clamp(0.0, 0.4),
            seed: self.seed,
            self_occlusion: false,
            partly_seen: Vec::new(),
            soft_tissue_m: 0.0,
        }
    }

    /// Number of keypoints per body, base first (the base has 8).
    pub fn points_per_body(&self) -> Vec<usize> {
        std::iter::once(8)
            .chain(self.joints.iter().map(|j| j.n_points.clamp(4, 12)))
            .collect()
    }
}
