//! Structure cases issue 4 names: joints past one full turn, a body hidden in frame 0, a
//! 3 cm finger-like prismatic joint, a body with three children.

use kinetree_eval::evaluate;
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{Mechanism, Scenario, SynthData, Trajectory, simulate};
use kinetree_tests::build::{base, body, joint, scenario, sine};
use kinetree_tests::rate_draw;

/// Base, an 8-point link on a revolute joint (points 8-15), and a second 8-point link
/// (points 16-23) on a revolute or prismatic joint.
fn two_links(second_revolute: bool) -> Mechanism {
    Mechanism {
        bodies: vec![
            base(),
            body([0.15, 0.0, 0.1], [0.15, 0.04, 0.04], 8),
            body([0.3, 0.15, 0.1], [0.04, 0.15, 0.04], 8),
        ],
        joints: vec![
            joint(0, 1, true, [0.0, 0.0, 1.0], [0.0, 0.0, 0.05]),
            joint(1, 2, second_revolute, [0.0, 1.0, 0.2], [0.3, 0.0, 0.1]),
        ],
    }
}

fn discover(s: &Scenario) -> (kinetree_core::Model, kinetree_eval::Evaluation) {
    discover_data(&simulate(s).expect("simulate"))
}

fn discover_data(data: &SynthData) -> (kinetree_core::Model, kinetree_eval::Evaluation) {
    discover_hinged(data, true)
}

/// The default pipeline's model of `data`, with the hinges on or off, and its evaluation.
fn discover_hinged(
    data: &SynthData,
    hinged_bodies: bool,
) -> (kinetree_core::Model, kinetree_eval::Evaluation) {
    // Every point of a hinge's axis is a centre the link turns about: the ball repairs pose
    // such links too, so "without" turns both off.
    let cfg = PipelineConfig::default()
        .with_hinges(hinged_bodies)
        .with_balls(hinged_bodies);
    let model = Pipeline::from_config(&cfg)
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover")
        .model;
    let e = evaluate(&model, &data.truth);
    (model, e)
}

/// Asserts that `point` and `mate` share a true body and that the model put both on one
/// body.
fn assert_placed_with(model: &kinetree_core::Model, data: &SynthData, point: usize, mate: usize) {
    assert_eq!(data.truth.point_body[point], data.truth.point_body[mate]);
    let (b, m) = (model.point_body[point], model.point_body[mate]);
    assert!(
        b >= 0 && b == m,
        "point {point} on {b}, point {mate} on {m}"
    );
}

/// Hides point `i` in frame `t` wherever `hide(t, i)`.
fn hide(data: &mut SynthData, hide: impl Fn(usize, usize) -> bool) {
    let frames: Vec<Vec<Option<kinetree_core::nalgebra::Point3<f64>>>> =
        (0..data.tracks.n_frames())
            .map(|t| {
                (0..data.tracks.n_points())
                    .map(|i| {
                        if hide(t, i) {
                            None
                        } else {
                            data.tracks.get(t, i)
                        }
                    })
                    .collect()
            })
            .collect();
    data.tracks = kinetree_core::Tracks::from_points(&frames).expect("tracks");
}

/// The joint whose child holds point `point`.
fn joint_with_child_point(m: &kinetree_core::Model, point: usize) -> &kinetree_core::model::Joint {
    m.joints
        .iter()
        .find(|j| m.bodies[j.child].points.contains(&point))
        .expect("joint")
}

