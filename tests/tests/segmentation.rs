//! Body segmentation with every clusterer: random mechanisms of 2-12 bodies at 1 mm noise and
//! 30 % occlusion, and the hard cases (a 3-point body, a body that barely moves, a 2 cm
//! prismatic stroke).
//!
//! Scored with the adjusted Rand index over the points some method could place: a point whose
//! track fits another body's *true* motion within noise (near a joint axis, for example) has
//! no identifiable owner and is left out (`kinetree_eval::ambiguous_points`); the plain ARI is
//! checked too, more loosely.

use kinetree_eval::{ambiguous_points, evaluate, identifiable_ari};
use kinetree_pipeline::config::ClusteringConfig;
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{JointDraw, MechanismSpec, Scenario, Trajectory, simulate, strategies};
use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::TestRunner;

fn clusterers() -> Vec<(&'static str, ClusteringConfig)> {
    vec![
        (
            "hierarchical",
            ClusteringConfig::Hierarchical(Default::default()),
        ),
        ("dbscan", ClusteringConfig::Dbscan(Default::default())),
        ("spectral", ClusteringConfig::Spectral(Default::default())),
        (
            "spectral_gmm",
            ClusteringConfig::SpectralGmm(Default::default()),
        ),
        (
            "spectral_dbscan",
            ClusteringConfig::SpectralDbscan(Default::default()),
        ),
    ]
}

/// `(identifiable ARI, plain ARI, bodies found)` of the default pipeline with `clustering`.
fn score(scenario: &Scenario, clustering: &ClusteringConfig) -> (f64, f64, usize) {
    let data = simulate(scenario).expect("simulate");
    let cfg = PipelineConfig {
        clustering: clustering.clone(),
        ..PipelineConfig::default()
    };
    let d = Pipeline::from_config(&cfg)
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover");
    let amb = ambiguous_points(&data.tracks, &data.truth, scenario.noise_sigma_m);
    let e = evaluate(&d.model, &data.truth);
    (
        identifiable_ari(&d.model, &data.truth, &amb),
        e.ari,
        d.model.bodies.len(),
    )
}

/// The first `n` mechanisms of a deterministic draw: 1-11 joints (2-12 bodies), chains and
/// trees, 1 mm noise, 30 % occlusion.
fn random_mechanisms(n: usize) -> Vec<MechanismSpec> {
    random_mechanisms_of(1..=11, n)
}

/// The first `n` mechanisms of a deterministic draw of `joints` joints, chains and trees,
/// 1 mm noise, 30 % occlusion.
fn random_mechanisms_of(joints: std::ops::RangeInclusive<usize>, n: usize) -> Vec<MechanismSpec> {
    let mut runner = TestRunner::deterministic();
    let strategy = strategies::mechanism(joints, proptest::bool::ANY).prop_map(|mut s| {
        s.noise_sigma_m = 0.001;
        s.dropout = 0.3;
        s
    });
    (0..n)
        .map(|_| strategy.new_tree(&mut runner).expect("draw").current())
        .collect()
}

/// Measured on the first 600 of this draw (release build): identifiable ARI = 1 on
/// 599 / 599 / 598 (hierarchical / spectral / DBSCAN), 200 of the first 200 each. The
/// misses: with every clusterer, a 2 cm body turning 0.3 deg on its parent, merged with it;
/// with DBSCAN, a few points of one more mechanism. On the 30 used here: 30 each (DBSCAN 28
/// without `regroup_leftovers`, where a 4-6 point body breaks into fragments of 1-2 points).
/// The bound leaves room for one miss each; the worst case must still be close
/// (identifiable ARI above 0.85: a few points, not a body).
#[test]
fn every_clusterer_segments_random_mechanisms() {
    let specs = random_mechanisms(30);
    for (name, c) in clusterers() {
        let mut exact = 0;
        let mut failures = Vec::new();
        for (k, spec) in specs.iter().enumerate() {
            let (ari, plain, found) = score(&spec.scenario(), &c);
            if ari > 1.0 - 1e-12 {
                exact += 1;
            } else {
                failures.push((k, spec.joints.len() + 1, found, ari, plain));
            }
            assert!(
                ari > 0.85,
                "{name}: case {k} ({} bodies) ARI {ari}",
                spec.joints.len() + 1
            );
        }
        let need = 29;
        assert!(
            exact >= need,
            "{name}: ARI = 1 on {exact}/30 (need {need}); (case, bodies, found, ARI, plain): {failures:?}"
        );
    }
}

