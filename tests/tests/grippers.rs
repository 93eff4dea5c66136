//! Exact ties in the tree: a gripper's two fingers move relative to each other by a joint of
//! the same type as their joints with the hand, so the data fit them as siblings and as a
//! chain; the tree hangs both on the hand.

use kinetree_core::{Model, Warning};
use kinetree_eval::{body_map, evaluate};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{GripperKind, GripperParams, SynthData, gripper_scenario, simulate};

/// The true names of the fingers' parents in `model`.
fn fingers_parents(model: &Model, data: &SynthData) -> Vec<String> {
    let map = body_map(model, &data.truth);
    let names = |b: usize| data.truth.mechanism.bodies[map[b]].name.clone();
    model
        .joints
        .iter()
        .filter(|j| names(j.child).starts_with("finger"))
        .map(|j| names(j.parent))
        .collect()
}

/// Draws whose pair tests leave the second finger on the first: the grandparent's pair fits
/// 0.5-0.6 worse in fit ratio than the parent's, beyond the spanning tree's margin, although
/// the fingers share one rail or one pin. With `sibling_ties` the whole-tree fit hangs both on
/// the hand (the chain and the siblings fit within a small fraction of a noise variance per
/// frame of each other); without it they stay chained, so the draws exercise the repair.
#[test]
fn fingers_chained_by_scattered_pair_fits_hang_on_the_hand() {
    let draws = [
        GripperParams {
            gripper: GripperKind::Parallel,
            arm_joints: 3,
            noise_sigma_m: 0.00023,
            dropout: 0.144,
            seed: 109,
            ..GripperParams::default()
        },
        GripperParams {
            gripper: GripperKind::Angular,
            arm_joints: 3,
            noise_sigma_m: 0.0008208563509288292,
            dropout: 0.13154360329775128,
            seed: 14049863939353054014,
            ..GripperParams::default()
        },
    ];
    for params in draws {
        let data = simulate(&gripper_scenario(&params)).expect("simulate");
        let mut off = PipelineConfig::default();
        off.repairs.sibling_ties.enabled = false;
        for (config, on) in [(PipelineConfig::default(), true), (off, false)] {
            let model = Pipeline::from_config(&config)
                .expect("pipeline")
                .run(&data.tracks)
                .expect("discover")
                .model;
            let parents = fingers_parents(&model, &data);
            let kept = model
                .trace
                .iter()
                .any(|t| t.repair == "sibling_ties" && t.outcome == "kept");
            assert_eq!(kept, on, "{params:?}: sibling_ties {on}, trace");
            if on {
                assert_eq!(parents, ["hand", "hand"], "{params:?}");
            } else {
                assert!(
                    parents.iter().any(|p| p.starts_with("finger")),
                    "{params:?}"
                );
            }
        }
    }
}

/// Parallel (sliding) and angular (one pin) grippers on an arm, 1 mm of noise: in every draw
/// both fingers hang on the hand, and at least 9 of 10 draws of each kind have every joint
/// found with its type.
#[test]
fn both_fingers_of_a_gripper_hang_on_the_hand() {
    for gripper in [GripperKind::Parallel, GripperKind::Angular] {
        let mut exact = 0;
        let draws = 10;
        for seed in 0..draws {
            let data = simulate(&gripper_scenario(&GripperParams {
                gripper,
                seed,
                ..GripperParams::default()
            }))
            .expect("simulate");
            let model = Pipeline::from_config(&PipelineConfig::default())
                .expect("pipeline")
                .run(&data.tracks)
                .expect("discover")
                .model;
            assert_eq!(
                fingers_parents(&model, &data),
                ["hand", "hand"],
                "{gripper:?} seed {seed}: the fingers' parents"
            );
            exact += usize::from(evaluate(&model, &data.truth).joints_exact);
        }
        assert!(
            exact * 10 >= draws as usize * 9,
            "{gripper:?}: {exact} of {draws} exact"
        );
    }
}

