//! Arms of slender rods, whose keypoints lie nearly on a line: each rod is posed though its
//! points spread across it by about the noise, and every joint is found.

use kinetree_core::Model;
use kinetree_eval::evaluate;
use kinetree_pipeline::PipelineConfig;
use kinetree_pipeline::config::PoseConfig;
use kinetree_synth::{SlenderArmParams, SynthData, simulate, slender_arm};

fn arm(seed: u64, planar: bool) -> SynthData {
    simulate(&slender_arm(&SlenderArmParams {
        seed,
        planar,
        ..SlenderArmParams::default()
    }))
    .expect("simulate")
}

fn discover_with(data: &SynthData, config: &PipelineConfig) -> Model {
    kinetree_pipeline::Pipeline::from_config(config)
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover")
        .model
}

/// Rods of 4 mm at 1 mm of noise: the keypoints spread across a rod by about 1.2 mm RMS.
#[test]
fn arms_of_four_millimetre_rods_get_their_joints() {
    for (planar, least) in [(true, 9), (false, 9)] {
        let mut exact = 0;
        for seed in 0..10 {
            let data = arm(seed, planar);
            let e = evaluate(&kinetree_tests::discover_default(&data.tracks), &data.truth);
            exact += usize::from(e.joints_exact);
        }
        assert!(
            exact >= least,
            "planar {planar}: every joint right in {exact} of 10 arms"
        );
    }
}

/// A rod whose frames all spread across it by under the noise level is posed only with the
/// slender bodies' lower bound; with the general bound it gets no pose and is lost.
#[test]
fn a_rod_collinear_within_the_noise_is_posed() {
    let data = arm(6, true);
    let e = evaluate(&kinetree_tests::discover_default(&data.tracks), &data.truth);
    assert!(e.joints_exact, "{:?}", e.joints);
    let mut strict = PipelineConfig::default();
    let PoseConfig::Kabsch(p) = &mut strict.pose;
    p.slender_min_spread_in_sigma = p.min_spread_in_sigma;
    let e = evaluate(&discover_with(&data, &strict), &data.truth);
    assert!(
        e.n_bodies_found < data.truth.n_bodies(),
        "{} bodies found with the general bound",
        e.n_bodies_found
    );
}

/// Two rods in line whose joint turns about an axis near their common direction: their
/// keypoints' distances change by about the noise, so the clustering makes one body of both.
/// Cut along its axis, the halves fit far better and every joint is found; without the cut the
/// rods stay one body.
#[test]
fn rods_in_line_that_bend_at_a_joint_are_cut_along_their_axis() {
    let data = arm(4, false);
    let e = evaluate(&kinetree_tests::discover_default(&data.tracks), &data.truth);
    assert!(e.joints_exact, "{:?}", e.joints);
    assert_eq!(e.n_bodies_found, data.truth.n_bodies());
    let mut uncut = PipelineConfig::default();
    uncut.repairs.split.axis_cut_aspect = 0.0;
    let e = evaluate(&discover_with(&data, &uncut), &data.truth);
    assert!(
        e.n_bodies_found < data.truth.n_bodies(),
        "{} bodies found without the cut",
        e.n_bodies_found
    );
}