/// Issue 3 asks for mechanisms of up to 25 bodies: the same setting with 19-24 joints.
/// Measured on the first 100 of this draw (release build): identifiable ARI = 1 on
/// 99 / 99 / 98 (hierarchical / spectral / DBSCAN; plain ARI 96 / 96 / 95). The misses: with
/// every clusterer, one mechanism's keypoint near a joint axis on the child (its distances
/// to the child's keypoints vary by 1.3-1.4 mm, as rigid ones do); with DBSCAN also two
/// keypoints of a 4-keypoint link turning little on its parent, in the parent's
/// neighbourhood. The first 40 at 40 % occlusion: 40 of 40 each; at the draw's own noise
/// (0-5 mm) and occlusion (0-40 %): 40 / 40 / 39. On the 8 used here: 8 of 8.
#[test]
fn every_clusterer_segments_mechanisms_of_twenty_to_twenty_five_bodies() {
    let specs = random_mechanisms_of(19..=24, 8);
    for (name, c) in clusterers() {
        for (k, spec) in specs.iter().enumerate() {
            let (ari, plain, found) = score(&spec.scenario(), &c);
            assert!(
                ari > 1.0 - 1e-12,
                "{name}: case {k} ({} bodies, found {found}): identifiable ARI {ari}, plain {plain}",
                spec.joints.len() + 1
            );
        }
    }
}

/// A mechanism of the draw of 20-25 bodies whose 4-keypoint slider (keypoints 88-91) the
/// pairwise measure breaks into two pairs, both too small to be bodies. One pair fits the
/// poorly determined poses of a small 4-keypoint link and is attached to it; the split takes
/// it off again (residual 29 sigma), and an attachment free to put it back did so eight
/// times over, the slider never found. The attachment may not remake a body a split undid:
/// the four keypoints, left on no body, move as one and become the slider.
#[test]
fn a_small_body_broken_into_pairs_is_made_whole() {
    let spec = random_mechanisms_of(19..=24, 80).pop().expect("case 79");
    let data = simulate(&spec.scenario()).expect("simulate");
    let slider = data.truth.point_body[88];
    let keypoints: Vec<usize> = (0..data.truth.point_body.len())
        .filter(|&i| data.truth.point_body[i] == slider)
        .collect();
    assert_eq!(keypoints, [88, 89, 90, 91]);
    for (name, c) in clusterers() {
        let (ari, plain, found) = score(&spec.scenario(), &c);
        assert_eq!(found, spec.joints.len() + 1, "{name}: {found} bodies");
        assert!(
            ari > 1.0 - 1e-12,
            "{name}: identifiable ARI {ari}, plain {plain}"
        );
    }
}

/// A 3-joint chain drawn once, to be made hard in one way at a time.
fn base_spec() -> MechanismSpec {
    let joint = |revolute: bool, axis: [f64; 3], size_m: f64, phase: f64| JointDraw {
        parent_pick: 0.0,
        revolute,
        axis,
        size_m,
        n_points: 6,
        amplitude: 0.5,
        phase,
    };
    MechanismSpec {
        joints: vec![
            joint(true, [0.2, 0.3, 1.0], 0.3, 0.0),
            joint(false, [1.0, -0.4, 0.3], 0.2, 1.0),
            joint(true, [-0.3, 1.0, 0.5], 0.15, 2.0),
        ],
        tree: false,
        noise_sigma_m: 0.001,
        dropout: 0.3,
        seed: 11,
    }
}

