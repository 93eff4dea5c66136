//! Discovery time: the whole pipeline on a 9-joint arm with 80 keypoints over 150 frames (the
//! observer benchmark's arm), and its last stage alone (`fit_model_positions`: the whole-tree
//! fit of every frame, the freeing of joints it cannot follow and the bundle adjustment of
//! the joints). Fixed seed. Run with `cargo bench -p kinetree-pipeline --bench discovery`.

mod common;

use common::arm_tracks;
use kinetree_core::{Model, Tracks};
use kinetree_pipeline::{Pipeline, PipelineConfig};

fn main() {
    divan::main();
}

fn discover_with(config: &PipelineConfig, tracks: &Tracks) -> Model {
    Pipeline::from_config(config)
        .expect("pipeline")
        .run(tracks)
        .expect("discover")
        .model
}

fn discover(tracks: &Tracks) -> Model {
    discover_with(&PipelineConfig::default(), tracks)
}

/// The tracks of a random mechanism simulated from `params`.
fn random_tracks(params: kinetree_synth::RandomParams) -> Tracks {
    kinetree_synth::simulate(&kinetree_synth::random_scenario(&params))
        .expect("simulate")
        .tracks
}

#[divan::bench(sample_count = 10)]
fn discover_9_joints_80_points_150_frames(bencher: divan::Bencher) {
    let tracks = arm_tracks();
    bencher.bench_local(|| discover(divan::black_box(&tracks)));
}