/// A link on the base and a second link on it, turning through one anchor about axes 5 deg
/// apart: all three pairs pass as hinges, so the second link is a candidate for the
/// grandparent, but hanging it there costs 26-36 noise variances per frame of the whole-tree
/// fit. The chain stays with the defaults; with the cost bound lifted the proposal is made
/// and does not stand (the finished model re-predicts about 20 % worse).
#[test]
fn serial_hinges_a_few_degrees_apart_stay_a_chain() {
    for seed in [0, 1] {
        let data = kinetree_tests::build::two_links_on_one_anchor(5.0, true, seed);
        let run = |max_cost_per_frame: f64| {
            let mut c = PipelineConfig::default();
            c.repairs.sibling_ties.max_cost_per_frame = max_cost_per_frame;
            let m = Pipeline::from_config(&c)
                .expect("pipeline")
                .run(&data.tracks)
                .expect("discover")
                .model;
            let outcomes: Vec<String> = m
                .trace
                .iter()
                .filter(|e| e.repair == "sibling_ties")
                .map(|e| e.outcome.clone())
                .collect();
            (evaluate(&m, &data.truth).joints_exact, outcomes)
        };
        let defaults = PipelineConfig::default().repairs.sibling_ties;
        assert_eq!(
            run(defaults.max_cost_per_frame),
            (true, vec![]),
            "seed {seed}"
        );
        assert_eq!(
            run(1e6),
            (true, vec!["discarded".to_string()]),
            "seed {seed}"
        );
    }
}

/// Grippers at 3 mm whose fingers move a few noise levels against the hand: a finger tests
/// rigid with the hand (parallel seed 2: it slides +-5 mm; seed 0: both fingers do; angular
/// seed 17: it turns on the pin), while the fingers test as their joint with each other, so
/// the spanning tree hangs one finger on the other. With `sibling_ties.quiet_siblings` (and the pair test's `hidden_slide_ratio`
/// off, which sees the parallel fingers' slides itself) both hang on the hand by the joint
/// their pairs share (the trace keeps the rule's tree), each with its type; a model whose last pass
/// still needed the rule names the joints it typed so with `joint_typed_by_sibling` warnings
/// (a later pass, with points moved, can test the fingers' joints plainly). Without the rule a
/// finger stays on its sibling.
#[test]
fn a_finger_too_quiet_to_test_hangs_beside_its_sibling() {
    let mut warned = 0;
    for (gripper, seed) in [
        (GripperKind::Parallel, 2),
        (GripperKind::Parallel, 0),
        (GripperKind::Angular, 17),
    ] {
        let params = GripperParams {
            gripper,
            noise_sigma_m: 0.003,
            seed,
            ..GripperParams::default()
        };
        let data = simulate(&gripper_scenario(&params)).expect("simulate");
        // The pair test's own rule for slides it hides is off, so that the repair alone acts.
        let on = PipelineConfig {
            dof: kinetree_pipeline::config::DofConfig::Chi2Rank(kinetree_dof::Chi2RankParams {
                hidden_slide_ratio: 0.0,
                ..kinetree_dof::Chi2RankParams::default()
            }),
            ..PipelineConfig::default()
        };
        let mut off = on.clone();
        off.repairs.sibling_ties.quiet_siblings = false;
        for (config, on) in [(on, true), (off, false)] {
            let model = kinetree_tests::discover_with(&data.tracks, &config);
            let parents = fingers_parents(&model, &data);
            let map = body_map(&model, &data.truth);
            let name = |b: usize| data.truth.mechanism.bodies[map[b]].name.clone();
            let typed: Vec<(String, String)> = model
                .warnings
                .iter()
                .filter_map(|w| match w {
                    Warning::JointTypedBySibling { parent, child, .. } => {
                        Some((name(*parent), name(*child)))
                    }
                    _ => None,
                })
                .collect();
            if on {
                assert_eq!(parents, ["hand", "hand"], "{gripper:?} seed {seed}");
                let report = evaluate(&model, &data.truth);
                assert!(report.joints_exact, "{gripper:?} seed {seed}: {report:?}");
                assert!(
                    model
                        .trace
                        .iter()
                        .any(|t| t.repair == "sibling_ties" && t.outcome == "kept"),
                    "{gripper:?} seed {seed}: the rule's tree is not in the trace"
                );
                assert!(
                    typed
                        .iter()
                        .all(|(p, c)| p == "hand" && c.starts_with("finger")),
                    "{gripper:?} seed {seed}: {typed:?}"
                );
                warned += typed.len();
            } else {
                assert!(
                    parents.iter().any(|p| p.starts_with("finger")),
                    "{gripper:?} seed {seed}: {parents:?} without the rule"
                );
                assert!(typed.is_empty(), "{gripper:?} seed {seed}: {typed:?}");
            }
        }
    }
    assert!(warned > 0, "no joint typed by its sibling in any draw");
}

