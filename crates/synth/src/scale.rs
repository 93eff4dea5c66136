//! The scale scenario that speed is measured on: a static base and four links, revolute,
//! revolute, prismatic, revolute, in a chain, with any number of keypoints and frames.

use crate::{JointDraw, MechanismSpec, Scenario};
use serde::{Deserialize, Serialize};

/// Sizes and observation of the scale scenario ([`scale_scenario`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScaleParams {
    /// Keypoints in all, split evenly over the five bodies (the base takes the remainder);
    /// at least 20.
    pub n_points: usize,
    /// Frames (30 Hz); at least 2.
    pub n_frames: usize,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Random burst occlusion (fraction of observations).
    pub dropout: f64,
    /// Seed of the keypoints, the noise and the occlusion.
    pub seed: u64,
}

impl Default for ScaleParams {
    /// 1000 keypoints over 1000 frames at 1 mm of noise with 15 % occluded.
    fn default() -> Self {
        Self {
            n_points: 1000,
            n_frames: 1000,
            noise_sigma_m: 0.001,
            dropout: 0.15,
            seed: 0,
        }
    }
}

impl ScaleParams {
    /// Checks the ranges: 20 to 10^7 keypoints, 2 to 10^7 frames, noise from 0 to 1 m, a
    /// dropout in `[0, 0.9]`.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count("data.n_points", self.n_points, 20, 10_000_000)?;
        check_count("data.n_frames", self.n_frames, 2, 10_000_000)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 0.9)
    }
}

/// A static base and four 25 cm links (R-R-P-R) with `n_points / 5` keypoints inside each
/// body in general position, every joint on its own sine (a third of a period or more at
/// 1000 frames), no self-occlusion. The joint layout is that of [`MechanismSpec::scenario`];
/// only the keypoint counts and the number of frames differ.
pub fn scale_scenario(p: &ScaleParams) -> Scenario {
    let joints = (0..4)
        .map(|k| JointDraw {
            parent_pick: 0.0,
            revolute: k != 2,
            axis: [(k as f64 * 1.3).cos(), (k as f64 * 1.3).sin(), 0.6],
            size_m: 0.25,
            n_points: 8,
            amplitude: 0.6,
            phase: k as f64,
        })
        .collect();
    let spec = MechanismSpec {
        joints,
        tree: false,
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
    };
    let mut scenario = spec.scenario();
    let n = p.n_points.max(20);
    let per_body = n / 5;
    for (b, body) in scenario.mechanism.bodies.iter_mut().enumerate() {
        body.skip_corners = (0..8).collect();
        body.extra_points = 0;
        body.interior_points = if b == 0 { n - 4 * per_body } else { per_body };
    }
    scenario.n_frames = p.n_frames.max(2);
    scenario.dropout = p.dropout.clamp(0.0, 0.9);
    scenario
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_scenario_has_the_asked_sizes_and_five_even_bodies() {
        let d = crate::simulate(&scale_scenario(&ScaleParams {
            n_points: 103,
            n_frames: 60,
            ..Default::default()
        }))
        .expect("simulate");
        assert_eq!((d.tracks.n_points(), d.tracks.n_frames()), (103, 60));
        let counts: Vec<usize> = (0..5)
            .map(|b| d.truth.point_body.iter().filter(|&&x| x == b).count())
            .collect();
        assert_eq!(counts, vec![23, 20, 20, 20, 20]);
        let kinds: Vec<_> = d
            .truth
            .mechanism
            .joints
            .iter()
            .map(|j| j.joint_type)
            .collect();
        use crate::JointType::{Prismatic, Revolute};
        assert_eq!(kinds, vec![Revolute, Revolute, Prismatic, Revolute]);
        let seen: usize = (0..103).map(|i| d.tracks.visible_count(i)).sum();
        let visible = seen as f64 / (103.0 * 60.0);
        assert!(
            (0.75..0.95).contains(&visible),
            "visible fraction {visible}"
        );
    }
}
