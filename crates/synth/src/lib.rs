//! Synthetic articulated mechanisms: boxes joined by revolute, prismatic and spherical joints
//! (random mechanisms, the paper's arm, a human-like skeleton, an arm with a gripper, a
//! hand, an arm with a hidden link, an arm of slender rods), joint
//! trajectories, a camera with a field of view, self-occlusion by ray casting, extra burst
//! dropout and Gaussian noise, all from a seed.

mod gripper;
mod hand;
mod hidden;
mod mechanism;
mod named;
mod scale;
mod scenario;
mod skeleton;
mod slender;
mod spec;
#[cfg(feature = "proptest")]
pub mod strategies;

pub use gripper::{GripperKind, GripperParams, gripper_scenario};
pub use hand::{HandParams, hand_scenario};
pub use hidden::{HiddenLinkParams, hidden_link_arm};
pub use mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
pub use named::{RandomParams, paper_arm, random_scenario};
pub use scale::{ScaleParams, scale_scenario};
pub use scenario::{Camera, GroundTruth, PartlySeen, Scenario, SynthData, Trajectory, simulate};
pub use skeleton::{SkeletonParams, skeleton_scenario};
pub use slender::{SlenderArmParams, slender_arm};
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

    #[test]
    fn a_ball_joint_takes_three_coordinates_and_keeps_its_centre() {
        let mut s = random_scenario(&RandomParams {
            n_joints: 4,
            prismatic_fraction: 0.0,
            spherical_fraction: 1.0,
            ..RandomParams::default()
        });
        s.n_frames = 40;
        let m = &s.mechanism;
        assert!(
            m.joints
                .iter()
                .all(|j| j.joint_type == JointType::Spherical)
        );
        assert_eq!(m.n_coordinates(), 12);
        assert_eq!(m.coordinate_offsets(), vec![0, 3, 6, 9]);
        assert_eq!(s.trajectories.len(), 12);
        let d = simulate(&s).expect("simulate");
        assert_eq!(d.truth.joint_positions.len(), 12);
        assert!(d.truth.single_positions(0).is_none());
        let mut turned = 0.0f64;
        for t in 0..s.n_frames {
            let q: Vec<f64> = d.truth.joint_positions.iter().map(|p| p[t]).collect();
            let poses = m.forward(&q);
            for j in &m.joints {
                // The centre is fixed in both bodies: where the parent carries it, the child
                // carries it too.
                let c = nalgebra::Point3::from(j.anchor);
                let in_child = poses[j.child] * c;
                assert!((poses[j.parent] * c - in_child).norm() < 1e-12);
                turned = turned.max(
                    (poses[j.parent].inverse() * poses[j.child])
                        .rotation
                        .angle(),
                );
            }
        }
        assert!(turned > 0.3, "largest relative turn {turned} rad");
    }
}
