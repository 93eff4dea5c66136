//! Exact ties in the tree: a gripper's two fingers move relative to each other by a joint of
//! the same type as their joints with the hand, so the data fit them as siblings and as a
//! chain; the tree hangs both on the hand.

use kinetree_eval::{body_map, evaluate};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{GripperKind, GripperParams, gripper_scenario, simulate};

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
            let map = body_map(&model, &data.truth);
            let names = |b: usize| data.truth.mechanism.bodies[map[b]].name.as_str();
            let fingers: Vec<&str> = model
                .joints
                .iter()
                .filter(|j| names(j.child).starts_with("finger"))
                .map(|j| names(j.parent))
                .collect();
            assert_eq!(
                fingers,
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