#[test]
fn revolute_turning_more_than_one_full_turn_is_unwrapped() {
    // Constant torque from rest to 11 rad (1.75 turns), as the paper arm's link 1 but further.
    let mechanism = Mechanism {
        bodies: vec![base(), body([0.15, 0.0, 0.1], [0.15, 0.04, 0.04], 8)],
        joints: vec![joint(0, 1, true, [0.0, 0.3, 1.0], [0.0, 0.0, 0.05])],
    };
    let s = scenario(
        mechanism,
        vec![Trajectory::Quadratic { final_value: 11.0 }],
        0.001,
    );
    let (m, e) = discover(&s);
    assert!(e.joints_exact, "{e:?}");
    let j = &e.joints[0];
    assert!(j.axis_error_deg.is_some_and(|a| a < 1.0), "{j:?}");
    assert!(j.position_rms.is_some_and(|r| r < 0.02), "{j:?}");
    let range = m.joints[0].range.expect("range");
    assert!(
        (range[1] - range[0] - 11.0).abs() < 0.1,
        "unwrapped range {range:?}"
    );
}

#[test]
fn a_body_hidden_in_frame_zero_still_gets_its_joint() {
    let mechanism = two_links(false);
    let s = scenario(
        mechanism,
        vec![sine(0.8, 0.25, 0.3), sine(0.08, 0.45, 1.0)],
        0.001,
    );
    let mut data = simulate(&s).expect("simulate");
    // Hide body 2 (points 16-23) in the first 15 frames.
    hide(&mut data, |t, i| t < 15 && i >= 16);
    let (m, e) = discover_data(&data);
    assert!(e.structure_exact, "{e:?}");
    let j = joint_with_child_point(&m, 16);
    assert!(
        j.positions[..15].iter().all(Option::is_none),
        "no position while hidden"
    );
    assert!(j.reference_frame >= 15);
    assert!(e.joints[1].position_rms.is_some_and(|r| r < 0.003), "{e:?}");
}

/// A joint's reference frame (where its positions are zero and its camera-frame axis is
/// given) is a frame where the parent's pose is precise, not simply the first frame: here the
/// parent shows only three of its eight points in frame 0.
#[test]
fn the_reference_frame_avoids_a_poorly_seen_parent() {
    let mechanism = two_links(true);
    let s = scenario(
        mechanism,
        vec![sine(0.8, 0.25, 0.3), sine(0.7, 0.45, 1.0)],
        0.002,
    );
    let mut data = simulate(&s).expect("simulate");
    // Body 1 is points 8-15, body 2 points 16-23: frame 0 keeps three of body 1's points (and
    // enough of body 2's for a pose).
    let seen = |range: std::ops::Range<usize>| -> Vec<usize> {
        range.filter(|&i| data.tracks.is_visible(0, i)).collect()
    };
    assert!(seen(16..24).len() >= 3, "body 2 has a pose in frame 0");
    let keep: Vec<usize> = seen(8..16).into_iter().take(3).collect();
    assert_eq!(keep.len(), 3);
    hide(&mut data, |t, i| {
        t == 0 && (8..16).contains(&i) && !keep.contains(&i)
    });
    let (m, e) = discover_data(&data);
    assert!(e.structure_exact, "{e:?}");
    let j = joint_with_child_point(&m, 16);
    assert_ne!(j.reference_frame, 0, "frame 0 has three parent points");
    assert_eq!(j.positions[j.reference_frame], Some(0.0));
}

#[test]
fn a_three_centimetre_finger_slide_is_prismatic() {
    // A gripper: a palm turning on the base and a finger sliding 3 cm (1.5 cm amplitude).
    let mechanism = Mechanism {
        bodies: vec![
            base(),
            body([0.1, 0.0, 0.08], [0.08, 0.06, 0.03], 8),
            body([0.2, 0.03, 0.08], [0.03, 0.01, 0.01], 6),
        ],
        joints: vec![
            joint(0, 1, true, [0.0, 0.0, 1.0], [0.0, 0.0, 0.05]),
            joint(1, 2, false, [0.0, 1.0, 0.0], [0.2, 0.0, 0.08]),
        ],
    };
    let s = scenario(
        mechanism,
        vec![sine(0.7, 0.2, 0.0), sine(0.015, 0.55, 0.5)],
        0.0005,
    );
    let (_, e) = discover(&s);
    assert!(e.joints_exact, "{e:?}");
    let finger = &e.joints[1];
    assert!(finger.axis_error_deg.is_some_and(|a| a < 3.0), "{finger:?}");
    assert!(finger.position_rms.is_some_and(|r| r < 0.001), "{finger:?}");
}

