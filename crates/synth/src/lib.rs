//! Synthetic articulated mechanisms: boxes joined by revolute and prismatic joints, joint
//! trajectories, a camera with a field of view, self-occlusion by ray casting, extra burst
//! dropout and Gaussian noise, all from a seed.

mod mechanism;
mod named;
mod scenario;
mod spec;
#[cfg(feature = "proptest")]
pub mod strategies;

pub use mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
pub use named::{RandomParams, paper_arm, random_scenario};
pub use scenario::{Camera, GroundTruth, Scenario, SynthData, Trajectory, simulate};
pub use spec::{JointDraw, MechanismSpec, SPEC_FRAMES};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_arm_matches_the_paper_setup() {
        let d = simulate(&paper_arm(0)).expect("simulate");
        assert_eq!(d.tracks.n_points(), 23, "24 corners minus one");
        assert_eq!(d.tracks.n_frames(), 100);
        assert_eq!(d.tracks.frame_rate_hz(), Some(30.0));
        assert!(
            d.truth.visible_frames.iter().all(|&v| v >= 2),
            "every keypoint seen"
        );
        // Link 2 passes in front of link 1, and the links in front of the base, part of the
        // time (the camera looks down on the arm, so nothing ever covers link 2).
        let hidden = |body: usize| -> usize {
            (0..23)
                .filter(|&i| d.truth.point_body[i] == body)
                .map(|i| d.truth.occluded_by_other_body[i])
                .sum()
        };
        for body in [0, 1] {
            let h = hidden(body);
            assert!(
                h > 0 && h < 8 * 50,
                "body {body} hidden by others {h} times"
            );
        }
        // Link 1 about one turn, link 2 about half a turn relative to it; quadratic.
        let q = &d.truth.joint_positions;
        assert!((q[0][99] - 6.0).abs() < 1e-12 && (q[1][99] - 3.0).abs() < 1e-12);
        assert!((q[0][50] / q[0][99] - (50.0f64 / 99.0).powi(2)).abs() < 1e-12);
    }

    #[test]
    fn same_seed_same_data_and_noise_is_per_coordinate_sigma() {
        let mut s = random_scenario(&RandomParams::default());
        s.dropout = 0.3;
        let a = simulate(&s).expect("a");
        let b = simulate(&s).expect("b");
        assert_eq!(a.tracks.raw().len(), b.tracks.raw().len());
        assert!(
            a.tracks
                .raw()
                .iter()
                .zip(b.tracks.raw())
                .all(|(x, y)| x.to_bits() == y.to_bits())
        );
        let occ = a.tracks.occluded_fraction();
        assert!(occ > 0.3, "dropout on top of self-occlusion: {occ}");
        // Noise: compare with the noise-free simulation.
        let mut clean = s.clone();
        clean.noise_sigma_m = 0.0;
        let c = simulate(&clean).expect("clean");
        let diffs: Vec<f64> = a
            .tracks
            .raw()
            .iter()
            .zip(c.tracks.raw())
            .filter(|(x, y)| !x.is_nan() && !y.is_nan())
            .map(|(x, y)| x - y)
            .collect();
        let sd = (diffs.iter().map(|d| d * d).sum::<f64>() / diffs.len() as f64).sqrt();
        assert!((sd / s.noise_sigma_m - 1.0).abs() < 0.05, "noise sd {sd}");
    }
}
