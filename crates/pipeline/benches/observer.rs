//! Observer latency per frame: a 9-joint arm with 80 keypoints (the base's 8 and 8 on each
//! of 9 links), discovered once from a fixed seed. Run with `cargo bench -p
//! kinetree-pipeline`; divan runs on one thread by default.

use kinetree_core::nalgebra::Point3;
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_structure::Observer;
use kinetree_synth::{JointDraw, MechanismSpec, simulate};

fn main() {
    divan::main();
}

fn arm() -> (Observer, Vec<Vec<Option<Point3<f64>>>>) {
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
    let data = simulate(&spec.scenario()).expect("simulate");
    let model = Pipeline::from_config(&PipelineConfig::default())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover")
        .model;
    assert_eq!(model.n_points, 80);
    let observer = Observer::new(&model).expect("observer");
    let frames = (0..data.tracks.n_frames())
        .map(|t| (0..80).map(|i| data.tracks.get(t, i)).collect())
        .collect();
    (observer, frames)
}

#[divan::bench(sample_count = 200)]
fn observe_one_frame_9_joints_80_points(bencher: divan::Bencher) {
    let (observer, frames) = arm();
    let mut t = 0;
    bencher.bench_local(|| {
        t = (t + 1) % frames.len();
        observer.observe(divan::black_box(&frames[t]))
    });
}

/// Per-body Kabsch-Umeyama poses alone (what the fit once started from), for the ratio.
#[divan::bench(sample_count = 200)]
fn body_poses_one_frame_10_bodies_80_points(bencher: divan::Bencher) {
    let (observer, frames) = arm();
    let mut t = 0;
    bencher.bench_local(|| {
        t = (t + 1) % frames.len();
        observer.body_poses(divan::black_box(&frames[t]))
    });
}