#[test]
fn a_body_with_three_children_is_a_tree() {
    // A hand: a palm on a wrist joint, three fingers turning on the palm.
    let mechanism = Mechanism {
        bodies: vec![
            base(),
            body([0.0, 0.0, 0.15], [0.08, 0.08, 0.1], 8),
            body([-0.06, 0.0, 0.35], [0.015, 0.015, 0.08], 6),
            body([0.0, 0.0, 0.35], [0.015, 0.015, 0.08], 6),
            body([0.06, 0.0, 0.35], [0.015, 0.015, 0.08], 6),
        ],
        joints: vec![
            joint(0, 1, true, [0.0, 0.0, 1.0], [0.0, 0.0, 0.05]),
            joint(1, 2, true, [1.0, 0.0, 0.0], [-0.06, 0.0, 0.26]),
            joint(1, 3, true, [1.0, 0.2, 0.0], [0.0, 0.0, 0.26]),
            joint(1, 4, true, [1.0, -0.2, 0.0], [0.06, 0.0, 0.26]),
        ],
    };
    let s = scenario(
        mechanism,
        vec![
            sine(0.6, 0.15, 0.0),
            sine(0.7, 0.35, 0.4),
            sine(0.7, 0.55, 1.1),
            sine(0.7, 0.75, 2.0),
        ],
        0.001,
    );
    let (m, e) = discover(&s);
    assert!(e.joints_exact, "{e:?}");
    let palm = m.joints[0].child;
    assert_eq!(
        m.joints.iter().filter(|j| j.parent == palm).count(),
        3,
        "three fingers on the palm"
    );
    assert!(m.chain.is_none(), "a tree is not a chain");
}

/// A slender link turning about its own long axis: its rotation is poorly known about that
/// axis (its points lie within 2 cm of it), so the rotation test's slack can hide a 0.5 rad
/// swing and the arc of its centroid looks like a line. Every seed must give a revolute
/// joint, not a prismatic one (with the slack alone the chi-square tester called seed 1
/// prismatic; the hidden-rotation rule, `kinetree_dof::hidden_next_rank`, makes the rotation
/// stand out against the measured noise level).
#[test]
fn a_slender_link_turning_about_its_length_is_revolute() {
    use kinetree_synth::{JointDraw, MechanismSpec};
    for seed in 0..12 {
        let spec = MechanismSpec {
            joints: vec![JointDraw {
                parent_pick: 0.0,
                revolute: true,
                axis: [1.0, 0.1, 0.05],
                size_m: 0.16,
                n_points: 5,
                amplitude: 0.05,
                phase: 0.3,
            }],
            tree: false,
            noise_sigma_m: 0.0035,
            dropout: 0.1,
            seed,
        };
        let (model, e) = discover(&spec.scenario());
        let types: Vec<&str> = model.joints.iter().map(|j| j.joint_type.as_str()).collect();
        assert!(e.joints_exact, "seed {seed}: joints {types:?}");
    }
}

