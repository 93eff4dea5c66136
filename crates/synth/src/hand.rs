//! A human-like hand: a palm, four fingers of three phalanges and a thumb of three links,
//! links of 1.2-2.5 cm with keypoints on their surfaces, universal joints (flexion, then
//! abduction) at the knuckles and the thumb's base, and hinges between phalanges.

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, Scenario, Trajectory};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Parameters of [`hand_scenario`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HandParams {
    /// Keypoints on each link's surface (the palm has twice as many).
    pub keypoints_per_link: usize,
    /// Least and most flexion range of each joint, degrees; abduction swings through a
    /// quarter of it.
    pub motion_deg: [f64; 2],
    /// Number of frames.
    pub n_frames: usize,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Random occlusion (see [`Scenario::dropout`]); links also hide each other.
    pub dropout: f64,
    /// Seed.
    pub seed: u64,
}

impl Default for HandParams {
    fn default() -> Self {
        Self {
            keypoints_per_link: 8,
            motion_deg: [30.0, 90.0],
            n_frames: 300,
            noise_sigma_m: 0.001,
            dropout: 0.2,
            seed: 0,
        }
    }
}

impl HandParams {
    /// Checks the ranges: 3 to 1000 keypoints a link, a motion range within 1-170 deg (least
    /// first), 2 to 1 000 000 frames, noise from 0 to 1 m, a dropout in `[0, 0.99]`.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count("data.keypoints_per_link", self.keypoints_per_link, 3, 1000)?;
        check_within("data.motion_deg", self.motion_deg[0], 1.0, 170.0)?;
        check_within(
            "data.motion_deg",
            self.motion_deg[1],
            self.motion_deg[0],
            170.0,
        )?;
        check_count("data.n_frames", self.n_frames, 2, 1_000_000)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 0.99)
    }
}

/// Lengths of a finger's three links, proximal first, metres, and the knuckle's x on the
/// palm's top edge (index to little finger), then the thumb's.
const FINGERS: [(f64, [f64; 3]); 4] = [
    (0.027, [0.025, 0.016, 0.012]),
    (0.009, [0.025, 0.018, 0.013]),
    (-0.009, [0.024, 0.017, 0.012]),
    (-0.027, [0.02, 0.014, 0.012]),
];
const THUMB: [f64; 3] = [0.025, 0.02, 0.015];

/// A static palm (8 x 2 x 9 cm, in the x-z plane, fingers pointing up +z) with four fingers
/// and a thumb: 16 bodies, 15 joints. Each finger's knuckle is a universal joint, flexion
/// about the palm's x axis then abduction about the finger's y axis (normal to the palm), and
/// its two other joints are hinges about x; the thumb leaves the palm's side along +x with a
/// universal joint at its base (about z, then y) and two hinges about z. Links are 1.6 cm
/// wide and 1.4 cm thick with `keypoints_per_link` keypoints on their surfaces, as a point
/// tracker gives on a hand; a camera 60 cm in front of the palm.
///
/// Motion: every coordinate follows its own sine at 0.1-0.4 Hz with a random phase: a flexion
/// from straight through a range drawn from `motion_deg`, an abduction about zero through a
/// quarter of one.
pub fn hand_scenario(p: &HandParams) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let link = |name: String, centre: [f64; 3], half: [f64; 3], points: usize| BodySpec {
        name,
        shape: BoxShape {
            centre,
            half_extents: half,
        },
        skip_corners: (0..8).collect(),
        extra_points: points,
        interior_points: 0,
        marked_points: Vec::new(),
    };
    let mut bodies = vec![link(
        "palm".into(),
        [0.0, 0.0, 0.0],
        [0.04, 0.01, 0.045],
        2 * p.keypoints_per_link,
    )];
    let mut joints = Vec::new();
    let mut trajectories = Vec::new();
    let [least, most] = p.motion_deg.map(f64::to_radians);
    let swing = |rng: &mut ChaCha8Rng, flexion: bool| {
        let range = rng.random_range(least..=most) * if flexion { 1.0 } else { 0.25 };
        Trajectory::Sine {
            offset: if flexion { range / 2.0 } else { 0.0 },
            amplitude: range / 2.0,
            frequency_hz: rng.random_range(0.1..0.4),
            phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
        }
    };
    let (half_w, half_t) = (0.008, 0.007);
    // A finger or the thumb: links from `start` along the x or z axis (`along`), each turning
    // about `flexion`, the first on a universal joint whose second axis is y.
    let mut chain = |rng: &mut ChaCha8Rng,
                     bodies: &mut Vec<BodySpec>,
                     name: &str,
                     start: [f64; 3],
                     along: usize,
                     lengths: &[f64],
                     flexion: [f64; 3]| {
        let mut at = start;
        let mut parent = 0;
        for (k, len) in lengths.iter().enumerate() {
            let mut centre = at;
            centre[along] += 0.001 + len / 2.0;
            let mut half = [half_w, half_t, half_w];
            half[along] = len / 2.0;
            bodies.push(link(
                format!("{name}_{}", k + 1),
                centre,
                half,
                p.keypoints_per_link,
            ));
            let child = bodies.len() - 1;
            let universal = k == 0;
            joints.push(JointSpec {
                parent,
                child,
                joint_type: if universal {
                    JointType::Universal
                } else {
                    JointType::Revolute
                },
                axis: flexion,
                anchor: at,
                second_axis: universal.then_some([0.0, 1.0, 0.0]),
            });
            trajectories.push(swing(rng, true));
            if universal {
                trajectories.push(swing(rng, false));
            }
            parent = child;
            at[along] += 0.001 + len;
        }
    };
    for (f, (x, lengths)) in FINGERS.iter().enumerate() {
        chain(
            &mut rng,
            &mut bodies,
            &format!("finger{}", f + 1),
            [*x, 0.0, 0.045],
            2,
            lengths,
            [1.0, 0.0, 0.0],
        );
    }
    chain(
        &mut rng,
        &mut bodies,
        "thumb",
        [0.04, 0.0, -0.015],
        0,
        &THUMB,
        [0.0, 0.0, 1.0],
    );
    Scenario {
        mechanism: Mechanism { bodies, joints },
        trajectories,
        n_frames: p.n_frames,
        frame_rate_hz: 30.0,
        camera: Camera::looking_at([0.1, -0.6, 0.15], [0.0, 0.0, 0.05], 60.0, 50.0),
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
        self_occlusion: true,
        partly_seen: Vec::new(),
        soft_tissue_m: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate;

    #[test]
    fn a_hand_has_sixteen_links_on_universal_knuckles_and_hinges() {
        let s = hand_scenario(&HandParams::default());
        let m = &s.mechanism;
        assert_eq!((m.bodies.len(), m.joints.len()), (16, 15));
        let count = |t: JointType| m.joints.iter().filter(|j| j.joint_type == t).count();
        assert_eq!(
            (count(JointType::Universal), count(JointType::Revolute)),
            (5, 10)
        );
        assert_eq!(s.trajectories.len(), 20);
        let d = simulate(&s).expect("simulate");
        assert_eq!(d.tracks.n_points(), 16 * 8 + 8);
        // Links 1.2-2.5 cm long: every keypoint within 2.5 cm of its link's centre.
        for (i, p) in d.truth.body_points.iter().enumerate() {
            let c = nalgebra::Vector3::from(m.bodies[d.truth.point_body[i]].shape.centre);
            let reach = if d.truth.point_body[i] == 0 {
                0.07
            } else {
                0.015
            };
            assert!((p.coords - c).norm() < reach, "keypoint {i}");
        }
    }
}
