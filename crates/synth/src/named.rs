//! Named and random scenarios.

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, Scenario, Trajectory, random_unit};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

fn body(name: &str, centre: [f64; 3], half_extents: [f64; 3]) -> BodySpec {
    BodySpec {
        name: name.into(),
        shape: BoxShape {
            centre,
            half_extents,
        },
        skip_corners: Vec::new(),
        extra_points: 0,
        interior_points: 0,
        marked_points: Vec::new(),
    }
}

/// The paper's experiment (Sec. IV): a static base and two box links joined by two parallel
/// revolute joints, 23 keypoints at box corners (the base corner that always faces away from
/// the camera has none), constant joint torques over `T = 100` steps at 30 Hz so each angle
/// grows quadratically (link 1 about one full turn, link 2 about half a turn relative to
/// link 1), 1 mm noise, and a camera placed so that link 2 passes in front of link 1, and the
/// links in front of the base, part of the time.
pub fn paper_arm(seed: u64) -> Scenario {
    let mut base = body("base", [0.0, 0.0, 0.05], [0.15, 0.15, 0.05]);
    base.skip_corners = vec![2];
    let link1 = body("link1", [0.2, 0.0, 0.21], [0.25, 0.04, 0.05]);
    let link2 = body("link2", [0.6, 0.0, 0.32], [0.2, 0.035, 0.05]);
    Scenario {
        mechanism: Mechanism {
            bodies: vec![base, link1, link2],
            joints: vec![
                JointSpec {
                    parent: 0,
                    child: 1,
                    joint_type: JointType::Revolute,
                    axis: [0.0, 0.0, 1.0],
                    anchor: [0.0, 0.0, 0.0],
                    second_axis: None,
                },
                JointSpec {
                    parent: 1,
                    child: 2,
                    joint_type: JointType::Revolute,
                    axis: [0.0, 0.0, 1.0],
                    anchor: [0.4, 0.0, 0.0],
                    second_axis: None,
                },
            ],
        },
        trajectories: vec![
            Trajectory::Quadratic { final_value: 6.0 },
            Trajectory::Quadratic { final_value: 3.0 },
        ],
        n_frames: 100,
        frame_rate_hz: 30.0,
        camera: Camera::looking_at([1.8, -1.6, 0.7], [0.1, 0.0, 0.15], 70.0, 55.0),
        noise_sigma_m: 0.001,
        dropout: 0.0,
        seed,
        self_occlusion: true,
        partly_seen: Vec::new(),
        soft_tissue_m: 0.0,
    }
}

/// Parameters of [`random_scenario`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RandomParams {
    /// Number of joints (bodies = joints + 1).
    pub n_joints: usize,
    /// Probability that a joint is prismatic.
    pub prismatic_fraction: f64,
    /// Probability that a joint that is not prismatic is spherical (a ball joint, drawn
    /// only when positive, so the draws of mechanisms without them do not change).
    pub spherical_fraction: f64,
    /// Attach each new body to a random earlier one (a tree) instead of the last (a chain).
    pub tree: bool,
    /// Keypoints per body beyond the 8 corners.
    pub extra_points: usize,
    /// Number of frames.
    pub n_frames: usize,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Extra random occlusion (see [`Scenario::dropout`]).
    pub dropout: f64,
    /// Seed.
    pub seed: u64,
}

impl Default for RandomParams {
    fn default() -> Self {
        Self {
            n_joints: 3,
            prismatic_fraction: 0.3,
            spherical_fraction: 0.0,
            tree: false,
            extra_points: 2,
            n_frames: 200,
            noise_sigma_m: 0.001,
            dropout: 0.0,
            seed: 0,
        }
    }
}

impl RandomParams {
    /// Checks the ranges: at most 200 joints, 10 000 extra keypoints a body and 1 000 000
    /// frames; a prismatic fraction and a dropout in `[0, 1]`; a noise level from 0 to 1 m.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count("data.n_joints", self.n_joints, 0, 200)?;
        check_count("data.extra_points", self.extra_points, 0, 10_000)?;
        check_count("data.n_frames", self.n_frames, 2, 1_000_000)?;
        check_within("data.prismatic_fraction", self.prismatic_fraction, 0.0, 1.0)?;
        check_within("data.spherical_fraction", self.spherical_fraction, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 1.0)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)
    }
}