/// A hinge below a 3 cm, four-point slider: the slider's own poses are noisy and missing in
/// many frames, and the tester's axis and pivot inherit that noise (pivots 1.5-5 cm off on
/// these seeds). Refined with the slider posed by the whole-tree fit, every pivot is within
/// 1 cm of the true axis line in the slider's frame and every axis within 2.5 deg.
#[test]
fn a_hinge_below_a_small_slider_gets_its_axis_from_the_tree_fit() {
    use kinetree_synth::{JointDraw, MechanismSpec};
    let mut checked = 0;
    for seed in 0..16 {
        let spec = MechanismSpec {
            joints: vec![
                JointDraw {
                    parent_pick: 0.0,
                    revolute: false,
                    axis: [0.7, -0.5, -0.4],
                    size_m: 0.03,
                    n_points: 4,
                    amplitude: 0.5,
                    phase: 0.0,
                },
                JointDraw {
                    parent_pick: 0.0,
                    revolute: true,
                    axis: [-0.6, -0.5, -0.6],
                    size_m: 0.25,
                    n_points: 7,
                    amplitude: 0.3,
                    phase: 1.0,
                },
            ],
            tree: false,
            noise_sigma_m: 0.001,
            dropout: 0.3,
            seed,
        };
        let (_, e) = discover(&spec.scenario());
        if !e.joints_exact {
            continue;
        }
        checked += 1;
        let hinge = &e.joints[1];
        let axis = hinge.axis_error_in_parent_deg.expect("axis");
        let pivot = hinge.pivot_error_in_parent_m.expect("pivot");
        assert!(axis < 2.5, "seed {seed}: axis {axis} deg");
        assert!(pivot < 0.01, "seed {seed}: pivot {pivot} m");
    }
    assert!(checked >= 14, "{checked} of 16 seeds structurally exact");
}

/// The default pipeline on a drawn mechanism, its model's warnings, and the true joints it
/// gets wrong (not found or wrongly typed).
fn wrong_joints(spec: &kinetree_synth::MechanismSpec) -> (Vec<kinetree_core::Warning>, Vec<usize>) {
    wrong_joints_with(spec, &PipelineConfig::default())
}

/// [`wrong_joints`] with the pipeline of `config`.
fn wrong_joints_with(
    spec: &kinetree_synth::MechanismSpec,
    config: &PipelineConfig,
) -> (Vec<kinetree_core::Warning>, Vec<usize>) {
    let (model, wrong) = model_and_wrong_joints(spec, config);
    (model.warnings, wrong)
}

/// The model `config` discovers on `spec`'s data, and [`wrong_joints`].
fn model_and_wrong_joints(
    spec: &kinetree_synth::MechanismSpec,
    config: &PipelineConfig,
) -> (kinetree_core::Model, Vec<usize>) {
    let data = simulate(&spec.scenario()).expect("simulate");
    let d = Pipeline::from_config(config)
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover");
    let e = evaluate(&d.model, &data.truth);
    let wrong = e
        .joints
        .iter()
        .enumerate()
        .filter(|(_, j)| !(j.found && j.type_ok))
        .map(|(k, _)| k)
        .collect();
    (d.model, wrong)
}

/// Whether `type_by_fit` typed a joint in the discovery of `model` (its trace): the
/// `joint_typed_by_fit` warning goes when `retest` rebuilds the model from the fitted poses.
fn typed_by_fit(model: &kinetree_core::Model) -> bool {
    model
        .trace
        .iter()
        .any(|t| t.repair == "type_by_fit" && t.outcome == "applied")
}

/// Three mechanisms of the rate test's deterministic draw (1.1-2.6 mm of noise, 15-37 %
/// occlusion) where a slide can be typed multi-DoF: its parent, a 10-30 cm body of 5 points
/// with a third of its frames unposed, bends the child's straight path by its pose errors
/// (with averaged reference shapes alone, one child's translation missed a line at chi2/dof
/// 5.4 against a bound of 4.0; off the line by 14 mm RMS with per-body poses, 1.6 mm with
/// the whole-tree fit's). Tested again on the fitted poses, every joint comes out with its
/// type (a `pairs_retested` warning). With the reference shapes refined by Gauss-Newton
/// steps, that one's parent is posed well enough for the first pair tests (no retest
/// needed), and with the rotation test's hidden-hinge rule (`dof.hidden_hinge_ratio`) the
/// first pair tests type another right; the third needs the retest.
#[test]
fn a_slide_bent_by_a_poorly_posed_parent_is_retested_on_the_fitted_poses() {
    let specs = rate_draw(458);
    for (case, needs_retest) in [(159, true), (287, false), (457, false)] {
        let (warnings, wrong) = wrong_joints(&specs[case]);
        assert!(wrong.is_empty(), "case {case}: wrong joints {wrong:?}");
        let retested = warnings
            .iter()
            .any(|w| matches!(w, kinetree_core::Warning::PairsRetested { .. }));
        assert!(retested || !needs_retest, "case {case}: no retest");
    }
}

