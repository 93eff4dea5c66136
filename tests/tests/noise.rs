//! The noise estimate against the simulator's truth, including crowded scenes where under
//! 5 % of the pairs are rigid.

use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{RandomParams, random_scenario, simulate};

#[test]
fn noise_estimate_within_ten_percent_from_a_tenth_to_ten_millimetres() {
    let pipeline = Pipeline::from_config(&PipelineConfig::default()).expect("pipeline");
    // 4 bodies with 10 points each; 21 bodies with 8 points each (about 4 % rigid pairs).
    for (joints, extra) in [(3usize, 2usize), (20, 0)] {
        for noise in [0.0001, 0.001, 0.003, 0.01] {
            for seed in [1, 3] {
                let p = RandomParams {
                    n_joints: joints,
                    extra_points: extra,
                    tree: joints > 5,
                    noise_sigma_m: noise,
                    dropout: 0.1,
                    seed,
                    ..RandomParams::default()
                };
                let data = simulate(&random_scenario(&p)).expect("simulate");
                let sigma = pipeline.run(&data.tracks).expect("run").model.noise.sigma_m;
                let err = sigma / noise - 1.0;
                assert!(
                    err.abs() < 0.1,
                    "{joints} joints, {noise} m, seed {seed}: {sigma} ({err:+.3})"
                );
            }
        }
    }
}
