//! Skeletons with a clinical marker set (`SkeletonParams::clinical_markers`): four markers on
//! the pelvis, torso and head, two on each limb segment, and two on each elbow's and knee's
//! axis (carried by the upper arm or thigh, rigid with the forearm or shank too) and on each
//! wrist's and ankle's first axis (carried by the forearm or shank). The pelvis floats.

use kinetree_core::Model;
use kinetree_core::model::JointType;
use kinetree_eval::body_map;
use kinetree_pipeline::PipelineConfig;
use kinetree_synth::{SkeletonParams, SynthData, simulate, skeleton_scenario};

fn clinical(seed: u64, soft_tissue_m: f64) -> SynthData {
    simulate(&skeleton_scenario(&SkeletonParams {
        seed,
        clinical_markers: true,
        floating_pelvis: true,
        soft_tissue_m,
        ..SkeletonParams::default()
    }))
    .expect("simulate")
}

fn discover(data: &SynthData, cfg: &PipelineConfig) -> Model {
    kinetree_tests::discover_with(&data.tracks, cfg)
}

/// Per true joint whose two segments are both bodies of `model`: whether a joint of the
/// model joins them, and whether its type is the truth's (a ball may come out universal, or
/// revolute with a `joint_not_identifiable` warning naming the ball).
fn judged_edges(model: &Model, data: &SynthData) -> Vec<(String, bool, bool)> {
    let map = body_map(model, &data.truth);
    let mech = &data.truth.mechanism;
    let body_of = |segment: usize| map.iter().position(|&t| t == segment);
    mech.joints
        .iter()
        .filter_map(|spec| {
            let (p, c) = (body_of(spec.parent)?, body_of(spec.child)?);
            let name = mech.bodies[spec.child].name.clone();
            let joint = model
                .joints
                .iter()
                .find(|j| (j.parent, j.child) == (p, c) || (j.parent, j.child) == (c, p));
            let typed = joint.is_some_and(|j| match spec.joint_type {
                kinetree_synth::JointType::Revolute => j.joint_type == JointType::Revolute,
                kinetree_synth::JointType::Spherical => kinetree_tests::typed_as_ball(model, j),
                _ => false,
            });
            Some((name, joint.is_some(), typed))
        })
        .collect()
}

/// The upper arms and thighs show two markers of their own; their others sit on the elbow's
/// and knee's axes, where the clustering puts them with the forearm or shank. Those axis
/// markers are shared: they make a body with the two, and stay on the forearm or shank. So
/// every segment but the hands and feet (two markers on a ball joint, posed through it by
/// the `balls` repairs) is a body, and the tree joins them as the skeleton does, with their types, with the
/// motion-capture settings and with the defaults.
#[test]
fn two_marker_segments_share_the_markers_on_their_hinge_axis() {
    let limbs = ["upper_arm_l", "upper_arm_r", "thigh_l", "thigh_r"];
    for (settings, cfg) in [
        ("motion-capture", PipelineConfig::motion_capture()),
        ("default", PipelineConfig::default()),
    ] {
        let (mut edges, mut joined, mut typed, mut posed) = (0, 0, 0, 0);
        for seed in 0..3 {
            let data = clinical(seed, 0.0);
            let model = discover(&data, &cfg);
            let map = body_map(&model, &data.truth);
            let names: Vec<&str> = map
                .iter()
                .map(|&t| data.truth.mechanism.bodies[t].name.as_str())
                .collect();
            for limb in limbs {
                assert!(
                    names.contains(&limb),
                    "{settings}, seed {seed}: no body for the {limb}: {names:?}"
                );
            }
            assert!(
                model.bodies.len() >= 11,
                "{settings}, seed {seed}: {names:?}"
            );
            // Each shared marker joins two segments a true joint joins, and both bodies list
            // it (it sits on the joint's axis, or near enough to move with both).
            for &[p, b] in &model.shared_points {
                let own = usize::try_from(model.point_body[p]).expect("assigned");
                let pair = [map[own], map[b]];
                assert!(
                    data.truth
                        .mechanism
                        .joints
                        .iter()
                        .any(|j| pair == [j.parent, j.child] || pair == [j.child, j.parent])
                        && model.bodies[b].points.contains(&p),
                    "{settings}, seed {seed}: point {p} shared by the {} and the {}",
                    names[own],
                    names[b]
                );
            }
            posed += model.shared_points.len();
            for (name, j, t) in judged_edges(&model, &data) {
                edges += 1;
                joined += usize::from(j);
                typed += usize::from(t);
                assert!(
                    j,
                    "{settings}, seed {seed}: the {name} is not joined to its parent"
                );
            }
        }
        assert!(posed >= 6, "{settings}: {posed} shared markers");
        assert!(edges >= 30, "{settings}: {edges} edges judged");
        assert!(
            typed * 100 >= edges * 90,
            "{settings}: {typed} of {edges} joints typed right ({joined} joined)"
        );
    }
    // The class this guards: without shared markers some upper arms and thighs are lost
    // (the ball repairs, off here, pose some of them through the shoulder or hip instead).
    let mut cfg = PipelineConfig::default().with_balls(false);
    cfg.repairs.share_points.enabled = false;
    cfg.repairs.hinge_groups.enabled = false;
    let lost: usize = (0..3)
        .map(|seed| {
            let data = clinical(seed, 0.0);
            let model = discover(&data, &cfg);
            let map = body_map(&model, &data.truth);
            limbs
                .iter()
                .filter(|l| {
                    !map.iter()
                        .any(|&t| data.truth.mechanism.bodies[t].name == **l)
                })
                .count()
        })
        .sum();
    assert!(
        lost >= 3,
        "{lost} upper arms and thighs lost without shared markers"
    );
}