/// A mechanism of the rate test's draw at 4 mm of noise and 29 % occlusion: a 31 cm, 6-point
/// link turning +-0.24 rad about a hinge on the base. Its pair test found one rotation
/// direction but centres of rotation off a point by 4.45 per degree of freedom against a
/// bound of 3.33 (rank 1), so the joint was multi-DoF. In the whole-tree fit the child moves
/// as a hinge: a hinge fitted from the fitted relative poses and refined misses the child's
/// points by 1.0 sigma^2 per point beyond its own pose (a slide, 36), so the fit types it
/// revolute (`joint_typed_by_fit`).
///
/// Another (2 mm, 33 %): a 3.9 cm link turning +-0.19 rad on the base showed no rotation in
/// its pair test (rotation noise of its 6 points) and a nearly straight path, so it was typed
/// prismatic, and the fit did not follow it (36 sigma^2 per point). Tried as a hinge by the
/// fit, it is followed; the model's tree is then retested on the fitted poses and every joint
/// comes out right (the trace names both repairs; the rebuilt model has no `joint_typed_by_fit`
/// warning). That link and its sibling turn about nearly one anchor on the base, so the two make a
/// universal pair (fit ratio 0.99); with universal edges at the default cost (`tree.universal_cost`
/// 2.5) the tree hangs the link on its sibling by it, so this case prices them as ball joints (4,
/// `docs/decisions.md`, `tree.universal_cost`).
#[test]
fn hinges_the_pair_test_mistyped_are_typed_by_the_fit() {
    let specs = rate_draw(549);
    let (_, wrong) = wrong_joints(&specs[548]);
    assert!(wrong.is_empty(), "case 548: wrong joints {wrong:?}");
    let mut balls = PipelineConfig::default();
    balls.tree.universal_cost = 4.0;
    let (model, wrong) = model_and_wrong_joints(&specs[536], &balls);
    assert!(wrong.is_empty(), "wrong joints {wrong:?}");
    assert!(
        typed_by_fit(&model),
        "no joint typed by the fit: {:?}",
        model.trace
    );
    // Without the retest the hinge typed by the fit is the model's own.
    let mut kept = balls.clone();
    kept.repairs.retest.enabled = false;
    let (warnings, wrong) = wrong_joints_with(&specs[536], &kept);
    assert!(wrong.is_empty(), "wrong joints {wrong:?}");
    assert!(
        warnings.iter().any(|w| matches!(
            w,
            kinetree_core::Warning::JointTypedByFit { joint_type, .. } if *joint_type == kinetree_core::model::JointType::Revolute
        )),
        "no joint typed by the fit: {warnings:?}"
    );
    // A candidate over `max_excess_to_adjust` before its bundle adjustment is dropped: with
    // the bound at zero no candidate is kept, and (without the retest) the hinge stays
    // multi-DoF. So is one over `max_local_excess` after the adjustment of the joints next
    // to it.
    let mut strict = kept.clone();
    strict.repairs.type_by_fit.max_excess_to_adjust = 0.0;
    let mut screened = kept.clone();
    screened.repairs.type_by_fit.max_local_excess = 0.0;
    for config in [strict, screened] {
        let (model, wrong) = model_and_wrong_joints(&specs[536], &config);
        assert!(!wrong.is_empty(), "every joint right without the typing");
        assert!(!typed_by_fit(&model), "{:?}", model.trace);
    }
}