/// The same without the Gauss-Newton steps of the reference shapes (`shape_steps = 0`), for
/// their cost.
#[divan::bench(sample_count = 10)]
fn discover_without_shape_steps_9_joints_80_points_150_frames(bencher: divan::Bencher) {
    let tracks = arm_tracks();
    let config = PipelineConfig {
        pose: kinetree_pipeline::config::PoseConfig::Kabsch(kinetree_pose::KabschParams {
            shape_steps: 0,
            ..Default::default()
        }),
        ..PipelineConfig::default()
    };
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

/// A 10-joint tree of box links that hide each other (the mechanisms sweep's revolute tree,
/// seed 7, 110 keypoints, 200 frames at 1 mm): three links get 108-174 frames each from
/// their hinges, and every joint is found only with them. With and without the hinges, for
/// their cost.
#[divan::bench(args = [true, false], sample_count = 5)]
fn discover_hidden_links_10_joints_110_points_200_frames(bencher: divan::Bencher, hinged: bool) {
    let tracks = random_tracks(kinetree_synth::RandomParams {
        n_joints: 10,
        prismatic_fraction: 0.0,
        tree: true,
        seed: 7,
        ..Default::default()
    });
    let config = PipelineConfig::default().with_hinges(hinged);
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

/// A 21-body tree (20 joints, 8 keypoints per link, 200 frames, 1 mm, 10 % dropout, seed 3:
/// the slowest of the noise test's scenes at 1 mm), where the whole-tree fits and their
/// bundle adjustments dominate.
#[divan::bench(sample_count = 3)]
fn discover_tree_20_joints_168_points_200_frames(bencher: divan::Bencher) {
    let tracks = random_tracks(kinetree_synth::RandomParams {
        n_joints: 20,
        extra_points: 0,
        tree: true,
        noise_sigma_m: 0.001,
        dropout: 0.1,
        seed: 3,
        ..Default::default()
    });
    bencher.bench_local(|| discover(divan::black_box(&tracks)));
}

/// 20-body trees of 8 keypoints a link over 300 frames (1 mm, 10 % dropout; the links hide
/// about two thirds of the observations), by seed: 3 comes out exact; 0 gets 4 of its 19
/// joints wrong, next to links seen by few keypoints at a time, and the repairs try them again
/// in every pass.
#[divan::bench(args = [3, 0], sample_count = 3)]
fn discover_tree_19_joints_160_points_300_frames(bencher: divan::Bencher, seed: u64) {
    let tracks = tree_19_joints_160_points_300_frames(seed);
    bencher.bench_local(|| discover(divan::black_box(&tracks)));
}

/// The same without the memo of pair tests and hinge fits (`runner.memo_mib = 0`): what the
/// later passes' repeated work costs.
#[divan::bench(args = [3, 0], sample_count = 3)]
fn discover_tree_19_joints_160_points_300_frames_memo_off(bencher: divan::Bencher, seed: u64) {
    let tracks = tree_19_joints_160_points_300_frames(seed);
    let mut config = PipelineConfig::default();
    config.runner.memo_mib = 0;
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

fn tree_19_joints_160_points_300_frames(seed: u64) -> Tracks {
    random_tracks(kinetree_synth::RandomParams {
        n_joints: 19,
        extra_points: 0,
        tree: true,
        n_frames: 300,
        noise_sigma_m: 0.001,
        dropout: 0.1,
        seed,
        ..Default::default()
    })
}

#[divan::bench(sample_count = 20)]
fn fit_model_positions_9_joints_80_points_150_frames(bencher: divan::Bencher) {
    let tracks = arm_tracks();
    let model = discover(&tracks);
    bencher
        .with_inputs(|| model.clone())
        .bench_local_values(|mut m| {
            kinetree_fit::fit_model_positions(&mut m, divan::black_box(&tracks))
        });
}

/// Long recordings: one revolute joint over 20 000 frames, 1 mm, sigma given (seed 1), where
/// the pair tests' reference frame (a medoid of the relative rotations over every frame)
/// used to cost time quadratic in the frames.
#[divan::bench(sample_count = 3)]
fn discover_hinge_1_joint_20000_frames(bencher: divan::Bencher) {
    let tracks = random_tracks(kinetree_synth::RandomParams {
        n_joints: 1,
        prismatic_fraction: 0.0,
        n_frames: 20_000,
        seed: 1,
        ..Default::default()
    });
    let config = PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    };
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

/// The scale scenario ([`kinetree_synth::scale_scenario`]: a static base and four links
/// R-R-P-R, `n` keypoints split evenly over the five bodies, 15 % occluded, 1 mm), sigma
/// given, seed 0.
fn scale_tracks(n_points: usize, n_frames: usize) -> Tracks {
    let scenario = kinetree_synth::scale_scenario(&kinetree_synth::ScaleParams {
        n_points,
        n_frames,
        ..Default::default()
    });
    kinetree_synth::simulate(&scenario)
        .expect("simulate")
        .tracks
}

fn sigma_given() -> PipelineConfig {
    PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    }
}

/// The scale scenario at N = T = 1000, where speed targets are set.
#[divan::bench(sample_count = 5)]
fn discover_rrpr_1000_points_1000_frames(bencher: divan::Bencher) {
    let tracks = scale_tracks(1000, 1000);
    let config = sigma_given();
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

/// The scale scenario against the number of keypoints, over 1000 frames; beyond 500 the
/// default pipeline discovers on a sample of 500 and assigns the rest (dense tracks).
#[divan::bench(args = [250, 500, 2000, 5000, 20000], sample_count = 2)]
fn discover_rrpr_points_1000_frames(bencher: divan::Bencher, n_points: usize) {
    let tracks = scale_tracks(n_points, 1000);
    let config = sigma_given();
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

/// Many points over many frames: the scale scenario at N = 5000, T = 10 000 (1.2 GB of
/// tracks), discovered on the default sample of 500 points and the rest assigned. One sample
/// of about 20 s; its peak memory is in `docs/benchmarks.md`.
#[divan::bench(sample_count = 1)]
fn discover_rrpr_5000_points_10000_frames(bencher: divan::Bencher) {
    let tracks = scale_tracks(5000, 10_000);
    let config = sigma_given();
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

/// The scale scenario against the number of frames, with 1000 keypoints.
#[divan::bench(args = [250, 500, 2000, 4000], sample_count = 3)]
fn discover_rrpr_1000_points_frames(bencher: divan::Bencher, n_frames: usize) {
    let tracks = scale_tracks(1000, n_frames);
    let config = sigma_given();
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}

/// The scale scenario at N = T = 1000 discovered on a sample of `max_points` points
/// (`[pipeline.sampling]`), the rest assigned to its bodies; 1000 runs on every point.
#[divan::bench(args = [300, 500, 1000], sample_count = 5)]
fn discover_rrpr_1000_points_1000_frames_sampled(bencher: divan::Bencher, max_points: usize) {
    let tracks = scale_tracks(1000, 1000);
    let mut config = sigma_given();
    config.sampling.max_points = max_points;
    bencher.bench_local(|| discover_with(&config, divan::black_box(&tracks)));
}