/// Without soft tissue (the default settings) and with each marker drifting by up to 5 mm
/// per coordinate (the motion-capture settings, meant for skin markers), the segments found
/// are joined as the skeleton joins them in at least 95 % and 90 % of the edges (and typed
/// right in 90 %), and the ball joints' centres among them are within 2 mm and 10 mm in at
/// least 90 %.
#[test]
fn clinical_skeletons_keep_their_edges_and_centres_with_soft_tissue() {
    for (settings, cfg, soft, edge_share, centre_bound) in [
        ("default", PipelineConfig::default(), 0.0, 95, 0.002),
        (
            "motion-capture",
            PipelineConfig::motion_capture(),
            0.005,
            90,
            0.01,
        ),
    ] {
        let (mut edges, mut joined, mut typed, mut centres, mut near) = (0, 0, 0, 0, 0);
        let mut worst = 0.0f64;
        for seed in 0..4 {
            let data = clinical(seed, soft);
            let model = discover(&data, &cfg);
            for (_, j, t) in judged_edges(&model, &data) {
                edges += 1;
                joined += usize::from(j);
                typed += usize::from(t);
            }
            let e = kinetree_eval::evaluate(&model, &data.truth);
            for c in e
                .joints
                .iter()
                .filter(|j| j.found)
                .filter_map(|j| j.centre_error_m)
            {
                centres += 1;
                near += usize::from(c <= centre_bound);
                worst = worst.max(c);
            }
        }
        let what = format!("{settings}, soft tissue {soft} m");
        assert!(
            edges >= 20 && centres >= 10,
            "{what}: {edges} edges, {centres} centres"
        );
        assert!(
            joined * 100 >= edges * edge_share && typed * 100 >= edges * 90,
            "{what}: {joined} of {edges} edges joined, {typed} typed right"
        );
        assert!(
            near * 100 >= centres * 90,
            "{what}: {near} of {centres} centres within {centre_bound} m (worst {worst})"
        );
    }
}

/// The hands and feet show two markers each, and the markers on the wrists' and ankles' axes
/// ride on the forearms and shanks; two markers give no pose, but with the centre of the ball
/// joint they turn about they do. With the default settings and no soft tissue every hand and
/// foot is a body, joined to its forearm or shank by a ball whose centre is within 2 mm.
/// Without the `balls` and `ball_groups` repairs none is a body.
#[test]
fn hands_and_feet_seen_through_two_markers_are_posed_through_their_ball_joint() {
    let distal = ["hand_l", "hand_r", "foot_l", "foot_r"];
    let found = |cfg: &PipelineConfig, check: bool| -> usize {
        let mut bodies = 0;
        for seed in 0..3 {
            let data = clinical(seed, 0.0);
            let model = discover(&data, cfg);
            let map = body_map(&model, &data.truth);
            let mech = &data.truth.mechanism;
            let e = kinetree_eval::evaluate(&model, &data.truth);
            let judged = judged_edges(&model, &data);
            for name in distal {
                let Some(segment) = mech.bodies.iter().position(|b| b.name == name) else {
                    panic!("no segment {name}");
                };
                if !map.contains(&segment) {
                    assert!(
                        !check,
                        "seed {seed}: no body for the {name}: {:?}",
                        model.point_body
                    );
                    continue;
                }
                bodies += 1;
                if !check {
                    continue;
                }
                let (k, spec) = mech
                    .joints
                    .iter()
                    .enumerate()
                    .find(|(_, j)| j.child == segment)
                    .expect("a joint");
                let (_, joined, typed) = judged.iter().find(|(n, _, _)| n == name).expect("judged");
                assert!(
                    *joined && *typed,
                    "seed {seed}: the {name} joined {joined}, typed as a ball {typed}"
                );
                let centre = e
                    .joints
                    .iter()
                    .find(|j| j.joint == k)
                    .and_then(|j| j.centre_error_m)
                    .expect("a centre");
                assert!(
                    centre <= 0.002,
                    "seed {seed}: the {name}'s centre is {centre} m off (joint {:?})",
                    spec.joint_type
                );
            }
        }
        bodies
    };
    assert_eq!(found(&PipelineConfig::default(), true), 12);
    let mut off = PipelineConfig::default();
    off.repairs.balls.enabled = false;
    off.repairs.ball_groups.enabled = false;
    assert_eq!(found(&off, false), 0);
}