fn set_amplitude(s: &mut Scenario, joint: usize, value: f64) {
    if let Trajectory::Sine { amplitude, .. } = &mut s.trajectories[joint] {
        *amplitude = value;
    }
}

/// Each hard case on three seeds (noise, occlusion and keypoint placement), every clusterer.
///
/// The 5 deg swing is of the 30 cm first link (+-2.5 deg about its rest pose). Measured limit
/// (default pipeline): the 15 cm, 6-point last link with its keypoints close to
/// its axis is found on 0/5 seeds at +-2.5 deg and 2/5 at +-5 deg (4/5 with `log_p_value`);
/// its tip moves a few millimetres, near the noise. DBSCAN alone merges four of the swinging
/// link's points into the base (their cross pairs with it have `q` 0.77-0.88, many under the
/// cut, so the base's neighbourhoods take them in); the pipeline splits that body again because
/// its average-linkage halves are apart on average (`split_mixed_bodies`), and re-attaches the
/// link's other two points.
#[test]
fn hard_cases_with_every_clusterer() {
    for seed in [11, 12, 13] {
        let spec = MechanismSpec {
            seed,
            ..base_spec()
        };
        let mut three_points = spec.scenario();
        three_points.mechanism.bodies[3].interior_points = 3;
        let mut barely_moves = spec.scenario();
        set_amplitude(&mut barely_moves, 0, 2.5f64.to_radians());
        // Amplitude 1 cm: the slide travels 2 cm.
        let mut short_slide = spec.scenario();
        set_amplitude(&mut short_slide, 1, 0.01);
        for (case, scenario) in [
            ("a body of three points", three_points),
            ("a link that swings 5 deg", barely_moves),
            ("a 2 cm prismatic stroke", short_slide),
        ] {
            for (name, c) in clusterers() {
                let (ari, plain, found) = score(&scenario, &c);
                assert_eq!(found, 4, "{name}, {case}, seed {seed}: {found} bodies");
                assert!(
                    ari > 1.0 - 1e-12,
                    "{name}, {case}, seed {seed}: identifiable ARI {ari} (plain {plain})"
                );
            }
        }
    }
}

/// The shared tumbling body with 1 mm noise and a clean track.
fn one_tumbling_body(frames: usize) -> Vec<f64> {
    kinetree_tests::tumbling_body(frames, 0.001, 7, |_, _| Default::default()).0
}

#[test]
fn every_clusterer_on_one_body_and_a_point_seen_once() {
    use kinetree_core::{Tracks, Warning};
    let frames = 60;
    let one = Tracks::new(frames, 8, one_tumbling_body(frames)).expect("valid");
    // The same body plus a ninth point visible in frame 10 only.
    let mut xyz = Vec::new();
    let base = one_tumbling_body(frames);
    for t in 0..frames {
        xyz.extend_from_slice(&base[t * 24..(t + 1) * 24]);
        xyz.extend_from_slice(&if t == 10 {
            [0.3, 0.3, 1.5]
        } else {
            [f64::NAN; 3]
        });
    }
    let with_lone = Tracks::new(frames, 9, xyz).expect("valid");
    for (name, c) in clusterers() {
        let cfg = PipelineConfig {
            clustering: c,
            ..PipelineConfig::default()
        };
        let p = Pipeline::from_config(&cfg).expect("pipeline");
        let m = p.run(&one).expect("one body").model;
        assert_eq!(m.bodies.len(), 1, "{name}: {} bodies", m.bodies.len());
        assert!(m.joints.is_empty(), "{name}");
        assert!(
            m.point_body.iter().all(|&b| b == 0),
            "{name}: {:?}",
            m.point_body
        );
        let m = p.run(&with_lone).expect("one body and a lone point").model;
        assert_eq!(m.bodies.len(), 1, "{name}");
        assert_eq!(m.point_body[8], -1, "{name}: the lone point has no body");
        assert!(
            m.warnings
                .iter()
                .any(|w| matches!(w, Warning::PointUnpaired { point: 8 })),
            "{name}: {:?}",
            m.warnings
        );
    }
}

