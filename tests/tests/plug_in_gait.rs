//! Skeletons with a sparse marker set as Plug-in Gait places one
//! (`SkeletonParams::plug_in_gait_markers`): one marker on each limb segment and one on each
//! elbow's, knee's, wrist's and ankle's axis. Some segments show too few markers for a body,
//! so the tree must join their neighbours across them.

use kinetree_core::Model;
use kinetree_eval::body_map;
use kinetree_pipeline::PipelineConfig;
use kinetree_synth::{SkeletonParams, SynthData, simulate, skeleton_scenario};

fn plug_in_gait(seed: u64, soft_tissue_m: f64) -> SynthData {
    simulate(&skeleton_scenario(&SkeletonParams {
        seed,
        plug_in_gait_markers: true,
        floating_pelvis: true,
        soft_tissue_m,
        ..SkeletonParams::default()
    }))
    .expect("simulate")
}

/// How many of the model's joints join two segments the true skeleton joins directly or
/// through segments that no body stands for, and how many joints there are. Each body stands
/// for the segment most of its points are on ([`body_map`]).
fn neighbour_joints(model: &Model, data: &SynthData) -> (usize, usize) {
    let map = body_map(model, &data.truth);
    let edges: Vec<(usize, usize)> = data
        .truth
        .mechanism
        .joints
        .iter()
        .map(|j| (j.parent, j.child))
        .collect();
    let reaches = |from: usize, to: usize| {
        kinetree_tests::joined_across_missing(&edges, |s| map.contains(&s), from, to)
    };
    let good = model
        .joints
        .iter()
        .filter(|j| map[j.parent] != map[j.child] && reaches(map[j.parent], map[j.child]))
        .count();
    (good, model.joints.len())
}

/// With the motion-capture settings every joint of the tree joins neighbouring segments, or
/// segments whose segment between has no body, with and without soft tissue; ranked by
/// their DoF instead (`[pipeline.tree] ball_fit_from_dof = 7`), the multi-DoF pairs hang
/// limbs on far segments.
#[test]
fn the_tree_joins_neighbours_across_segments_without_a_body() {
    let by_dof = {
        let mut c = PipelineConfig::motion_capture();
        c.tree.ball_fit_from_dof = 7;
        c
    };
    let mut counts = [(0, 0); 2];
    for soft_tissue_m in [0.0, 0.005] {
        for seed in 0..3 {
            let data = plug_in_gait(seed, soft_tissue_m);
            for (k, cfg) in [PipelineConfig::motion_capture(), by_dof.clone()]
                .iter()
                .enumerate()
            {
                let model = kinetree_tests::discover_with(&data.tracks, cfg);
                let (good, all) = neighbour_joints(&model, &data);
                assert!(all >= 5, "seed {seed}: {all} joints");
                counts[k].0 += good;
                counts[k].1 += all;
            }
        }
    }
    let [(ball, ball_all), (dof, dof_all)] = counts;
    assert!(
        ball as f64 >= 0.95 * ball_all as f64,
        "{ball} of {ball_all} joints join neighbours"
    );
    assert!(
        dof + 5 <= ball,
        "ranked by DoF {dof} of {dof_all} joints join neighbours, by the ball fit {ball}"
    );
}

/// The marker set: four markers on the pelvis, torso and head; a thigh, shank, upper arm or
/// forearm carries its own marker and the one on the joint below's axis; a hand or foot its
/// two. It is a set of its own: asked with the clinical set, the parameters are refused.
#[test]
fn the_plug_in_gait_set_puts_one_marker_on_a_limb_segment_and_one_on_its_joint_axis() {
    let data = plug_in_gait(0, 0.0);
    let mech = &data.truth.mechanism;
    for (b, body) in mech.bodies.iter().enumerate() {
        let count = data.truth.point_body.iter().filter(|&&t| t == b).count();
        let expected = match body.name.as_str() {
            "world" => 0,
            "pelvis" | "torso" | "head" => 4,
            _ => 2,
        };
        assert_eq!(count, expected, "{}: {count} markers", body.name);
    }
    let both = SkeletonParams {
        plug_in_gait_markers: true,
        clinical_markers: true,
        ..SkeletonParams::default()
    };
    let e = both.validate().expect_err("two marker sets").to_string();
    assert!(e.contains("data.plug_in_gait_markers"), "{e}");
}

/// A thigh or upper arm shows its own marker and the one on the knee's or elbow's axis, which
/// the clustering gives the shank or forearm (it is rigid with both). The marker left alone
/// borrows it (`[pipeline.repairs.ball_groups] borrow`, on in the motion-capture preset):
/// the two turn about the hip or the shoulder, make the segment's body, and the axis marker
/// is shared by the two segments it joins. Without borrowing fewer segments get a body.
#[test]
fn a_lone_marker_borrows_the_axis_marker_the_segment_below_took() {
    let borrowing = PipelineConfig::motion_capture();
    let mut lone = PipelineConfig::motion_capture();
    lone.repairs.ball_groups.borrow = false;
    let (mut with, mut without, mut shared) = (0, 0, 0);
    for seed in 0..3 {
        let data = plug_in_gait(seed, 0.0);
        let mech = &data.truth.mechanism;
        let adjacent = |a: usize, b: usize| {
            mech.joints
                .iter()
                .any(|j| (j.parent, j.child) == (a, b) || (j.parent, j.child) == (b, a))
        };
        for (cfg, count) in [(borrowing.clone(), &mut with), (lone.clone(), &mut without)] {
            let model = kinetree_tests::discover_with(&data.tracks, &cfg);
            let map = body_map(&model, &data.truth);
            let mut segments = map.clone();
            segments.sort_unstable();
            segments.dedup();
            *count += segments.len();
            // Every point on two bodies joins two neighbouring segments.
            for b in &model.bodies {
                for &p in &b.points {
                    let owner = model.point_body[p];
                    if owner >= 0 && owner as usize != b.id {
                        shared += 1;
                        assert!(
                            adjacent(map[owner as usize], map[b.id]),
                            "seed {seed}: point {p} shared by {} and {}",
                            mech.bodies[map[owner as usize]].name,
                            mech.bodies[map[b.id]].name
                        );
                    }
                }
            }
        }
    }
    assert!(shared >= 3, "{shared} shared points");
    assert!(
        with >= without + 3,
        "{with} segments with a body when lone markers borrow, {without} without"
    );
}
