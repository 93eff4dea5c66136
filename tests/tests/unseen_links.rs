//! Arms whose wrist link no keypoint shows well enough to pose (`HiddenLinkParams`): seen by a
//! few keypoints in a tenth of the frames, or buried without any. The links on either side
//! move against each other with two coordinates about two hinges whose axes do not meet; the
//! model puts a body without points between them, carried by the first hinge and carrying
//! the second (`[pipeline.unseen_links]`, an `unseen_link` warning).

use kinetree_core::model::JointType;
use kinetree_core::{Model, Warning};
use kinetree_eval::{Evaluation, evaluate};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{
    HiddenLinkParams, RandomParams, SkeletonParams, SynthData, hidden_link_arm, random_scenario,
    simulate, skeleton_scenario,
};

fn arm(seed: u64, hidden_points: usize, hidden_fraction: f64) -> SynthData {
    simulate(&hidden_link_arm(&HiddenLinkParams {
        seed,
        hidden_points,
        hidden_fraction,
        ..HiddenLinkParams::default()
    }))
    .expect("simulate")
}

fn discover(data: &SynthData, unseen_links: bool) -> Model {
    let mut cfg = PipelineConfig::default();
    cfg.unseen_links.enabled = unseen_links;
    kinetree_tests::discover_with(&data.tracks, &cfg)
}

/// Whether true joints 4 and 5 (into and out of the hidden link) are found with their type
/// and an axis within `max_axis_deg` of the truth.
fn link_joints_right(e: &Evaluation, max_axis_deg: f64) -> bool {
    e.joints[4..6]
        .iter()
        .all(|j| j.found && j.type_ok && j.axis_error_deg.is_some_and(|a| a <= max_axis_deg))
}

/// The body of the model's first `unseen_link` warning and the keypoints it names.
fn unseen_link(model: &Model) -> Option<(usize, Vec<usize>)> {
    model.warnings.iter().find_map(|w| match w {
        Warning::UnseenLink { body, points, .. } => Some((*body, points.clone())),
        _ => None,
    })
}

fn unseen_link_warnings(model: &Model) -> usize {
    model
        .warnings
        .iter()
        .filter(|w| matches!(w, Warning::UnseenLink { .. }))
        .count()
}

/// A random tree of 20 links (19 joints, 300 frames, 10 % dropout on top of the links hiding
/// about two thirds of the observations).
fn big_tree(seed: u64) -> SynthData {
    simulate(&random_scenario(&RandomParams {
        n_joints: 19,
        tree: true,
        n_frames: 300,
        dropout: 0.1,
        seed,
        ..RandomParams::default()
    }))
    .expect("simulate")
}

/// How many of the true joints `model` has right (the right bodies and type), of how many.
fn joints_right(model: &Model, data: &SynthData) -> (usize, usize) {
    let e = evaluate(model, &data.truth);
    let right = e.joints.iter().filter(|j| j.found && j.type_ok).count();
    (right, e.joints.len())
}

#[test]
fn a_link_seen_in_a_tenth_of_the_frames_is_put_between_its_hinges() {
    let seeds = [0u64, 1, 2, 3];
    let mut without = 0;
    let mut given = 0;
    for seed in seeds {
        let data = arm(seed, 8, 0.1);
        let model = discover(&data, true);
        let e = evaluate(&model, &data.truth);
        assert!(e.joints_exact, "seed {seed}: {e:?}");
        assert!(link_joints_right(&e, 1.5), "seed {seed}: {e:?}");
        assert_eq!(unseen_link_warnings(&model), 1, "seed {seed}");
        let (link, points) = unseen_link(&model).expect("a link");
        // The keypoints given to the link are on it, and are the true link's.
        assert_eq!(model.bodies[link].points, points, "seed {seed}");
        given += points.len();
        for &p in &points {
            assert_eq!(data.truth.point_body[p], 5, "seed {seed}: point {p}");
        }
        // Both hinges have positions in most frames: the link's pose follows from them.
        for j in model
            .joints
            .iter()
            .filter(|j| j.child == link || j.parent == link)
        {
            assert_eq!(j.joint_type, JointType::Revolute);
            let known = j.positions.iter().flatten().count();
            assert!(known * 2 > model.n_frames, "seed {seed}: {known} positions");
        }
        let off = discover(&data, false);
        without += usize::from(link_joints_right(&evaluate(&off, &data.truth), 1.5));
        assert_eq!(unseen_link_warnings(&off), 0);
    }
    // Without the unseen link the two hinges are one multi-DoF joint (a universal one where
    // their axes pass 5 mm apart, seed 1).
    assert_eq!(without, 0, "{without} draws right without it");
    assert!(given >= 4, "{given} keypoints given to the links");
}

/// A random 20-body tree (300 frames, 10 % dropout, seed 0; the links hide two thirds of the
/// observations) whose hub link, carrying four children, is seen by three of its keypoints at
/// once in 26 frames and by one in 254: its regrouped keypoints come with keypoints of other
/// bodies, no hinge holds and the link would be dropped. The hinges repair takes the strays
/// off (`peel_below_frames`), poses the link through its hinge, and every joint is found.
#[test]
fn a_hub_link_seen_by_three_keypoints_in_few_frames_is_posed_through_its_hinge() {
    let data = big_tree(0);
    let model = kinetree_tests::discover_with(&data.tracks, &PipelineConfig::default());
    let e = evaluate(&model, &data.truth);
    assert_eq!(e.n_bodies_found, 20, "{e:?}");
    assert!(e.joints.iter().all(|j| j.found && j.type_ok), "{e:?}");
    assert!(
        model
            .trace
            .iter()
            .any(|t| t.repair == "hinges" && t.summary.contains("taken off")),
        "{:?}",
        model.trace
    );
}