/// Every clusterer that can (not `spectral_dbscan`, which counts the bodies itself) takes a
/// number of bodies when told (`n_clusters`), on the dissimilarity
/// matrix of a simulated 4-body chain: the true count gives the true bodies, one fewer gives
/// one fewer body; DBSCAN names the counts it can reach when the asked one is impossible.
#[test]
fn every_clusterer_cuts_to_a_given_number_of_bodies() {
    use kinetree_clustering::{
        Dbscan, DbscanParams, Hierarchical, HierarchicalParams, Spectral, SpectralParams,
    };
    use kinetree_core::{Clustering, ClusteringInput};
    let mut spec = base_spec();
    spec.joints.truncate(3);
    let data = simulate(&spec.scenario()).expect("simulate");
    let d = Pipeline::from_config(&PipelineConfig::default())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover");
    let input = ClusteringInput {
        dissimilarity: &d.dissimilarity,
        seed: 1,
        pair_frames: None,
    };
    let with = |k: usize| -> Vec<(&str, Box<dyn Clustering>)> {
        vec![
            (
                "hierarchical",
                Box::new(
                    Hierarchical::new(HierarchicalParams {
                        n_clusters: Some(k),
                        ..Default::default()
                    })
                    .expect("params"),
                ),
            ),
            (
                "dbscan",
                Box::new(
                    Dbscan::new(DbscanParams {
                        n_clusters: Some(k),
                        ..Default::default()
                    })
                    .expect("params"),
                ),
            ),
            (
                "spectral",
                Box::new(
                    Spectral::new(SpectralParams {
                        n_clusters: Some(k),
                        ..Default::default()
                    })
                    .expect("params"),
                ),
            ),
            (
                "spectral_gmm",
                Box::new(
                    kinetree_clustering::SpectralGmm::new(kinetree_clustering::SpectralGmmParams {
                        embedding: kinetree_clustering::EmbeddingParams {
                            n_clusters: Some(k),
                            ..Default::default()
                        },
                        ..Default::default()
                    })
                    .expect("params"),
                ),
            ),
        ]
    };
    let truth: Vec<usize> = data.truth.point_body.clone();
    for (name, c) in with(4) {
        let seg = c.cluster(&input).expect("cluster");
        assert_eq!(seg.n_bodies(), 4, "{name}");
        let ari = kinetree_eval::adjusted_rand_index(&seg.labels_i64(), &truth);
        assert!(ari > 0.95, "{name}: ARI {ari}");
    }
    for (name, c) in with(3) {
        let seg = c.cluster(&input).expect("cluster");
        assert_eq!(seg.n_bodies(), 3, "{name}");
    }
    let impossible = Dbscan::new(DbscanParams {
        n_clusters: Some(40),
        ..Default::default()
    })
    .expect("params");
    let e = impossible
        .cluster(&input)
        .expect_err("40 clusters of 3+ points from 4 bodies");
    assert!(e.to_string().contains("40 clusters"), "{e}");
    assert!(
        DbscanParams {
            n_clusters: Some(0),
            ..Default::default()
        }
        .validate()
        .is_err()
    );
}