/// A slide of the rate test's draw whose parent is a 2 cm body of 4 points. Its rotation
/// residuals were 0.12 at rank 0 and 0.003 at rank 1 (whitened columns of nearly one
/// direction), and on the ratio alone the hidden-rotation rule types the slide revolute.
/// With rank 0 required over the nominal noise (`kinetree_dof::MIN_EXCESS`) it is
/// prismatic.
#[test]
fn a_slide_under_a_two_centimetre_parent_stays_prismatic() {
    let specs = rate_draw(398);
    let (_, wrong) = wrong_joints(&specs[397]);
    assert!(wrong.is_empty(), "wrong joints {wrong:?}");
}

/// Eight mechanisms of the rate test's draw at 1 mm of noise and 30 % occlusion whose axes
/// came out 1.02-3.97 deg off in the parent's frame when each joint was refined on its own
/// child's points against the whole-tree fit's poses (a prismatic chain through a 2.4 cm link:
/// 1.52 deg where the true parent poses give 0.02). Bundle-adjusted with every frame's
/// configuration, every axis of all eight is within 1 deg.
#[test]
fn bundle_adjusted_axes_are_within_a_degree() {
    let specs = rate_draw(139);
    let mut worst: f64 = 0.0;
    for case in [3, 15, 33, 68, 72, 100, 136, 138] {
        let mut spec = specs[case].clone();
        spec.noise_sigma_m = 0.001;
        spec.dropout = 0.3;
        let data = simulate(&spec.scenario()).expect("simulate");
        let (_, e) = discover_data(&data);
        assert!(e.joints_exact, "case {case}: joints not exact");
        for j in &e.joints {
            let axis = j.axis_error_in_parent_deg.expect("axis");
            assert!(
                axis < 1.0,
                "case {case} joint {}: axis {axis:.2} deg",
                j.joint
            );
            worst = worst.max(axis);
        }
    }
    eprintln!("largest axis error {worst:.2} deg");
}

/// Seven-joint revolute trees of the mechanisms sweep (seeds 5 and 7; seed 1 is one too when
/// the tree does not weigh its edges by the frames they were tested over): siblings turn about
/// one anchor on the base and hide each other, so one link is registered in 21 of 200 frames.
/// Over the ten frames it shared with each sibling, their relative motion passed for a hinge
/// with a better fit ratio than the siblings' true joints with the base over a hundred, and
/// the tree hung them on it; the fit freed those joints, but the tree stayed. Tested again on
/// the whole-tree fit's poses, which pose the hidden link through its own joint in most
/// frames (with their precision), every joint is found. (With the hidden link posed through
/// its hinge where it lacks poses, seed 5 needs no retest: the retest is checked with the
/// hinge and ball repairs off, and the default must get every joint too.) On seed 7 the siblings' hinges with
/// the base and the brief hinge between them pass the tree's tie rule (three hinges, the
/// base's pair fitting about as well), which hangs the link on the base before any retest.
#[test]
fn siblings_hidden_by_each_other_get_their_parent_back() {
    for (seed, retested) in [(5, true), (7, false)] {
        let data = kinetree_tests::revolute_tree(7, seed);
        let (model, e) = discover_hinged(&data, false);
        assert!(e.joints_exact, "seed {seed}: joints not exact");
        assert_eq!(
            kinetree_tests::warned(&model, |w| matches!(
                w,
                kinetree_core::Warning::PairsRetested { .. }
            )),
            retested,
            "seed {seed}: retest"
        );
        let (_, e) = discover_hinged(&data, true);
        assert!(
            e.joints_exact,
            "seed {seed}: joints not exact with the hinges"
        );
    }
}

/// Seed 0 of the same sweep row: a link posed in 110 of 200 frames has a revolute test with
/// the base over all 110 (fit ratio 0.26) and one with a sibling over the 23 frames both are
/// posed in (0.13, with the same residual per degree of freedom: the bound of a short test is
/// wider). Weighed by the share of frames each test missed, the tree takes the base.
#[test]
fn a_joint_tested_over_more_frames_wins_over_a_brief_one() {
    let data = kinetree_tests::revolute_tree(7, 0);
    let (_, e) = discover_data(&data);
    let wrong: Vec<usize> = e
        .joints
        .iter()
        .filter(|j| !(j.found && j.type_ok))
        .map(|j| j.joint)
        .collect();
    assert!(wrong.is_empty(), "wrong joints {wrong:?}");
}