/// A random 20-body tree (300 frames, 10 % dropout, seed 1) whose hub link, slid along its
/// base and carrying two hinged children whose axes meet at the link's end, is seen by two of
/// its keypoints at once in 53 frames and never by three: it gets no body, and its children
/// hang on each other by a universal joint. That joint's cross moves against the base by one
/// slide, so it is read as the link (`[pipeline.unseen_links] hubs`), and every joint is
/// found; without it three are not.
#[test]
fn a_hub_link_that_no_three_keypoints_show_is_read_from_its_childrens_universal_joint() {
    let data = big_tree(1);
    let model = kinetree_tests::discover_with(&data.tracks, &PipelineConfig::default());
    let (right, all) = joints_right(&model, &data);
    assert_eq!(right, all, "joints right");
    let (hub, _) = unseen_link(&model).expect("a link put in");
    let children = model.joints.iter().filter(|j| j.parent == hub).count();
    assert!(children >= 2, "the link carries {children} bodies");
    let mut off = PipelineConfig::default();
    off.unseen_links.hubs = false;
    let (right, all) = joints_right(&kinetree_tests::discover_with(&data.tracks, &off), &data);
    assert!(right < all, "every joint right without the hubs");
}

/// A random 20-body tree (300 frames, 10 % dropout, seed 6) with a hidden link that carries
/// one child, which the tree hangs by a multi-DoF joint on another link of the base, and a
/// hidden hub whose children hang by a universal joint. With `rehang` the child is tried on
/// the body whose two hinges carry it best (the base, through a link put in), and every joint
/// is found; without it, not.
#[test]
fn a_hidden_links_child_hung_on_a_neighbour_is_moved_onto_it() {
    let data = big_tree(6);
    let model = kinetree_tests::discover_with(&data.tracks, &PipelineConfig::default());
    let (right, all) = joints_right(&model, &data);
    assert_eq!(right, all, "joints right");
    assert!(unseen_link_warnings(&model) >= 2, "{:?}", model.warnings);
    let mut off = PipelineConfig::default();
    off.unseen_links.rehang = false;
    let (right, all) = joints_right(&kinetree_tests::discover_with(&data.tracks, &off), &data);
    assert!(right < all, "every joint right without rehanging");
}

#[test]
fn a_buried_link_without_keypoints_is_put_in() {
    for seed in 0..4u64 {
        let data = arm(seed, 0, 0.27);
        let model = discover(&data, true);
        let e = evaluate(&model, &data.truth);
        assert!(e.joints_exact, "seed {seed}: {e:?}");
        assert!(link_joints_right(&e, 1.5), "seed {seed}: {e:?}");
        assert_eq!(model.bodies.len(), 7, "seed {seed}");
        assert_eq!(
            unseen_link(&model).map(|l| l.1),
            Some(Vec::new()),
            "seed {seed}"
        );
        let summary = kinetree_pipeline::report::inspect(&model);
        assert!(
            summary.contains("(a link put in between two hinges): 0 points"),
            "{summary}"
        );
    }
}

#[test]
fn universal_joints_stay_universal() {
    // Skeletons with universal wrists and ankles at 1 mm: the fitted axes of two hinges meet
    // within the offset bound, so no link is put in. With the bound and the gain over the
    // universal joint both at zero, two hinges a fraction of a millimetre apart replace
    // some universal joint.
    let mut loose = PipelineConfig::default();
    loose.unseen_links.min_offset_in_sigma = 0.0;
    loose.unseen_links.min_gain_over_universal = 0.0;
    let mut loosened = 0;
    for seed in 0..2u64 {
        let data = simulate(&skeleton_scenario(&SkeletonParams {
            seed,
            universal_wrists_and_ankles: true,
            ..SkeletonParams::default()
        }))
        .expect("simulate");
        let model = discover(&data, true);
        assert_eq!(unseen_link_warnings(&model), 0, "seed {seed}");
        let universal = model
            .joints
            .iter()
            .filter(|j| j.joint_type == JointType::Universal)
            .count();
        assert!(universal >= 3, "seed {seed}: {universal} universal joints");
        loosened += unseen_link_warnings(&kinetree_tests::discover_with(&data.tracks, &loose));
    }
    assert!(loosened > 0, "no link put in with the bounds at zero");
}

#[test]
fn unseen_link_parameters_out_of_range_are_errors_that_name_them() {
    for (key, value) in [
        ("min_frames", "2"),
        ("max_excess", "-1.0"),
        ("min_offset_in_sigma", "nan"),
        ("min_axes_angle_deg", "95.0"),
    ] {
        let toml = format!("[unseen_links]\n{key} = {value}\n");
        let c: PipelineConfig = toml::from_str(&toml).expect("parses");
        let err = Pipeline::from_config(&c)
            .expect_err("out of range")
            .to_string();
        assert!(
            err.contains(&format!("pipeline.unseen_links.{key}")),
            "{err}"
        );
    }
    let unknown: Result<PipelineConfig, _> = toml::from_str("[unseen_links]\nmin_frame = 5\n");
    assert!(unknown.is_err_and(|e| e.to_string().contains("min_frame")));
}