/// With soft tissue a segment's own marker near a joint is about as rigid with the
/// neighbouring segment's markers as with its own, and the clustering can put it there: the
/// segment is left one marker and is lost, with every joint that touches it. A point not
/// rigid with most of its body's points is a candidate of `share_points` as well, and makes
/// the segment's body with the markers on its joint's axis. With the motion-capture settings
/// and 5 mm of drift at least 90 % of the skeleton's joints join the right segments with
/// the right type, counting the joints of segments not found; without loose points, fewer.
#[test]
fn a_skin_marker_clustered_with_the_neighbouring_segment_is_taken_back() {
    let right = |cfg: &PipelineConfig| -> (usize, usize) {
        let (mut total, mut typed) = (0, 0);
        for seed in 0..4 {
            let data = clinical(seed, 0.005);
            let model = discover(&data, cfg);
            let e = kinetree_eval::evaluate(&model, &data.truth);
            total += e.joints.len();
            typed += e.joints.iter().filter(|j| j.found && j.type_ok).count();
        }
        (total, typed)
    };
    let (total, typed) = right(&PipelineConfig::motion_capture());
    assert!(
        total >= 50 && typed * 100 >= total * 90,
        "{typed} of {total} joints right"
    );
    let mut off = PipelineConfig::motion_capture();
    off.repairs.share_points.loose_share = 1.0;
    let (_, typed_off) = right(&off);
    assert!(
        typed_off < typed,
        "{typed_off} joints right without loose points, {typed} with"
    );
}

/// The hands and feet of a clinical set at 10 mm of drift found as bodies, over draws where
/// `ball_groups` makes one of them a body: `balls` poses such a body through its ball only
/// on a parent that explains none of its markers, and with a looser bound than
/// `ball_groups`' it takes the parent `ball_groups` chose for one that explains a marker,
/// finds no ball, and the body, never posed, is dropped. The motion-capture preset gives
/// both repairs the same bound.
#[test]
fn a_body_made_through_its_ball_keeps_its_pose() {
    let distal = ["hand_l", "hand_r", "foot_l", "foot_r"];
    let found = |cfg: &PipelineConfig| -> usize {
        [5, 8]
            .into_iter()
            .map(|seed| {
                let data = clinical(seed, 0.01);
                let model = discover(&data, cfg);
                let map = body_map(&model, &data.truth);
                map.iter()
                    .filter(|&&t| distal.contains(&data.truth.mechanism.bodies[t].name.as_str()))
                    .count()
            })
            .sum()
    };
    let preset = PipelineConfig::motion_capture();
    let (bound, slack) = (
        preset.repairs.ball_groups.explained_bound_in_std,
        preset.repairs.ball_groups.explained_slack,
    );
    assert_eq!(
        (
            preset.repairs.balls.explained_bound_in_std,
            preset.repairs.balls.explained_slack
        ),
        (bound, slack),
        "the preset's balls and ball_groups judge an explained marker alike"
    );
    let mut looser = preset.clone();
    looser.repairs.balls.explained_bound_in_std =
        kinetree_pipeline::repairs::BallsParams::default().explained_bound_in_std;
    looser.repairs.balls.explained_slack =
        kinetree_pipeline::repairs::BallsParams::default().explained_slack;
    let (with, without) = (found(&preset), found(&looser));
    assert!(
        with > without,
        "{with} hands and feet with the preset, {without} with the balls' looser bound"
    );
}
