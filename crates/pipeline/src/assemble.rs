//! A model assembled from bodies, poses and pair tests: the tree, the bodies in tree order, a
//! joint per tree edge.

use crate::Pipeline;
use kinetree_core::geom::cam_from;
use kinetree_core::model::{
    Body, Joint, NoiseInfo, NoiseSource, Ranks, RigidTransform, SCHEMA_VERSION, StageNames,
};
use kinetree_core::{
    BodyPoses, DofInput, Error, JointKind, Model, ModelDraft, PairDof, Result, Segmentation,
    Tracks, Warning,
};

/// The model of a segmentation's bodies, poses and pair tests (segmentation numbering): the
/// spanning tree without the edges `excluded`, the bodies renumbered in tree order, a joint
/// per tree edge from its pair test (looked up in `memo` when kept there), and the warnings
/// of the assembly after `warnings`. Not fitted: the whole-tree fit sets the positions'
/// precision and the re-prediction.
///
/// # Errors
/// [`Error::Degenerate`] when there is no body; the DoF stage's error.
#[allow(clippy::too_many_arguments)]
pub(crate) fn assemble(
    pipeline: &Pipeline,
    tracks: &Tracks,
    seg: &Segmentation,
    poses: &BodyPoses,
    pairs: Vec<PairDof>,
    sigma: f64,
    source: NoiseSource,
    mut warnings: Vec<Warning>,
    excluded: &[(usize, usize)],
    replaced: &[PairDof],
    memo: Option<&kinetree_core::memo::Memo>,
) -> Result<ModelDraft> {
    let nb = seg.n_bodies();
    let tree = kinetree_structure::spanning_tree_without(nb, &pairs, excluded, &pipeline.tree)
        .ok_or_else(|| Error::Degenerate("no bodies".into()))?;
    // Model numbering: tree (breadth-first) order.
    let order = tree.order.clone();
    let mut new_id = vec![0usize; nb];
    for (k, &b) in order.iter().enumerate() {
        new_id[b] = k;
    }
    let renumber_pair = |p: &PairDof| -> PairDof {
        let mut q = p.clone();
        q.a = p.a.map(|a| new_id[a]);
        q.b = new_id[p.b];
        q
    };
    let statics = kinetree_structure::static_bodies(nb, &pairs);
    if !tree.root_is_static {
        warnings.push(Warning::NoStaticBody {
            root: new_id[tree.root],
        });
    }
    let input = DofInput {
        poses,
        noise_sigma_m: sigma,
    };
    let mut joints = Vec::new();
    for &child in &order {
        let Some(parent) = tree.parent[child] else {
            continue;
        };
        let pair = match replaced
            .iter()
            .find(|q| (q.a, q.b) == (Some(parent), child))
        {
            Some(q) => q.clone(),
            None => {
                crate::runner::test_pair(pipeline.dof.as_ref(), &input, Some(parent), child, memo)?
            }
        };
        let (positions, reference) = kinetree_structure::joint_positions(poses, &pair);
        let reference_frame = reference.unwrap_or(pair.reference_frame);
        let cam_parent = cam_from(poses, Some(parent), reference_frame);
        // Single-DoF joints: averaged over all frames; others (multi-DoF, whose child is
        // posed freely; URDF export still needs a pose): the reference frame's.
        let reference_pose = reference
            .and_then(|r| kinetree_structure::joint_reference(poses, &pair, &positions, r))
            .or_else(|| {
                kinetree_core::geom::relative_poses(poses, Some(parent), child)
                    .get(reference_frame)
                    .copied()
                    .flatten()
            })
            .map(|x| RigidTransform::from_isometry(&x));
        let (axis_p, point_p) = match &pair.joint {
            JointKind::Revolute { axis, pivot } => (Some(*axis), Some(*pivot)),
            JointKind::Prismatic { axis } => (Some(*axis), None),
            JointKind::Spherical { centre } => (None, Some(*centre)),
            JointKind::Universal { axis, centre, .. } => (Some(*axis), Some(*centre)),
            _ => (None, None),
        };
        // A universal joint's second axis, fixed in the child, where the reference pose
        // (the relative pose at the reference frame, where its angles are zero) holds it.
        let second_p = match (&pair.joint, reference_pose.and_then(|r| r.to_isometry())) {
            (JointKind::Universal { child_axis, .. }, Some(zero)) => {
                Some(zero.rotation * child_axis)
            }
            _ => None,
        };
        // A spherical joint's rotation vectors from the two bodies' own poses, until the
        // whole-tree fit writes its own.
        let coordinates = match (&pair.joint, reference_pose.and_then(|r| r.to_isometry())) {
            (JointKind::Spherical { .. }, Some(zero)) => {
                kinetree_core::geom::relative_poses(poses, Some(parent), child)
                    .iter()
                    .map(|x| {
                        x.map(|x| {
                            let v = (x.rotation * zero.rotation.inverse()).scaled_axis();
                            vec![v.x, v.y, v.z]
                        })
                    })
                    .collect()
            }
            _ => Vec::new(),
        };
        let arr = |v: kinetree_core::nalgebra::Vector3<f64>| [v.x, v.y, v.z];
        if !pair.joint.is_single_dof()
            && !matches!(
                pair.joint,
                JointKind::Spherical { .. } | JointKind::Universal { .. }
            )
        {
            warnings.push(Warning::MultiDofJoint {
                parent: new_id[parent],
                child: new_id[child],
                dof: pair.dof,
            });
        }
        joints.push(Joint {
            parent: new_id[parent],
            child: new_id[child],
            joint_type: pair.joint.joint_type(),
            axis: match (axis_p, cam_parent) {
                (Some(a), Some(c)) => Some(arr(c.rotation * a)),
                _ => None,
            },
            point: match (point_p, cam_parent) {
                (Some(p), Some(c)) => Some(arr((c * p).coords)),
                _ => None,
            },
            axis_in_parent: axis_p.map(arr),
            point_in_parent: point_p.map(|p| arr(p.coords)),
            second_axis: match (second_p, cam_parent) {
                (Some(a), Some(c)) => Some(arr(c.rotation * a)),
                _ => None,
            },
            second_axis_in_parent: second_p.map(arr),
            reference_frame,
            reference_pose,
            positions,
            // Set with the positions by `kinetree_fit::fit_model_positions`.
            position_std: Vec::new(),
            // Set for the finished model by `kinetree_fit::write_joint_precision`.
            axis_std_deg: None,
            pivot_std_m: None,
            centre_std_m: None,
            second_axis_std_deg: None,
            smoothed_positions: Vec::new(),
            smoothed_std: Vec::new(),
            coordinates,
            coordinate_std: Vec::new(),
            smoothed_coordinates: Vec::new(),
            smoothed_coordinate_std: Vec::new(),
            range: None,
            dof: pair.dof,
            ranks: Ranks {
                translation: pair.translation.rank,
                rotation: pair.rotation.rank,
                centre: pair.centre.rank,
                sliding: pair.sliding.rank,
            },
            fit_ratio: pair.fit_ratio,
            fit: kinetree_core::model::JointFit::Followed,
        });
    }
    for &b in &order {
        if b != tree.root && tree.parent[b].is_none() {
            warnings.push(Warning::BodyDetached { body: new_id[b] });
        }
        let missing = poses.n_frames - poses.bodies[b].n_registered();
        if missing > 0 {
            warnings.push(Warning::FramesUnregistered {
                body: new_id[b],
                frames: missing,
            });
        }
    }
    let bodies = order
        .iter()
        .map(|&b| Body {
            id: new_id[b],
            points: poses.bodies[b].points.clone(),
            is_static: statics.contains(&b),
            parent: tree.parent[b].map(|p| new_id[p]),
            frames_registered: poses.bodies[b].n_registered(),
            median_residual_m: poses.bodies[b].median_residual_m(),
            shape: poses.bodies[b]
                .shape
                .iter()
                .zip(&poses.bodies[b].placed)
                .map(|(p, &ok)| ok.then_some([p.x, p.y, p.z]))
                .collect(),
            internal_dissimilarity: None,
        })
        .collect();
    let point_body = seg
        .labels()
        .iter()
        .map(|l| l.map_or(-1, |b| new_id[b] as i64))
        .collect();
    let mut model_pairs: Vec<PairDof> = pairs.iter().map(renumber_pair).collect();
    for p in &mut model_pairs {
        if let Some(a) = p.a
            && a > p.b
        {
            // Keep a < b in the new numbering; the ranks do not depend on the order.
            p.a = Some(p.b);
            p.b = a;
        }
    }
    model_pairs.sort_by_key(|p| (p.a.map_or(0, |a| a + 1), p.b));
    let chain =
        kinetree_structure::paper_chain(nb, &pairs).map(|c| c.iter().map(|&b| new_id[b]).collect());
    let model = Model {
        schema_version: SCHEMA_VERSION,
        generator: format!("kinetree {}", env!("CARGO_PKG_VERSION")),
        n_frames: tracks.n_frames(),
        n_points: tracks.n_points(),
        point_labels: tracks.labels().map(<[String]>::to_vec),
        noise: NoiseInfo {
            sigma_m: sigma,
            distance_variance_m2: 2.0 * sigma * sigma,
            source,
        },
        position_limits: pipeline.positions,
        stages: StageNames {
            dissimilarity: pipeline.dissimilarity.name().into(),
            clustering: pipeline.clustering.name().into(),
            pose: pipeline.pose.name().into(),
            dof: pipeline.dof.name().into(),
        },
        point_body,
        shared_points: {
            let mut shared: Vec<[usize; 2]> =
                seg.shared().iter().map(|&(p, b)| [p, new_id[b]]).collect();
            shared.sort_unstable();
            shared
        },
        point_confidence: Vec::new(),
        // The root when it is static (the most posed of several), else none is.
        static_body: tree.root_is_static.then(|| new_id[tree.root]),
        root_joint: Some(kinetree_core::model::RootJoint::of(
            tree.root_is_static.then_some(tree.root),
        )),
        root_body: new_id[tree.root],
        bodies,
        joints,
        chain,
        pairs: model_pairs,
        reprediction_rms_in_sigma: None,
        warnings,
        trace: Vec::new(),
        body_poses_file: None,
    };
    Ok(ModelDraft {
        model,
        body_order: order,
        fitted: None,
        history: Vec::new(),
        cache: None,
    })
}