/// A random mechanism of box links growing from a static base along the axis directions,
/// with random 3D joint axes and sine trajectories.
///
/// Excitation rule: every joint follows its own sine with a distinct frequency between 0.15
/// and 0.45 Hz over at least one half period, with amplitude 0.6-1.4 rad (revolute) or
/// 6-15 cm (prismatic), so each joint moves far beyond the noise and joints are not
/// correlated. A spherical joint's three rotation-vector coordinates each follow such a sine
/// with amplitude 0.35-0.8 rad (20-45 deg) and their own frequencies, so it turns about
/// every axis.
pub fn random_scenario(p: &RandomParams) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut bodies = vec![body("base", [0.0, 0.0, -0.05], [0.2, 0.2, 0.05])];
    let mut tips = vec![([0.0, 0.0, 0.0], 4usize)];
    let mut joints = Vec::new();
    let mut trajectories = Vec::new();
    let dirs: [[f64; 3]; 5] = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    for j in 0..p.n_joints {
        let parent = if p.tree { rng.random_range(0..=j) } else { j };
        let (anchor, parent_dir) = tips[parent];
        // Grow in a direction other than straight back into the parent.
        let back = match parent_dir {
            0 => 1,
            1 => 0,
            2 => 3,
            3 => 2,
            _ => 5,
        };
        let mut d = rng.random_range(0..5);
        while d == back {
            d = rng.random_range(0..5);
        }
        let dir = dirs[d];
        let len = rng.random_range(0.15..0.3);
        let w = rng.random_range(0.025..0.05);
        let gap = 0.01;
        let centre: [f64; 3] = std::array::from_fn(|i| anchor[i] + dir[i] * (gap + len / 2.0));
        let half: [f64; 3] = std::array::from_fn(|i| if dir[i] != 0.0 { len / 2.0 } else { w });
        let tip: [f64; 3] = std::array::from_fn(|i| anchor[i] + dir[i] * (gap + len));
        let mut b = body(&format!("link{}", j + 1), centre, half);
        b.extra_points = p.extra_points;
        bodies.push(b);
        tips.push((tip, d));
        let prismatic = rng.random_bool(p.prismatic_fraction.clamp(0.0, 1.0));
        let axis = random_unit(&mut rng);
        let spherical = !prismatic
            && p.spherical_fraction > 0.0
            && rng.random_bool(p.spherical_fraction.clamp(0.0, 1.0));
        joints.push(JointSpec {
            parent,
            child: j + 1,
            joint_type: if prismatic {
                JointType::Prismatic
            } else if spherical {
                JointType::Spherical
            } else {
                JointType::Revolute
            },
            axis: [axis.x, axis.y, axis.z],
            anchor,
            second_axis: None,
        });
        if spherical {
            for i in 0..3 {
                let share = (j as f64 + (i as f64 + rng.random_range(0.0..1.0)) / 3.0)
                    / p.n_joints.max(1) as f64;
                trajectories.push(Trajectory::Sine {
                    offset: 0.0,
                    amplitude: rng.random_range(0.35..0.8),
                    frequency_hz: 0.15 + 0.3 * share,
                    phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
                });
            }
            continue;
        }
        let amplitude = if prismatic {
            rng.random_range(0.06..0.15)
        } else {
            rng.random_range(0.6..1.4)
        };
        let frequency_hz =
            0.15 + 0.3 * (j as f64 + rng.random_range(0.0..1.0)) / p.n_joints.max(1) as f64;
        trajectories.push(Trajectory::Sine {
            offset: 0.0,
            amplitude,
            frequency_hz,
            phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
        });
    }
    let az = rng.random_range(0.0..std::f64::consts::TAU);
    let el = rng.random_range(0.35..0.7f64);
    let dist = 3.0;
    Scenario {
        mechanism: Mechanism { bodies, joints },
        trajectories,
        n_frames: p.n_frames,
        frame_rate_hz: 30.0,
        camera: Camera::looking_at(
            [
                dist * el.cos() * az.cos(),
                dist * el.cos() * az.sin(),
                0.3 + dist * el.sin(),
            ],
            [0.0, 0.0, 0.3],
            90.0,
            80.0,
        ),
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
        self_occlusion: true,
        partly_seen: Vec::new(),
        soft_tissue_m: 0.0,
    }
}