/// Mechanisms sweep, 3-joint revolute tree, seed 0: two links turn on the base about axes
/// 3 deg apart through one anchor, so the second link also moves nearly as a hinge on the
/// first. The two edges into it tie (costs 1.1665 and 1.1670) and the tree took the wrong
/// one; fitted whole, the tree without it re-predicts the keypoints at 1.61 sigma against
/// 1.78, so it replaces the model and every joint is found.
#[test]
fn a_near_tied_parent_is_chosen_by_the_whole_tree_fit() {
    let data = kinetree_tests::revolute_tree(3, 0);
    let model = kinetree_tests::discover_default(&data.tracks);
    let e = evaluate(&model, &data.truth);
    assert!(e.joints_exact, "{:?}", e.joints);
}

/// Mechanisms sweep, 5-joint revolute tree, seed 14: the hub link carrying three children
/// never shows three keypoints at once (two, keypoints 11 and 15), so it has no pose and
/// its children looked multi-DoF on the base. Posed through its hinge (on the camera: the
/// base is static), it takes its place in the tree and every joint is found. Without the
/// hinge and ball steps, the link is read from two children's universal joint and its third
/// child moved onto it (`[pipeline.unseen_links] hubs` and `rehang`); without those too, the
/// joints are not found.
#[test]
fn a_hub_link_seen_two_keypoints_at_a_time_gets_its_joints() {
    let data = kinetree_tests::revolute_tree(5, 14);
    let (model, e) = discover_hinged(&data, true);
    assert!(e.joints_exact && e.ari > 1.0 - 1e-9, "{:?}", e.joints);
    assert!(kinetree_tests::warned(&model, |w| matches!(
        w,
        kinetree_core::Warning::BodyPosedThroughHinge { points, .. } if points == &[11, 15]
    )));
    let (model, read) = discover_hinged(&data, false);
    assert!(read.joints_exact, "{:?}", read.joints);
    assert!(kinetree_tests::warned(&model, |w| matches!(
        w,
        kinetree_core::Warning::UnseenLink { offset_m, .. } if *offset_m == 0.0
    )));
    let mut cfg = PipelineConfig::default()
        .with_hinges(false)
        .with_balls(false);
    cfg.unseen_links.hubs = false;
    cfg.unseen_links.rehang = false;
    let without = kinetree_tests::discover_with(&data.tracks, &cfg);
    assert!(
        !evaluate(&without, &data.truth).joints_exact,
        "found without the hinge, ball and hub steps"
    );
}

/// Mechanisms sweep, 7-joint revolute tree, seed 3: links 2 and 3 show three keypoints at
/// once in 32 and 81 of 200 frames; registered in those alone, their keypoints were mixed
/// into each other's bodies and three joints were missed. Posed through their hinges where
/// they lack poses of their own, every body and joint is found. (Without the hinge steps the
/// tree's preference for near pairs now finds them too.)
#[test]
fn links_registered_in_few_frames_are_posed_through_their_hinges() {
    let data = kinetree_tests::revolute_tree(7, 3);
    let (model, e) = discover_hinged(&data, true);
    assert!(e.joints_exact, "{:?}", e.joints);
    // A body with poses of its own had frames filled through a hinge on another body.
    assert!(kinetree_tests::warned(&model, |w| matches!(
        w,
        kinetree_core::Warning::BodyPosedThroughHinge { points, frames, .. }
            if model.bodies.iter().any(|b| &b.points == points && b.frames_registered > *frames)
    )));
}