/// Two bodies that test rigid with a third are no quiet siblings unless they move along the
/// joint by more than their fitted position's precision and by less than their pair test
/// would see. In two trees of the mechanisms sweep (3 hinges, seed 9; 5 slides, seed 17), the
/// first model's pairs include a rigid verdict over the few frames two bodies were posed
/// together, beside bodies that move against each other by one joint; hung there, the body
/// spreads 25-160 of its precision along that joint. With the spread bounds the draws come
/// out exact; without them the quiet rule takes that tree and a body is lost or split.
#[test]
fn a_rigid_verdict_the_fit_contradicts_makes_no_quiet_sibling() {
    for (n_joints, prismatic_fraction, seed) in [(3, 0.0, 9), (5, 1.0, 17)] {
        let data = simulate(&kinetree_synth::random_scenario(
            &kinetree_synth::RandomParams {
                n_joints,
                prismatic_fraction,
                tree: true,
                seed,
                ..kinetree_synth::RandomParams::default()
            },
        ))
        .expect("simulate");
        let mut unbounded = PipelineConfig::default();
        unbounded.repairs.sibling_ties.quiet_min_spread_in_std = 0.0;
        unbounded.repairs.sibling_ties.quiet_max_spread_in_std = 1e6;
        for (config, bounded) in [(PipelineConfig::default(), true), (unbounded, false)] {
            let model = kinetree_tests::discover_with(&data.tracks, &config);
            let report = evaluate(&model, &data.truth);
            assert_eq!(
                report.structure_exact, bounded,
                "{n_joints} joints, seed {seed}, bounded {bounded}: {report:?}"
            );
        }
    }
}

/// A parallel gripper at 3 mm (seed 18) whose hand the clustering does not keep apart from
/// its neighbours: a slide of 1-2 cm leaves the distances across its direction nearly
/// constant, and the halves of a merged body by the pairwise measure mix the two. Cut by the
/// points' profiles against every other keypoint, the halves fit better than the union: the
/// split makes the hand a body and both fingers hang on it. Without the profile cut the hand
/// is lost and a finger hangs on the other.
#[test]
fn a_hand_merged_with_a_sliding_finger_is_split_by_profile() {
    let params = GripperParams {
        gripper: GripperKind::Parallel,
        noise_sigma_m: 0.003,
        seed: 18,
        ..GripperParams::default()
    };
    let data = simulate(&gripper_scenario(&params)).expect("simulate");
    let parents = |profile_max_points: usize| {
        let mut c = PipelineConfig::default();
        c.repairs.split.profile_max_points = profile_max_points;
        let model = Pipeline::from_config(&c)
            .expect("pipeline")
            .run(&data.tracks)
            .expect("discover")
            .model;
        fingers_parents(&model, &data)
    };
    let defaults = PipelineConfig::default().repairs.split;
    assert_eq!(parents(defaults.profile_max_points), ["hand", "hand"]);
    assert!(parents(0).iter().any(|p| p.starts_with("finger")));
}

/// A hand merged with one finger of a parallel gripper (3 mm of noise): the merged body's poses
/// turn by a degree or two with the other finger's 1 cm slide, and that rotation stands out
/// against the measured noise level (the `chi2_rank` hidden-hinge rule's ratio). Taken as a
/// hinge, it would make the fingers' pair a hinge about a far axis (the arc that mimics the
/// slide), and the merged body would stay unsplit. The rule's least angle keeps that hinge
/// out: the hand is split off and both fingers hang on it. With no least angle, the hand is
/// lost.
#[test]
fn a_slide_seen_through_a_merged_body_is_no_hidden_hinge() {
    let params = GripperParams {
        gripper: GripperKind::Parallel,
        noise_sigma_m: 0.003,
        seed: 6,
        ..GripperParams::default()
    };
    let data = simulate(&gripper_scenario(&params)).expect("simulate");
    let discover = |min_angle_deg: f64| {
        let c = PipelineConfig {
            dof: kinetree_pipeline::config::DofConfig::Chi2Rank(kinetree_dof::Chi2RankParams {
                hidden_hinge_min_angle_deg: min_angle_deg,
                ..kinetree_dof::Chi2RankParams::default()
            }),
            ..PipelineConfig::default()
        };
        Pipeline::from_config(&c)
            .expect("pipeline")
            .run(&data.tracks)
            .expect("discover")
            .model
    };
    let bounded = discover(kinetree_dof::Chi2RankParams::default().hidden_hinge_min_angle_deg);
    assert_eq!(fingers_parents(&bounded, &data), ["hand", "hand"]);
    let lifted = discover(0.0);
    assert!(
        !fingers_parents(&lifted, &data).contains(&"hand".to_string()),
        "{:?}",
        fingers_parents(&lifted, &data)
    );
}
