//! Proptest strategies over mechanisms (feature `proptest`).
//!
//! Every choice is a field of [`MechanismSpec`], so proptest shrinks a failing case towards
//! fewer joints, smaller bodies, less noise and less occlusion: a minimal failing mechanism.
//! The identifiability rule is on [`MechanismSpec::scenario`].

use crate::spec::{JointDraw, MechanismSpec};
use proptest::collection::vec;
use proptest::prelude::*;

/// One joint: parent pick, type (prismatic with probability `prismatic`), a random 3D axis,
/// body length 2-50 cm, 4-12 keypoints, amplitude and phase.
pub fn joint_draw(prismatic: f64) -> impl Strategy<Value = JointDraw> {
    (
        0.0..1.0f64,
        proptest::bool::weighted(1.0 - prismatic),
        [-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64],
        0.02..0.5f64,
        4usize..=12,
        0.0..1.0f64,
        0.0..std::f64::consts::TAU,
    )
        .prop_map(
            |(parent_pick, revolute, axis, size_m, n_points, amplitude, phase)| JointDraw {
                parent_pick,
                revolute,
                axis,
                size_m,
                n_points,
                amplitude,
                phase,
            },
        )
}

/// Mechanisms with `joints` joints (a range within 1-8), chains or trees, noise 0-5 mm,
/// occlusion 0-40 %.
pub fn mechanism(
    joints: std::ops::RangeInclusive<usize>,
    tree: impl Strategy<Value = bool>,
) -> impl Strategy<Value = MechanismSpec> {
    (
        vec(joint_draw(0.35), joints),
        tree,
        0.0..0.005f64,
        0.0..0.4f64,
        any::<u64>(),
    )
        .prop_map(
            |(joints, tree, noise_sigma_m, dropout, seed)| MechanismSpec {
                joints,
                tree,
                noise_sigma_m,
                dropout,
                seed,
            },
        )
}

/// Chains of 1-8 joints.
pub fn chain() -> impl Strategy<Value = MechanismSpec> {
    mechanism(1..=8, Just(false))
}

/// Trees of 2-8 joints.
pub fn tree() -> impl Strategy<Value = MechanismSpec> {
    mechanism(2..=8, Just(true))
}

/// Chains or trees of 1-8 joints.
pub fn any_mechanism() -> impl Strategy<Value = MechanismSpec> {
    mechanism(1..=8, any::<bool>())
}