/// A random 5-joint tree (30 % prismatic, seed 11): keypoint 15 of body 1, seen in 34 of 200
/// frames, is clustered onto a body posed through its hinge, whose turn it does not follow.
/// Taken off the hinge (a `points_off_hinge` warning), it goes back to body 1 and every joint
/// is right.
#[test]
fn a_keypoint_that_does_not_turn_with_its_bodys_hinge_is_taken_off() {
    let data = kinetree_tests::random_tree(5, 0.3, 11);
    let (model, e) = discover_data(&data);
    assert!(kinetree_tests::warned(&model, |w| matches!(
        w,
        kinetree_core::Warning::PointsOffHinge { points } if points.contains(&15)
    )));
    assert!(e.joints_exact, "{:?}", e.joints);
    assert_eq!(data.truth.point_body[15], 1);
    assert_placed_with(&model, &data, 15, 8);
}

/// A random 10-joint tree (30 % prismatic, seed 5): keypoint 23 of body 2, seen in 29 of
/// 200 frames, is clustered onto a body whose fitted motion it misses by more than the bound
/// allows while no other body's explains it either. Left on no body (a `points_unassigned`
/// warning), it joins body 2 in the next pass and every joint is found.
#[test]
fn a_keypoint_fitting_no_body_leaves_the_one_it_was_put_on() {
    let data = kinetree_tests::random_tree(10, 0.3, 5);
    let (model, e) = discover_data(&data);
    assert!(e.joints_exact, "{:?}", e.joints);
    assert!(kinetree_tests::warned(&model, |w| matches!(
        w,
        kinetree_core::Warning::PointsUnassigned { points } if points.contains(&23)
    )));
    assert_eq!(data.truth.point_body[23], 2);
    assert_placed_with(&model, &data, 23, 19);
}

/// Mechanisms sweep, 5-joint tree with half its joints prismatic, seed 19: splitting a
/// mixed body left a body of three keypoints, two of the base (3 and 5) and one of link 5
/// (50), which the model's fit poses through a joint to follow the base keypoints. The
/// link's keypoint fits that fitted motion at `chi^2 / k` 4.7 (over five times the body's
/// median, 0.9) and its own link's at 1.4, but a body of three keypoints could lose none.
/// Moved off as an outlier, it joins its link; the two base keypoints, a body no more, are
/// attached to the base, and every joint is found.
#[test]
fn an_outlier_leaves_a_body_of_three_keypoints() {
    let data = kinetree_tests::random_tree(5, 0.5, 19);
    let (model, e) = discover_data(&data);
    assert!(e.joints_exact, "{:?}", e.joints);
    assert!(kinetree_tests::warned(&model, |w| matches!(
        w,
        kinetree_core::Warning::PointsReassigned { points } if points == &[50]
    )));
    assert_placed_with(&model, &data, 50, 49);
    assert_eq!((data.truth.point_body[3], data.truth.point_body[5]), (0, 0));
    assert_placed_with(&model, &data, 3, 5);
    assert_placed_with(&model, &data, 3, 1);
}

/// A mechanism of the rate test's draw (8-joint chain, 1.5 mm of noise, 34 % occlusion):
/// keypoint 16 of link 2, near the hinge joining it to the 4-keypoint slider below, was
/// clustered onto the slider. Seen three keypoints at a time, the slider's poses followed
/// it, so it fitted them better than its own link's and the model's moves kept it there; the
/// slider's joint had a rotation (multi-DoF). Without it the pair test finds one slide
/// (without any other keypoint of the two bodies, still two DoF): it is left on no body, and
/// the next pass's fitted motions put it on its link.
#[test]
fn a_keypoint_that_gives_a_slide_a_rotation_leaves_it() {
    let spec = kinetree_tests::rate_draw(84).pop().expect("case 83");
    let data = simulate(&spec.scenario()).expect("simulate");
    let (model, e) = discover_data(&data);
    assert!(e.joints_exact, "{:?}", e.joints);
    assert!(kinetree_tests::warned(&model, |w| matches!(
        w,
        kinetree_core::Warning::PointsMakingJointsMultiDof { points } if points == &[16]
    )));
    assert_placed_with(&model, &data, 16, 12);
}
