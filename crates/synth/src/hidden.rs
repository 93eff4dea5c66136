//! An arm with one link mostly hidden: a short link buried between its neighbours, seen by a
//! few keypoints in part of the frames (a robot's wrist links seen by a camera).

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, PartlySeen, Scenario, Trajectory, random_unit};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Parameters of [`hidden_link_arm`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HiddenLinkParams {
    /// Revolute joints of the arm (one link each).
    pub n_joints: usize,
    /// Which link is hidden, 1-based along the chain (0: the last but one, as a wrist link).
    pub hidden_link: usize,
    /// Keypoints on the hidden link (0: a link buried between its neighbours, which no
    /// keypoint shows).
    pub hidden_points: usize,
    /// Fraction of the frames in which the hidden link can be seen at all.
    pub hidden_fraction: f64,
    /// Windows of frames the hidden link is seen in ([`PartlySeen::windows`]).
    pub hidden_windows: usize,
    /// Number of frames.
    pub n_frames: usize,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Extra random occlusion of every keypoint (see [`Scenario::dropout`]).
    pub dropout: f64,
    /// Seed.
    pub seed: u64,
}

impl Default for HiddenLinkParams {
    fn default() -> Self {
        Self {
            n_joints: 6,
            hidden_link: 0,
            hidden_points: 8,
            hidden_fraction: 0.27,
            hidden_windows: 3,
            n_frames: 300,
            noise_sigma_m: 0.001,
            dropout: 0.15,
            seed: 0,
        }
    }
}

impl HiddenLinkParams {
    /// Checks the ranges: 2 to 12 joints, a hidden link among them (or 0), 3 to 1000 keypoints
    /// on it, a fraction in `[0, 1]`, 1 to 100 windows, 2 to 1 000 000 frames, noise from 0 to
    /// 1 m, a dropout in `[0, 0.99]`.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count("data.n_joints", self.n_joints, 2, 12)?;
        check_count("data.hidden_link", self.hidden_link, 0, self.n_joints)?;
        check_count("data.hidden_points", self.hidden_points, 0, 1000)?;
        check_within("data.hidden_fraction", self.hidden_fraction, 0.0, 1.0)?;
        check_count("data.hidden_windows", self.hidden_windows, 1, 100)?;
        check_count("data.n_frames", self.n_frames, 2, 1_000_000)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 0.99)
    }

    /// The hidden link's body id (the base is body 0, link `k` body `k`).
    pub fn hidden_body(&self) -> usize {
        if self.hidden_link == 0 {
            self.n_joints.saturating_sub(1).max(1)
        } else {
            self.hidden_link
        }
    }
}

/// An arm standing on a static base (40 x 40 x 10 cm): `n_joints` links stacked upwards, each
/// turning about a random axis through its bottom end over 0.6-1.2 rad at 0.1-0.45 Hz with a
/// random phase. The visible links are 12-25 cm boxes of 7 x 7 cm with their 8 corners and two
/// more keypoints; the hidden one is a 5 cm box of 4 x 4 cm with `hidden_points` keypoints on
/// its surface, seen only in `hidden_windows` windows covering `hidden_fraction` of the
/// frames. The camera looks down on the arm from about 2 m; the links hide each other.
pub fn hidden_link_arm(p: &HiddenLinkParams) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let hidden = p.hidden_body();
    let body =
        |name: String, centre: [f64; 3], half: [f64; 3], corners: bool, extra: usize| BodySpec {
            name,
            shape: BoxShape {
                centre,
                half_extents: half,
            },
            skip_corners: if corners {
                Vec::new()
            } else {
                (0..8).collect()
            },
            extra_points: extra,
            interior_points: 0,
            marked_points: Vec::new(),
        };
    let mut bodies = vec![body(
        "base".into(),
        [0.0, 0.0, -0.05],
        [0.2, 0.2, 0.05],
        true,
        0,
    )];
    let mut joints = Vec::new();
    let mut trajectories = Vec::new();
    let mut top = 0.0;
    for k in 1..=p.n_joints {
        let (len, half, corners, extra) = if k == hidden {
            (0.05, 0.02, false, p.hidden_points)
        } else {
            (rng.random_range(0.12..0.25), 0.035, true, 2)
        };
        bodies.push(body(
            format!("link{k}"),
            [0.0, 0.0, top + 0.01 + len / 2.0],
            [half, half, len / 2.0],
            corners,
            extra,
        ));
        let axis = random_unit(&mut rng);
        joints.push(JointSpec {
            parent: k - 1,
            child: k,
            joint_type: JointType::Revolute,
            axis: [axis.x, axis.y, axis.z],
            anchor: [0.0, 0.0, top],
            second_axis: None,
        });
        top += 0.01 + len;
    }
    for _ in 0..p.n_joints {
        trajectories.push(Trajectory::Sine {
            offset: 0.0,
            amplitude: rng.random_range(0.3..0.6),
            frequency_hz: rng.random_range(0.1..0.45),
            phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
        });
    }
    Scenario {
        mechanism: Mechanism { bodies, joints },
        trajectories,
        n_frames: p.n_frames,
        frame_rate_hz: 30.0,
        camera: Camera::looking_at([1.2, -1.4, 1.6], [0.0, 0.0, 0.4], 80.0, 70.0),
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
        self_occlusion: true,
        partly_seen: vec![PartlySeen {
            body: hidden,
            fraction: p.hidden_fraction,
            windows: p.hidden_windows,
        }],
        soft_tissue_m: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate;

    #[test]
    fn the_hidden_link_is_seen_only_in_its_windows() {
        let p = HiddenLinkParams::default();
        let d = simulate(&hidden_link_arm(&p)).expect("simulate");
        let hidden = p.hidden_body();
        assert_eq!(hidden, 5);
        let points: Vec<usize> = (0..d.tracks.n_points())
            .filter(|&i| d.truth.point_body[i] == hidden)
            .collect();
        assert_eq!(points.len(), p.hidden_points);
        // Frames in which any of its keypoints is seen: at most the windows' share.
        let seen = (0..p.n_frames)
            .filter(|&t| points.iter().any(|&i| d.tracks.get(t, i).is_some()))
            .count();
        assert!(seen > 0 && seen <= (p.hidden_fraction * p.n_frames as f64).round() as usize + 3);
        // The other links are seen far more.
        let other = (0..p.n_frames)
            .filter(|&t| {
                (0..d.tracks.n_points())
                    .any(|i| d.truth.point_body[i] == 4 && d.tracks.get(t, i).is_some())
            })
            .count();
        assert!(other > 2 * seen, "{other} against {seen}");
        // Without the windows the same scenario is seen throughout, and nothing else changes.
        let mut open = hidden_link_arm(&p);
        open.partly_seen.clear();
        let o = simulate(&open).expect("simulate");
        for t in 0..p.n_frames {
            for i in 0..d.tracks.n_points() {
                if d.truth.point_body[i] != hidden {
                    assert_eq!(d.tracks.get(t, i), o.tracks.get(t, i));
                }
            }
        }
    }

    #[test]
    fn bad_windows_are_config_errors() {
        let mut s = hidden_link_arm(&HiddenLinkParams::default());
        s.partly_seen[0].windows = 0;
        assert!(simulate(&s).is_err());
        s.partly_seen[0] = PartlySeen {
            body: 99,
            fraction: 0.5,
            windows: 1,
        };
        assert!(simulate(&s).is_err());
    }
}
