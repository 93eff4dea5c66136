//! A subject moving freely past a static scene (`SkeletonParams::scene_markers`: a floating
//! skeleton and six markers on a box on the floor). The scene is the static root, and the
//! subject hangs from it by its own root, the pelvis, through a multi-DoF joint: the tree a
//! floating subject gets with nothing static, not the one through whichever segment's pair
//! with the scene happened to test nearest a joint.

use kinetree_core::Model;
use kinetree_core::model::JointType;
use kinetree_eval::{body_map, evaluate};
use kinetree_pipeline::PipelineConfig;
use kinetree_synth::{SkeletonParams, SynthData, simulate, skeleton_scenario};

fn scene(seed: u64) -> SynthData {
    simulate(&skeleton_scenario(&SkeletonParams {
        seed,
        floating_pelvis: true,
        scene_markers: 6,
        ..SkeletonParams::default()
    }))
    .expect("simulate")
}

fn discover(data: &SynthData, cfg: &PipelineConfig) -> Model {
    kinetree_tests::discover_with(&data.tracks, cfg)
}

/// The true segment (0 the scene, 1 the pelvis) of the one body the static scene carries,
/// and that joint's type; `None` when the scene is not the static root or carries other
/// than one body.
fn carried_by_scene(model: &Model, data: &SynthData) -> Option<(usize, JointType)> {
    let map = body_map(model, &data.truth);
    let scene = model.static_body.filter(|&s| map[s] == 0)?;
    let carried: Vec<_> = model.joints.iter().filter(|j| j.parent == scene).collect();
    let [joint] = carried[..] else {
        return None;
    };
    Some((map[joint.child], joint.joint_type))
}

#[test]
fn a_person_moving_past_a_static_object_hangs_from_it_by_the_pelvis() {
    let seeds = 0..4u64;
    let mut exact = 0;
    let mut by_other_segments = 0;
    for seed in seeds.clone() {
        let data = scene(seed);
        let model = discover(&data, &PipelineConfig::default());
        assert_eq!(
            carried_by_scene(&model, &data),
            Some((1, JointType::MultiDof)),
            "seed {seed}"
        );
        exact += usize::from(evaluate(&model, &data.truth).joints_exact);
        // With the rule off, the tree hangs the subject by the segment nearest a joint.
        let mut off = PipelineConfig::default();
        off.tree.min_free_dof = 7;
        let without = discover(&data, &off);
        by_other_segments +=
            usize::from(carried_by_scene(&without, &data).is_some_and(|c| c.0 != 1));
    }
    assert_eq!(exact as u64, seeds.end, "joints exact in {exact} draws");
    assert!(by_other_segments >= 2, "{by_other_segments} draws");
}
