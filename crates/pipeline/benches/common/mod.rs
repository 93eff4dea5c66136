//! The 9-joint arm both pipeline benchmarks run on.

use kinetree_core::Tracks;
use kinetree_synth::{JointDraw, MechanismSpec, simulate};

/// A 9-joint arm (two revolute joints, then a prismatic one, three times) with 80 keypoints
/// (the base's 8 and 8 on each link) over 150 frames at 1 mm of noise and 10 % occlusion,
/// from a fixed seed.
pub fn arm_tracks() -> Tracks {
    let joints = (0..9)
        .map(|k| JointDraw {
            parent_pick: 0.0,
            revolute: k % 3 != 2,
            axis: [(k as f64).cos(), (k as f64).sin(), 0.7],
            size_m: 0.25,
            n_points: 8,
            amplitude: 0.5,
            phase: k as f64,
        })
        .collect();
    let spec = MechanismSpec {
        joints,
        tree: false,
        noise_sigma_m: 0.001,
        dropout: 0.1,
        seed: 9,
    };
    let tracks = simulate(&spec.scenario()).expect("simulate").tracks;
    assert_eq!((tracks.n_points(), tracks.n_frames()), (80, 150));
    tracks
}
