//! `kinetree_eval::evaluate` names why each true joint is missed: a branching tree discovered
//! exactly, then edited into each failure class.

use kinetree_core::Model;
use kinetree_core::model::JointType;
use kinetree_eval::{JointMiss, body_map, evaluate};
use kinetree_synth::{GroundTruth, RandomParams, random_scenario, simulate};

/// A 5-joint random tree (the discovery test's branching tree) and its exact model.
fn exact_tree() -> (GroundTruth, Model) {
    let params = RandomParams {
        n_joints: 5,
        tree: true,
        seed: 3,
        dropout: 0.2,
        ..RandomParams::default()
    };
    let data = simulate(&random_scenario(&params)).expect("simulate");
    let model = kinetree_tests::discover_default(&data.tracks);
    let e = evaluate(&model, &data.truth);
    assert!(e.joints_exact, "the fixture must be exact: {e:?}");
    assert!(e.joints.iter().all(|j| j.miss.is_none()), "{e:?}");
    (data.truth, model)
}

/// The model body standing for each true body (the fixture is exact: one each).
fn model_body(model: &Model, truth: &GroundTruth) -> Vec<usize> {
    let map = body_map(model, truth);
    (0..truth.n_bodies())
        .map(|t| {
            map.iter()
                .position(|&m| m == t)
                .expect("every true body found")
        })
        .collect()
}

/// The model joint whose child stands for true body `child`.
fn joint_of(model: &Model, of: &[usize], child: usize) -> usize {
    model
        .joints
        .iter()
        .position(|j| j.child == of[child])
        .expect("joint")
}

/// The miss of true joint `k` after `edit` of the model.
fn miss_after(
    truth: &GroundTruth,
    model: &Model,
    k: usize,
    edit: impl FnOnce(&mut Model),
) -> Option<JointMiss> {
    let mut m = model.clone();
    edit(&mut m);
    evaluate(&m, truth).joints[k].miss
}

#[test]
fn each_missed_joint_is_named_by_why() {
    let (truth, model) = exact_tree();
    let of = model_body(&model, &truth);
    let joints = &truth.mechanism.joints;
    // A joint two levels down (its parent has a parent), and two siblings.
    let deep = joints
        .iter()
        .position(|j| truth.mechanism.parent_of(j.parent).is_some())
        .expect("the tree has a joint two levels down");
    let (first, second) = (0..joints.len())
        .flat_map(|a| (a + 1..joints.len()).map(move |b| (a, b)))
        .find(|&(a, b)| joints[a].parent == joints[b].parent)
        .expect("the tree has siblings");
    let (parent, child) = (joints[deep].parent, joints[deep].child);
    let grandparent = truth.mechanism.parent_of(parent).expect("grandparent");
    let jk = joint_of(&model, &of, child);

    let wrong = {
        let mut m = model.clone();
        m.joints[jk].joint_type = if m.joints[jk].joint_type == JointType::Prismatic {
            JointType::Revolute
        } else {
            JointType::Prismatic
        };
        evaluate(&m, &truth).joints[deep].clone()
    };
    assert_eq!(wrong.miss, Some(JointMiss::WrongType));
    assert!(wrong.found && !wrong.type_ok);
    assert!(wrong.model_type.is_some());

    let reversed = miss_after(&truth, &model, deep, |m| {
        let j = &mut m.joints[jk];
        (j.parent, j.child) = (j.child, j.parent);
    });
    assert_eq!(reversed, Some(JointMiss::Reversed));

    let root = miss_after(&truth, &model, deep, |m| {
        m.joints.remove(jk);
    });
    assert_eq!(root, Some(JointMiss::ChildIsRoot));

    let up = miss_after(&truth, &model, deep, |m| {
        m.joints[jk].parent = of[grandparent]
    });
    assert_eq!(up, Some(JointMiss::OnGrandparent));

    let sibling = miss_after(&truth, &model, second, |m| {
        let k = joint_of(m, &of, joints[second].child);
        m.joints[k].parent = of[joints[first].child];
    });
    assert_eq!(sibling, Some(JointMiss::OnSibling));

    // The parent hung on its own child.
    let pk = joint_of(&model, &of, parent);
    let below = miss_after(
        &truth,
        &model,
        joints
            .iter()
            .position(|j| j.child == parent)
            .expect("joint"),
        |m| {
            m.joints[pk].parent = of[child];
        },
    );
    assert_eq!(below, Some(JointMiss::OnDescendant));

    // The child's keypoints all on its parent's body: no body stands for the child.
    let merged = miss_after(&truth, &model, deep, |m| {
        m.bodies[of[child]].points = m.bodies[of[parent]].points.clone();
    });
    assert_eq!(merged, Some(JointMiss::ChildMissing));

    let parent_gone = miss_after(&truth, &model, deep, |m| {
        m.bodies[of[parent]].points = m.bodies[of[grandparent]].points.clone();
    });
    assert_eq!(parent_gone, Some(JointMiss::ParentMissing));

    // Another body holding the child's keypoints too, and neither on the parent.
    let other = (0..truth.n_bodies())
        .find(|&b| b != child && b != parent && b != 0)
        .expect("another body");
    let split = miss_after(&truth, &model, deep, |m| {
        m.bodies[of[other]].points = m.bodies[of[child]].points.clone();
        m.joints.remove(jk);
    });
    assert_eq!(split, Some(JointMiss::ChildSplit));
}

#[test]
fn every_miss_class_has_its_sweep_column_in_order() {
    for (k, m) in JointMiss::ALL.iter().enumerate() {
        assert_eq!(*m as usize, k, "{m:?}");
        assert_eq!(
            kinetree_pipeline::sweep::PER_JOINT_COLUMNS[2 + k],
            format!("missed_{}", m.as_str())
        );
    }
    assert_eq!(
        kinetree_pipeline::sweep::PER_JOINT_COLUMNS.len(),
        2 + JointMiss::ALL.len()
    );
}
