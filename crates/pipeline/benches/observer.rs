//! Observer latency per frame: a 9-joint arm with 80 keypoints (the base's 8 and 8 on each
//! of 9 links), discovered once from a fixed seed. Run with `cargo bench -p
//! kinetree-pipeline`; divan runs on one thread by default.

mod common;

use kinetree_core::nalgebra::Point3;
use kinetree_fit::Observer;
use kinetree_pipeline::{Pipeline, PipelineConfig};

fn main() {
    divan::main();
}

fn arm() -> (Observer, Vec<Vec<Option<Point3<f64>>>>) {
    let tracks = common::arm_tracks();
    let model = Pipeline::from_config(&PipelineConfig::default())
        .expect("pipeline")
        .run(&tracks)
        .expect("discover")
        .model;
    assert_eq!(model.n_points, 80);
    let observer = Observer::new(&model).expect("observer");
    let frames = (0..tracks.n_frames())
        .map(|t| (0..80).map(|i| tracks.get(t, i)).collect())
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
