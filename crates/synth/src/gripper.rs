//! An arm with a gripper: a static base, a chain of revolute links, a hand on a revolute
//! wrist, and two fingers that either slide along one axis (a parallel gripper) or turn about
//! one pin (an angular gripper). Either way the two fingers' motion relative to each other is
//! a joint of the same type, so the data fit the fingers as siblings and as a chain equally.

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, Scenario, Trajectory, random_unit};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// How the fingers move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GripperKind {
    /// Both fingers slide along the hand's lateral axis.
    Parallel,
    /// Both jaws turn about one pin across the hand's tip.
    Angular,
}

/// Parameters of [`gripper_scenario`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GripperParams {
    /// How the fingers move.
    pub gripper: GripperKind,
    /// Revolute joints of the arm before the wrist.
    pub arm_joints: usize,
    /// Keypoints on each body beyond its 8 corners.
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

impl Default for GripperParams {
    fn default() -> Self {
        Self {
            gripper: GripperKind::Parallel,
            arm_joints: 2,
            extra_points: 2,
            n_frames: 300,
            noise_sigma_m: 0.001,
            dropout: 0.0,
            seed: 0,
        }
    }
}

impl GripperParams {
    /// Checks the ranges: 0 to 10 arm joints, at most 10 000 extra keypoints a body, 2 to
    /// 1 000 000 frames, noise from 0 to 1 m, a dropout in `[0, 0.99]`.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count("data.arm_joints", self.arm_joints, 0, 10)?;
        check_count("data.extra_points", self.extra_points, 0, 10_000)?;
        check_count("data.n_frames", self.n_frames, 2, 1_000_000)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 0.99)
    }
}

fn body(name: &str, centre: [f64; 3], half_extents: [f64; 3], extra_points: usize) -> BodySpec {
    BodySpec {
        name: name.into(),
        shape: BoxShape {
            centre,
            half_extents,
        },
        skip_corners: Vec::new(),
        extra_points,
        interior_points: 0,
        marked_points: Vec::new(),
    }
}

/// An arm standing on a static base (40 x 40 x 10 cm): `arm_joints` links of 15-25 cm turning
/// about random axes through their bottom ends, a hand (12 x 5 x 6 cm) on a revolute wrist,
/// and two fingers (2 x 3 x 8 cm) on the hand's tip. A parallel gripper's fingers slide along
/// the hand's lateral axis (x at the zero configuration), each through 1-2 cm about 4 cm from
/// the middle; an angular gripper's jaws turn about one pin along the hand's y axis through
/// its tip, each through 0.2-0.5 rad. Every coordinate follows its own sine at 0.1-0.45 Hz
/// with a random phase (the fingers move independently); the arm's joints swing through
/// 0.6-1.2 rad. The camera looks down on the arm from 2 m.
pub fn gripper_scenario(p: &GripperParams) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut bodies = vec![body("base", [0.0, 0.0, -0.05], [0.2, 0.2, 0.05], 0)];
    let mut joints = Vec::new();
    let mut trajectories = Vec::new();
    let sine = |rng: &mut ChaCha8Rng, amplitude: f64| Trajectory::Sine {
        offset: 0.0,
        amplitude,
        frequency_hz: rng.random_range(0.1..0.45),
        phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
    };
    let mut top = 0.0;
    let mut revolute = |rng: &mut ChaCha8Rng,
                        bodies: &mut Vec<BodySpec>,
                        name: &str,
                        height: f64,
                        half: [f64; 2],
                        top: &mut f64| {
        let parent = bodies.len() - 1;
        bodies.push(body(
            name,
            [0.0, 0.0, *top + 0.01 + height / 2.0],
            [half[0], half[1], height / 2.0],
            p.extra_points,
        ));
        let axis = random_unit(rng);
        joints.push(JointSpec {
            parent,
            child: parent + 1,
            joint_type: JointType::Revolute,
            axis: [axis.x, axis.y, axis.z],
            anchor: [0.0, 0.0, *top],
            second_axis: None,
        });
        *top += 0.01 + height;
    };
    for k in 0..p.arm_joints {
        let len = rng.random_range(0.15..0.25);
        revolute(
            &mut rng,
            &mut bodies,
            &format!("link{}", k + 1),
            len,
            [0.035, 0.035],
            &mut top,
        );
    }
    revolute(&mut rng, &mut bodies, "hand", 0.06, [0.06, 0.025], &mut top);
    for _ in 0..=p.arm_joints {
        let amplitude = rng.random_range(0.3..0.6);
        trajectories.push(sine(&mut rng, amplitude));
    }
    let hand = bodies.len() - 1;
    for (side, name) in [(1.0, "finger_left"), (-1.0, "finger_right")] {
        bodies.push(body(
            name,
            [side * 0.04, 0.0, top + 0.01 + 0.04],
            [0.01, 0.015, 0.04],
            p.extra_points,
        ));
        let (joint_type, axis, amplitude) = match p.gripper {
            GripperKind::Parallel => (
                JointType::Prismatic,
                [side, 0.0, 0.0],
                rng.random_range(0.005..0.01),
            ),
            GripperKind::Angular => (
                JointType::Revolute,
                [0.0, side, 0.0],
                rng.random_range(0.1..0.25),
            ),
        };
        joints.push(JointSpec {
            parent: hand,
            child: bodies.len() - 1,
            joint_type,
            axis,
            anchor: [0.0, 0.0, top],
            second_axis: None,
        });
        trajectories.push(sine(&mut rng, amplitude));
    }
    Scenario {
        mechanism: Mechanism { bodies, joints },
        trajectories,
        n_frames: p.n_frames,
        frame_rate_hz: 30.0,
        camera: Camera::looking_at([1.2, -1.4, 1.3], [0.0, 0.0, 0.3], 80.0, 70.0),
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
        self_occlusion: true,
        partly_seen: Vec::new(),
        soft_tissue_m: 0.0,
    }
}