/// Seven mechanisms of the rate test's deterministic draw (`strategies::any_mechanism()`,
/// 0.3-4.8 mm of noise) where a point landed on a neighbouring body that it fits pairwise and
/// against per-body poses. The model's whole-tree fit tells the bodies apart, the point is
/// moved back (a `points_reassigned` warning) and every identifiable point ends on its body.
/// With `move_points` off, six of them had an identifiable ARI of 0.91-0.98.
#[test]
fn points_near_a_joint_axis_are_moved_by_the_model_fit() {
    let specs = kinetree_tests::rate_draw(173);
    let mut reassigned = 0;
    for case in [43, 49, 83, 88, 116, 165, 172] {
        let spec = &specs[case];
        let data = simulate(&spec.scenario()).expect("simulate");
        let d = Pipeline::from_config(&PipelineConfig::default())
            .expect("pipeline")
            .run(&data.tracks)
            .expect("discover");
        let amb = ambiguous_points(
            &data.tracks,
            &data.truth,
            spec.effective_noise_sigma_m().max(1e-6),
        );
        let ari = identifiable_ari(&d.model, &data.truth, &amb);
        assert!(ari > 1.0 - 1e-12, "case {case}: identifiable ARI {ari}");
        if d.model
            .warnings
            .iter()
            .any(|w| matches!(w, kinetree_core::Warning::PointsReassigned { .. }))
        {
            reassigned += 1;
        }
    }
    assert!(reassigned >= 6, "{reassigned} of 7 moved points");
}

/// A mechanism of the draw above: a 28 cm body of 4 points on a 6 cm slide, which average
/// linkage broke into fragments of 2, 1 and 1 points (each fragment's mean `q` to the rest over
/// the cut) and DBSCAN and spectral clustering lost in other ways. Its four points still move
/// as one rigid body, so the pipeline makes them one (an `unassigned_points_grouped`
/// warning) and every clusterer ends with every identifiable point on its body.
#[test]
fn a_small_body_the_clustering_breaks_apart_is_regrouped() {
    let spec = &random_mechanisms(105)[104];
    let scenario = spec.scenario();
    for (name, c) in clusterers() {
        let (ari, plain, found) = score(&scenario, &c);
        assert!(
            ari > 1.0 - 1e-12,
            "{name}: identifiable ARI {ari} (plain {plain}), {found} bodies"
        );
    }
    let data = simulate(&scenario).expect("simulate");
    let d = Pipeline::from_config(&PipelineConfig::default())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover");
    assert!(
        d.model
            .warnings
            .iter()
            .any(|w| matches!(w, kinetree_core::Warning::UnassignedPointsGrouped { .. })),
        "{:?}",
        d.model.warnings
    );
}

/// Seed 5 of the mechanisms sweep's 10-joint revolute trees: two links turning on the base
/// are seen poorly (each keypoint in 0-70 of 200 frames), and five of their points were left
/// on no body. Fitted as one body they had a median residual under the split threshold, since
/// most frames show only one link's points, and the made-up body became the parent of six
/// links. The pairwise measure keeps the two links' points apart, so they are not grouped;
/// every group made of leftover points is of one true body, and the links' joints with the
/// base are found (with the made-up body, joint 0 was missing).
#[test]
fn leftover_points_of_two_links_are_not_made_one_body() {
    let data = kinetree_tests::revolute_tree(10, 5);
    let model = kinetree_tests::discover_default(&data.tracks);
    let truth = &data.truth;
    let groups: Vec<&Vec<usize>> = model
        .warnings
        .iter()
        .filter_map(|w| match w {
            kinetree_core::Warning::UnassignedPointsGrouped { groups } => Some(groups),
            _ => None,
        })
        .flatten()
        .collect();
    for g in &groups {
        let first = truth.point_body[g[0]];
        assert!(
            g.iter().all(|&p| truth.point_body[p] == first),
            "group {g:?} mixes bodies {:?}",
            g.iter().map(|&p| truth.point_body[p]).collect::<Vec<_>>()
        );
    }
    let e = kinetree_eval::evaluate(&model, truth);
    for k in [0, 1] {
        assert!(
            e.joints[k].found && e.joints[k].type_ok,
            "joint {k}: {:?}",
            e.joints[k]
        );
    }
}

