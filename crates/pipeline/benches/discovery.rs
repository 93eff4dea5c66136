//! Discovery time: the whole pipeline on a 9-joint arm with 80 keypoints over 150 frames (the
//! observer benchmark's arm), and its last stage alone (`fit_model_positions`: the whole-tree
//! fit of every frame, the freeing of joints it cannot follow and the bundle adjustment of
//! the joints). Fixed seed. Run with `cargo bench -p kinetree-pipeline --bench discovery`.

use kinetree_core::{Model, Tracks};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{JointDraw, MechanismSpec, simulate};

fn main() {
    divan::main();
}

fn arm_tracks() -> Tracks {
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

fn discover(tracks: &Tracks) -> Model {
    Pipeline::from_config(&PipelineConfig::default())
        .expect("pipeline")
        .run(tracks)
        .expect("discover")
        .model
}

#[divan::bench(sample_count = 10)]
fn discover_9_joints_80_points_150_frames(bencher: divan::Bencher) {
    let tracks = arm_tracks();
    bencher.bench_local(|| discover(divan::black_box(&tracks)));
}

#[divan::bench(sample_count = 20)]
fn fit_model_positions_9_joints_80_points_150_frames(bencher: divan::Bencher) {
    let tracks = arm_tracks();
    let model = discover(&tracks);
    bencher
        .with_inputs(|| model.clone())
        .bench_local_values(|mut m| {
            kinetree_structure::fit_model_positions(&mut m, divan::black_box(&tracks))
        });
}
