//! An arm of slender links: rods a few millimetres thick whose keypoints lie nearly on a
//! line (a planar manipulator's bars, a reacher's capsules, a robot's thin links).

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, Scenario, Trajectory, random_unit};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Parameters of [`slender_arm`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlenderArmParams {
    /// Revolute joints of the arm (one link each).
    pub n_joints: usize,
    /// Every axis parallel (a planar manipulator); otherwise each axis is random.
    pub planar: bool,
    /// Thickness of each rod (the side of its square section), metres.
    pub thickness_m: f64,
    /// Keypoints on each rod (at random places in it).
    pub points_per_link: usize,
    /// Number of frames.
    pub n_frames: usize,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Extra random occlusion of every keypoint (see [`Scenario::dropout`]).
    pub dropout: f64,
    /// Seed.
    pub seed: u64,
}

impl Default for SlenderArmParams {
    fn default() -> Self {
        Self {
            n_joints: 3,
            planar: true,
            thickness_m: 0.004,
            points_per_link: 6,
            n_frames: 300,
            noise_sigma_m: 0.001,
            dropout: 0.1,
            seed: 0,
        }
    }
}

impl SlenderArmParams {
    /// Checks the ranges: 1 to 12 joints, a thickness from 0.1 mm to 10 cm, 3 to 1000
    /// keypoints a link, 2 to 1 000 000 frames, noise from 0 to 1 m, a dropout in
    /// `[0, 0.99]`.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count("data.n_joints", self.n_joints, 1, 12)?;
        check_within("data.thickness_m", self.thickness_m, 1e-4, 0.1)?;
        check_count("data.points_per_link", self.points_per_link, 3, 1000)?;
        check_count("data.n_frames", self.n_frames, 2, 1_000_000)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 0.99)
    }
}

/// An arm on a static base (30 x 30 x 5 cm, its 8 corners as keypoints): `n_joints` rods of
/// 15-30 cm stacked upwards, each `thickness_m` square with `points_per_link` keypoints at
/// random places in it, so nearly collinear. Each turns about an axis through its
/// bottom end (the x axis for every joint when `planar`, so the arm moves in one plane; a
/// random axis otherwise) over 0.8-1.8 rad at 0.1-0.4 Hz with a random phase. The camera
/// looks at the plane of motion from about 2 m; nothing hides a keypoint but the burst
/// dropout.
pub fn slender_arm(p: &SlenderArmParams) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut bodies = vec![BodySpec {
        name: "base".into(),
        shape: BoxShape {
            centre: [0.0, 0.0, -0.025],
            half_extents: [0.15, 0.15, 0.025],
        },
        skip_corners: Vec::new(),
        extra_points: 0,
        interior_points: 0,
        marked_points: Vec::new(),
    }];
    let mut joints = Vec::new();
    let mut trajectories = Vec::new();
    let half = p.thickness_m / 2.0;
    let mut top = 0.0;
    for k in 1..=p.n_joints {
        let len: f64 = rng.random_range(0.15..0.3);
        bodies.push(BodySpec {
            name: format!("rod{k}"),
            shape: BoxShape {
                centre: [0.0, 0.0, top + len / 2.0],
                half_extents: [half, half, len / 2.0],
            },
            skip_corners: (0..8).collect(),
            // Inside the rod, so spread along its length (the surface sampler would put a
            // third of them on its end caps, at the joints).
            extra_points: 0,
            interior_points: p.points_per_link,
            marked_points: Vec::new(),
        });
        let axis = if p.planar {
            kinetree_core::nalgebra::Vector3::x()
        } else {
            random_unit(&mut rng)
        };
        joints.push(JointSpec {
            parent: k - 1,
            child: k,
            joint_type: JointType::Revolute,
            axis: [axis.x, axis.y, axis.z],
            anchor: [0.0, 0.0, top],
            second_axis: None,
        });
        trajectories.push(Trajectory::Sine {
            offset: 0.0,
            amplitude: rng.random_range(0.4..0.9),
            frequency_hz: rng.random_range(0.1..0.4),
            phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
        });
        top += len;
    }
    Scenario {
        mechanism: Mechanism { bodies, joints },
        trajectories,
        n_frames: p.n_frames,
        frame_rate_hz: 30.0,
        camera: Camera::looking_at([2.0, 0.3, 0.6], [0.0, 0.0, top / 2.0], 80.0, 70.0),
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
        // A rod a few millimetres thick hides little, and markers stand off its surface:
        // every keypoint is seen except for the burst dropout.
        self_occlusion: false,
        partly_seen: Vec::new(),
        soft_tissue_m: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate;

    #[test]
    fn rods_keep_their_keypoints_near_a_line_and_planar_arms_in_a_plane() {
        let p = SlenderArmParams::default();
        let d = simulate(&slender_arm(&p)).expect("simulate");
        assert_eq!(d.truth.n_bodies(), p.n_joints + 1);
        for b in 1..=p.n_joints {
            let points: Vec<_> = (0..d.tracks.n_points())
                .filter(|&i| d.truth.point_body[i] == b)
                .map(|i| d.truth.body_points[i])
                .collect();
            assert_eq!(points.len(), p.points_per_link);
            // Across the rod every keypoint is within half its diagonal of the axis, and the
            // keypoints spread along it.
            for q in &points {
                assert!(q.x.hypot(q.y) <= p.thickness_m / 2.0 * 2f64.sqrt() + 1e-12);
            }
            let (lo, hi) = points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), q| {
                    (a.min(q.z), b.max(q.z))
                });
            assert!(hi - lo > 0.05, "rod {b} keypoints span {} m", hi - lo);
        }
        // Planar: every axis is x, and the rods' keypoints move in planes x = const.
        for j in &d.truth.mechanism.joints {
            assert_eq!(j.axis, [1.0, 0.0, 0.0]);
        }
        // Only the burst dropout hides keypoints.
        let seen = (0..d.tracks.n_frames())
            .flat_map(|t| (0..d.tracks.n_points()).map(move |i| (t, i)))
            .filter(|&(t, i)| d.tracks.get(t, i).is_some())
            .count();
        let share = seen as f64 / (d.tracks.n_frames() * d.tracks.n_points()) as f64;
        assert!(share > 0.8, "{share} of the observations seen");
    }

    #[test]
    fn bad_parameters_are_config_errors() {
        for p in [
            SlenderArmParams {
                thickness_m: 0.0,
                ..SlenderArmParams::default()
            },
            SlenderArmParams {
                points_per_link: 2,
                ..SlenderArmParams::default()
            },
            SlenderArmParams {
                n_joints: 0,
                ..SlenderArmParams::default()
            },
        ] {
            assert!(p.validate().is_err(), "{p:?}");
        }
    }
}