/// The default pipeline's model of a drawn mechanism and its identifiable ARI.
fn drawn_model(spec: &MechanismSpec) -> (kinetree_core::Model, f64) {
    let data = simulate(&spec.scenario()).expect("simulate");
    let model = kinetree_tests::discover_default(&data.tracks);
    let amb = ambiguous_points(&data.tracks, &data.truth, spec.effective_noise_sigma_m());
    let ari = identifiable_ari(&model, &data.truth, &amb);
    (model, ari)
}

/// Two mechanisms of the rate test's draw (1.3-1.9 mm of noise, 14-34 % occlusion) where one
/// point seen in 76-125 frames was left unassigned: the attachment takes a point only when
/// exactly one body's per-body poses fit it within a wide bound, and these fitted two.
/// Against the whole-tree fit's motions one body explains each clearly best, and it gets the
/// point: identifiable ARI 1 on both (0.981-0.990 with the attachment alone). (With the
/// noise level pooled from the pairs inside bodies, a third such mechanism comes out with
/// identifiable ARI 1 and no move.)
#[test]
fn an_unassigned_point_goes_to_the_body_whose_fitted_motion_explains_it() {
    segmented_with_moved_points(&kinetree_tests::rate_draw(487), &[218, 486]);
}

/// Asserts that the default pipeline segments each of `cases` of `specs` with identifiable
/// ARI 1 and that the fitted motions moved or placed some point on the way.
fn segmented_with_moved_points(specs: &[MechanismSpec], cases: &[usize]) {
    for &case in cases {
        let (model, ari) = drawn_model(&specs[case]);
        assert!(ari > 1.0 - 1e-12, "case {case}: identifiable ARI {ari}");
        assert!(
            kinetree_tests::warned(&model, |w| matches!(
                w,
                kinetree_core::Warning::PointsReassigned { .. }
            )),
            "case {case}: no point moved or placed by the fitted motions"
        );
    }
}

/// A mechanism of the rate test's draw (2 mm of noise, 32 % occlusion): a 3.9 cm, 6-point
/// slider and the 18.5 cm link turning on it by +-0.65 rad came out as one body, whose points
/// fitted at a median 1.5 sigma (the residual split needs 2.5) with halves the pairwise
/// measure did not keep apart. Posed as two bodies, the halves lower the squared residual by
/// about three times what two poses per frame buy, and the body is split: three bodies,
/// identifiable ARI 1.
#[test]
fn a_small_slider_merged_with_its_link_is_split_by_the_fit_of_its_halves() {
    let (model, ari) = drawn_model(&kinetree_tests::rate_draw(179)[178]);
    assert_eq!(model.bodies.len(), 3, "bodies");
    assert!(ari > 1.0 - 1e-12, "identifiable ARI {ari}");
    assert!(
        kinetree_tests::warned(&model, |w| matches!(
            w,
            kinetree_core::Warning::BodySplit { .. }
        )),
        "no split"
    );
}

/// The guard on that split: in a 3-joint revolute tree of the mechanisms sweep (seed 10), a
/// point of another link seen in 17 of 200 frames sits in a body registered in 116 frames.
/// Its halves fit far better over those 17 frames, but average linkage put two of the body's
/// own points in the point's half; judged on under a quarter of the body's frames, the body is
/// not split, and the fitted motions move the point home (ARI 1, four bodies).
#[test]
fn a_point_seen_in_a_few_frames_does_not_split_its_body() {
    let data = kinetree_tests::revolute_tree(3, 10);
    let model = kinetree_tests::discover_default(&data.tracks);
    let e = evaluate(&model, &data.truth);
    assert_eq!(model.bodies.len(), 4, "bodies");
    assert!(e.ari > 1.0 - 1e-12, "ARI {}", e.ari);
}

/// A mechanism of this file's random draw (12 bodies): the split of a 6.4 cm slider merged
/// with the link turning on it put two points of each in one 4-point half, which then fitted
/// at a median of 1.79; the moves take no point from a body fitted worse than 1.5, nor leave
/// one under three points. Points of a body a split made, fitted that poorly, may leave for
/// well fitted bodies (`FittedMotions::points_leaving_mixed_bodies`): the two left over are
/// dropped and placed again, and every clusterer reaches identifiable ARI 1 (0.945 without
/// it).
#[test]
fn a_split_body_mixing_two_links_gives_its_points_back() {
    let spec = &random_mechanisms(375)[374];
    for (name, c) in clusterers() {
        let (ari, _, _) = score(&spec.scenario(), &c);
        assert!(ari > 1.0 - 1e-12, "{name}: identifiable ARI {ari}");
    }
}

/// Two mechanisms of this file's random draw (12 and 10 bodies): a point near a hinge, seen
/// in 91 and 116 frames, was put on the link across the hinge. Against the fitted motions
/// its true body explains it better by 35 and 41 in `chi^2` (0.13 and 0.12 per degree of
/// freedom), short of the two standard deviations of `chi^2` (46 and 53) that the rule of
/// deviations alone asks; a gain of `MIN_CHI2_GAIN` (16) moves it whatever its number of
/// frames, and both reach identifiable ARI 1 (0.969 and 0.978 with that rule alone).
#[test]
fn a_point_near_a_hinge_goes_to_the_body_it_fits_better() {
    segmented_with_moved_points(&random_mechanisms(451), &[331, 450]);
}

/// Seed 7 of the mechanisms sweep's 1-joint revolute chains (200 frames, 1 mm): point 17 of
/// the link, seen in 48 frames near the hinge, was clustered with the base. Against the
/// fitted motions the link explains it better by 24 in `chi^2` (0.94 against 1.11 per
/// degree of freedom over 141), under the 34 of two standard deviations and a bound of 25
/// (five deviations of the worst case); with `MIN_CHI2_GAIN` at 16 it moves to the link.
/// (Point 10, seen in 15 frames, fits both within 0.12 and stays where it is.)
#[test]
fn a_link_point_seen_near_its_hinge_leaves_the_base() {
    let data = simulate(&kinetree_synth::random_scenario(
        &kinetree_synth::RandomParams {
            n_joints: 1,
            prismatic_fraction: 0.0,
            seed: 7,
            ..Default::default()
        },
    ))
    .expect("simulate");
    let model = kinetree_tests::discover_default(&data.tracks);
    let link = model.point_body[17];
    let truth = &data.truth.point_body;
    let link_points: Vec<usize> = (0..truth.len())
        .filter(|&i| truth[i] == truth[17] && data.truth.visible_frames[i] >= 48)
        .collect();
    assert!(link_points.len() >= 4, "link points {link_points:?}");
    for i in link_points {
        assert_eq!(model.point_body[i], link, "point {i} apart from point 17");
    }
    let base = (0..truth.len())
        .find(|&i| truth[i] != truth[17] && data.truth.visible_frames[i] >= 100)
        .expect("a base point");
    assert_ne!(
        model.point_body[base], link,
        "the link merged with the base"
    );
}

/// Seed 3 of the mechanisms sweep's 5-joint revolute trees (200 frames, 1 mm): point 32, seen
/// in 8 frames, was clustered with the link its own link turns on. It fits its own link at
/// 0.69 per degree of freedom and the other at 1.80; the fitted motions judge points seen in
/// 5 frames or more (`MIN_FRAMES_TO_PLACE`), so it moves, and every point seen twice or more
/// is on its body (ARI 0.942 with a minimum of 10 frames).
#[test]
fn a_point_seen_in_eight_frames_is_moved_to_its_link() {
    let data = kinetree_tests::revolute_tree(5, 3);
    let model = kinetree_tests::discover_default(&data.tracks);
    let e = evaluate(&model, &data.truth);
    assert!(e.ari > 1.0 - 1e-12, "ARI {}", e.ari);
}
