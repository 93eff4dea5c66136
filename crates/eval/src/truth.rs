//! Comparing a discovered model with the simulator's truth.

use crate::{
    adjusted_rand_index, aligned_rms, axis_error_deg, point_line_distance, precision_check,
};
use kinetree_core::model::RootJoint;
use kinetree_core::{Error, Model, Result, Tracks};
use kinetree_synth::{GroundTruth, JointType};
use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// How one true joint was recovered.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointEval {
    /// True joint index.
    pub joint: usize,
    /// A model joint links the same two bodies, parent to child.
    pub found: bool,
    /// ... and has the same type.
    pub type_ok: bool,
    /// Axis error, degrees.
    pub axis_error_deg: Option<f64>,
    /// Distance from the true anchor to the estimated axis line (revolute), metres.
    pub pivot_error_m: Option<f64>,
    /// Axis error in the parent's body frame, degrees: the model's `axis_in_parent` after
    /// aligning the parent's reference shape with its true keypoints (all frames went into
    /// both), so one frame's pose noise does not enter. `None` when the parent has fewer
    /// than three non-collinear placed points of its true body.
    #[serde(default)]
    pub axis_error_in_parent_deg: Option<f64>,
    /// Distance from the true anchor to the estimated axis line in the parent's body frame
    /// (revolute), metres, with the same alignment.
    #[serde(default)]
    pub pivot_error_in_parent_m: Option<f64>,
    /// `axis_error_in_parent_deg` in units of the model's stated axis precision
    /// (`Joint::axis_std_deg`): about 1 in the RMS for a bound that the estimate reaches.
    #[serde(default)]
    pub axis_z: Option<f64>,
    /// `pivot_error_in_parent_m` in units of the model's `Joint::pivot_std_m`.
    #[serde(default)]
    pub pivot_z: Option<f64>,
    /// `centre_error_in_parent_m` in units of the model's `Joint::centre_std_m` (ball and
    /// universal joints).
    #[serde(default)]
    pub centre_z: Option<f64>,
    /// RMS joint-position error after sign and offset alignment (radians or metres).
    pub position_rms: Option<f64>,
    /// RMS of the model's per-frame position standard deviations (`Joint::position_std`),
    /// the precision its data allowed; see [`crate::precision_check`].
    #[serde(default)]
    pub position_std_rms: Option<f64>,
    /// RMS of the position errors in units of their stated standard deviations (about 1 for
    /// an estimate as good as it says).
    #[serde(default)]
    pub position_z_rms: Option<f64>,
    /// RMS error of the smoothed positions (`Joint::smoothed_positions`), after their own
    /// sign and offset alignment.
    #[serde(default)]
    pub smoothed_rms: Option<f64>,
    /// RMS of the smoothed positions' errors in units of their standard deviations.
    #[serde(default)]
    pub smoothed_z_rms: Option<f64>,
    /// Distance from a true spherical or universal joint's centre to the model's joint point
    /// in the camera frame at the joint's reference frame, metres.
    #[serde(default)]
    pub centre_error_m: Option<f64>,
    /// The same in the parent's body frame, with the alignment of
    /// `axis_error_in_parent_deg`, so one frame's pose noise does not enter.
    #[serde(default)]
    pub centre_error_in_parent_m: Option<f64>,
    /// A universal joint's second axis error in the parent's body frame at the model's
    /// reference frame, with the same alignment, degrees (its first axis is in
    /// `axis_error_in_parent_deg`).
    #[serde(default)]
    pub second_axis_error_in_parent_deg: Option<f64>,
    /// A universal joint's second axis error in the child's body frame (the model's
    /// `second_axis_in_parent` carried back through its `reference_pose`, the child's
    /// reference shape aligned with its true keypoints), degrees.
    #[serde(default)]
    pub second_axis_error_in_child_deg: Option<f64>,
    /// `second_axis_error_in_child_deg` in units of the model's `Joint::second_axis_std_deg`.
    #[serde(default)]
    pub second_axis_z: Option<f64>,
    /// The type of the model joint between the two bodies, where there is one.
    #[serde(default)]
    pub model_type: Option<kinetree_core::model::JointType>,
    /// Why the joint is not right (`None` when it is found with its type).
    #[serde(default)]
    pub miss: Option<JointMiss>,
}

/// Why a true joint was not recovered: the first of these that holds, in this order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JointMiss {
    /// A model joint links the two bodies, with another type.
    WrongType,
    /// No model body stands for the true child: its points went to other bodies or to none.
    ChildMissing,
    /// No model body stands for the true parent.
    ParentMissing,
    /// A model joint links the two bodies with the child as its parent.
    Reversed,
    /// More than one model body stands for the true child, and none hangs on the parent.
    ChildSplit,
    /// The child's body hangs on no body: it is the model's root.
    ChildIsRoot,
    /// The child hangs on its true parent's parent (the parent skipped).
    OnGrandparent,
    /// The child hangs on another child of its true parent (a sibling).
    OnSibling,
    /// The child hangs on one of its own descendants.
    OnDescendant,
    /// The child hangs on another body.
    OnOther,
    /// The truth's free root (a floating mechanism): the model's root is static or not free.
    RootNotFree,
}

impl JointMiss {
    /// The number of classes.
    pub const COUNT: usize = 11;

    /// Every class, in order.
    pub const ALL: [JointMiss; JointMiss::COUNT] = [
        Self::WrongType,
        Self::ChildMissing,
        Self::ParentMissing,
        Self::Reversed,
        Self::ChildSplit,
        Self::ChildIsRoot,
        Self::OnGrandparent,
        Self::OnSibling,
        Self::OnDescendant,
        Self::OnOther,
        Self::RootNotFree,
    ];

    /// How many of `misses` fall in each class, in the order of [`JointMiss::ALL`].
    pub fn tally(misses: impl IntoIterator<Item = JointMiss>) -> [usize; JointMiss::COUNT] {
        let mut counts = [0; JointMiss::COUNT];
        for m in misses {
            counts[m as usize] += 1;
        }
        counts
    }

    /// `counts` (in the order of [`JointMiss::ALL`]) as text, the classes with none left
    /// out: `wrong type 2, on sibling 3`; empty when every count is zero.
    pub fn describe(counts: &[usize; JointMiss::COUNT]) -> String {
        Self::ALL
            .iter()
            .zip(counts)
            .filter(|&(_, &c)| c > 0)
            .map(|(m, c)| format!("{} {c}", m.as_str().replace('_', " ")))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The name written in files (`wrong_type`, ...).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::WrongType => "wrong_type",
            Self::ChildMissing => "child_missing",
            Self::ParentMissing => "parent_missing",
            Self::Reversed => "reversed",
            Self::ChildSplit => "child_split",
            Self::ChildIsRoot => "child_is_root",
            Self::OnGrandparent => "on_grandparent",
            Self::OnSibling => "on_sibling",
            Self::OnDescendant => "on_descendant",
            Self::OnOther => "on_other",
            Self::RootNotFree => "root_not_free",
        }
    }
}

/// The comparison of a model with the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// Adjusted Rand index of the segmentation over the points visible in at least two frames
    /// (a point seen once or never cannot be placed by any method).
    pub ari: f64,
    /// Number of points the ARI is computed over.
    pub n_points_scored: usize,
    /// Number of true bodies.
    pub n_bodies_true: usize,
    /// Number of bodies found.
    pub n_bodies_found: usize,
    /// The right number of bodies (each the majority of a different true body), the true base
    /// static, and every joint found between the right bodies with its type; points may
    /// still be misassigned.
    pub joints_exact: bool,
    /// `joints_exact` and every point on its true body (ARI 1).
    pub structure_exact: bool,
    /// Per true joint.
    pub joints: Vec<JointEval>,
}

/// The true body holding most of each model body's points (the lower id on a tie). A body
/// without points (a link no keypoint shows, put in by the model between two bodies) stands
/// for the true body between the ones its parent and its child stand for, where the truth has
/// one there; otherwise for body 0.
pub fn body_map(model: &Model, truth: &GroundTruth) -> Vec<usize> {
    let mut map: Vec<usize> = model
        .bodies
        .iter()
        .map(|b| {
            let mut votes = vec![0usize; truth.n_bodies()];
            for &p in &b.points {
                votes[truth.point_body[p]] += 1;
            }
            (0..votes.len())
                .max_by_key(|&k| (votes[k], std::cmp::Reverse(k)))
                .unwrap_or(0)
        })
        .collect();
    for (b, body) in model.bodies.iter().enumerate() {
        if !body.points.is_empty() {
            continue;
        }
        let parent = body.parent.map(|p| map[p]);
        let child = model
            .joints
            .iter()
            .find(|j| j.parent == b)
            .map(|j| map[j.child]);
        let between = truth.mechanism.joints.iter().find(|above| {
            Some(above.parent) == parent
                && truth
                    .mechanism
                    .joints
                    .iter()
                    .any(|below| below.parent == above.child && Some(below.child) == child)
        });
        if let Some(j) = between {
            map[b] = j.child;
        }
    }
    map
}

/// The rigid transform from model body `body`'s frame to true body `true_body`'s frame, by
/// Kabsch over the body's placed points that truly belong to `true_body` (reference shape
/// against the true body-frame keypoints). `None` with fewer than three such points or when
/// they are nearly collinear.
fn parent_alignment(
    model: &Model,
    truth: &GroundTruth,
    body: usize,
    true_body: usize,
) -> Option<Isometry3<f64>> {
    let b = model.bodies.get(body)?;
    shape_alignment(
        &b.points,
        b.shape.iter().map(|s| s.map(Point3::from)),
        truth,
        true_body,
    )
}

/// The true body frame of `true_body` from an estimated body frame whose points `points` have
/// the positions `shape` (`None` where not placed): Kabsch-Umeyama on the points of the true
/// body; `None` for fewer than three non-collinear ones.
pub(crate) fn shape_alignment(
    points: &[usize],
    shape: impl Iterator<Item = Option<Point3<f64>>>,
    truth: &GroundTruth,
    true_body: usize,
) -> Option<Isometry3<f64>> {
    let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = points
        .iter()
        .zip(shape)
        .filter(|(p, _)| truth.point_body.get(**p) == Some(&true_body))
        .filter_map(|(p, s)| Some((s?, truth.body_points[*p])))
        .unzip();
    kinetree_core::geom::kabsch_with_rank_check(&src, &dst, 1e-3)
}

/// Compares `model` with `truth`.
pub fn evaluate(model: &Model, truth: &GroundTruth) -> Evaluation {
    let scored: Vec<usize> = (0..truth.point_body.len())
        .filter(|&i| truth.visible_frames[i] >= 2)
        .collect();
    let pred: Vec<i64> = scored.iter().map(|&i| model.point_body[i]).collect();
    let true_labels: Vec<usize> = scored.iter().map(|&i| truth.point_body[i]).collect();
    let ari = adjusted_rand_index(&pred, &true_labels);
    let map = body_map(model, truth);
    let mut joints = Vec::new();
    // A base without keypoints is the world a floating mechanism moves in: no body is
    // static, the root's joint is free, and the tree may hang from any body, so joints are
    // matched in either direction.
    let mut has_points = vec![false; truth.n_bodies()];
    for &b in &truth.point_body {
        has_points[b] = true;
    }
    let floating = !has_points[0];
    let n_seen = has_points.iter().filter(|&&h| h).count();
    let root_ok = if floating {
        model.static_body.is_none() && model.root_joint() == RootJoint::Free
    } else {
        model.static_body.is_some_and(|s| map[s] == 0)
    };
    // Bodies without keypoints that the model put in where the truth has one.
    let unseen_matched = model
        .bodies
        .iter()
        .filter(|b| b.points.is_empty() && !has_points[map[b.id]])
        .count();
    let mut all_ok = model.bodies.len() == n_seen + unseen_matched && root_ok && {
        let mut m = map.clone();
        m.sort_unstable();
        m.dedup();
        m.len() == model.bodies.len()
    };
    for (k, spec) in truth.mechanism.joints.iter().enumerate() {
        let mut found = model
            .joints
            .iter()
            .find(|j| map[j.parent] == spec.parent && map[j.child] == spec.child);
        let mut reversed = false;
        if floating && found.is_none() {
            found = model
                .joints
                .iter()
                .find(|j| map[j.parent] == spec.child && map[j.child] == spec.parent);
            reversed = found.is_some();
        }
        // The true body that the model joint's parent stands for.
        let parent_body = if reversed { spec.child } else { spec.parent };
        let mut e = JointEval {
            joint: k,
            found: found.is_some(),
            type_ok: false,
            axis_error_deg: None,
            pivot_error_m: None,
            axis_error_in_parent_deg: None,
            pivot_error_in_parent_m: None,
            axis_z: None,
            pivot_z: None,
            centre_z: None,
            position_rms: None,
            position_std_rms: None,
            position_z_rms: None,
            smoothed_rms: None,
            smoothed_z_rms: None,
            centre_error_m: None,
            centre_error_in_parent_m: None,
            second_axis_error_in_parent_deg: None,
            second_axis_error_in_child_deg: None,
            second_axis_z: None,
            model_type: None,
            miss: None,
        };
        if spec.joint_type == JointType::Free {
            // A free joint from the unseen world is the model's free root; from a seen body
            // (a subject moving freely past a static scene), a multi-DoF joint between the two
            // bodies, the model's way of saying no joint holds them (the tests can see fewer
            // than six DoF where a coordinate barely moves).
            e.found = if floating {
                spec.parent == 0 && root_ok
            } else {
                found.is_some_and(|j| j.joint_type == kinetree_core::model::JointType::MultiDof)
            };
            e.type_ok = e.found;
        } else if let Some(j) = found {
            let expected = match spec.joint_type {
                JointType::Revolute => Some(kinetree_core::model::JointType::Revolute),
                JointType::Prismatic => Some(kinetree_core::model::JointType::Prismatic),
                JointType::Spherical => Some(kinetree_core::model::JointType::Spherical),
                JointType::Universal => Some(kinetree_core::model::JointType::Universal),
                JointType::Free => None,
            };
            e.type_ok = expected == Some(j.joint_type);
            let true_axis = truth.axis_in_camera(k, j.reference_frame);
            if let Some(a) = j.axis {
                e.axis_error_deg = Some(axis_error_deg(&Vector3::from(a), &true_axis));
                if let (Some(p), JointType::Revolute) = (j.point, spec.joint_type) {
                    let anchor = truth.anchor_in_camera(k, j.reference_frame);
                    e.pivot_error_m = Some(point_line_distance(
                        &anchor,
                        &Point3::from(p),
                        &Vector3::from(a),
                    ));
                }
            }
            let true_axis = Vector3::from(spec.axis).normalize();
            // The model parent's reference shape on its true body, once for every in-parent
            // error below.
            let align = parent_alignment(model, truth, j.parent, parent_body);
            if let (Some(a), Some(align)) = (j.axis_in_parent, align) {
                let a = align.rotation * Vector3::from(a);
                e.axis_error_in_parent_deg = Some(axis_error_deg(&a, &true_axis));
                if let (Some(p), JointType::Revolute) = (j.point_in_parent, spec.joint_type) {
                    e.pivot_error_in_parent_m = Some(point_line_distance(
                        &Point3::from(spec.anchor),
                        &(align * Point3::from(p)),
                        &a,
                    ));
                }
            }
            let per_std = |error: Option<f64>, std: Option<f64>| {
                error.zip(std.filter(|&s| s > 0.0)).map(|(e, s)| e / s)
            };
            e.axis_z = per_std(e.axis_error_in_parent_deg, j.axis_std_deg);
            e.pivot_z = per_std(e.pivot_error_in_parent_m, j.pivot_std_m);
            let centred = matches!(spec.joint_type, JointType::Spherical | JointType::Universal);
            if centred && let Some(p) = j.point {
                let centre = truth.anchor_in_camera(k, j.reference_frame);
                e.centre_error_m = Some((Point3::from(p) - centre).norm());
            }
            if centred && let (Some(p), Some(align)) = (j.point_in_parent, align) {
                let centre = align * Point3::from(p);
                e.centre_error_in_parent_m = Some((centre - Point3::from(spec.anchor)).norm());
            }
            e.centre_z = per_std(e.centre_error_in_parent_m, j.centre_std_m);
            // A universal joint's second axis where the model's reference frame holds it: the
            // true one turned by the true first angle there (not compared on a reversed joint,
            // whose first axis is the true second one).
            if let (JointType::Universal, false, Some(a), Some(second), Some(align)) = (
                spec.joint_type,
                reversed,
                j.second_axis_in_parent,
                spec.second_axis,
                align,
            ) {
                let at = truth.mechanism.coordinate_offsets()[k];
                let q1 = truth.joint_positions[at][j.reference_frame];
                let turned = nalgebra::UnitQuaternion::from_axis_angle(
                    &nalgebra::Unit::new_normalize(Vector3::from(spec.axis)),
                    q1,
                ) * Vector3::from(second).normalize();
                e.second_axis_error_in_parent_deg = Some(axis_error_deg(
                    &(align.rotation * Vector3::from(a)),
                    &turned,
                ));
            }
            // The second axis is fixed in the child, where the truth's zero configuration
            // holds it.
            if let (JointType::Universal, false, Some(a), Some(second), Some(zero)) = (
                spec.joint_type,
                reversed,
                j.second_axis_in_parent,
                spec.second_axis,
                j.reference_pose.and_then(|r| r.to_isometry()),
            ) && let Some(align) = parent_alignment(model, truth, j.child, spec.child)
            {
                let in_child = align.rotation * (zero.rotation.inverse() * Vector3::from(a));
                e.second_axis_error_in_child_deg = Some(axis_error_deg(
                    &in_child,
                    &Vector3::from(second).normalize(),
                ));
                e.second_axis_z = per_std(e.second_axis_error_in_child_deg, j.second_axis_std_deg);
            }
            if let Some(q) = truth.single_positions(k) {
                e.position_rms = aligned_rms(&j.positions, q);
                (e.position_std_rms, e.position_z_rms) =
                    precision_check(&j.positions, &j.position_std, q).unzip();
                e.smoothed_rms = aligned_rms(&j.smoothed_positions, q);
                e.smoothed_z_rms =
                    precision_check(&j.smoothed_positions, &j.smoothed_std, q).map(|(_, z)| z);
            }
        }
        e.model_type = found.map(|j| j.joint_type);
        if !(e.found && e.type_ok) {
            e.miss = Some(miss(model, truth, &map, k, floating, found.is_some()));
        }
        all_ok &= e.found && e.type_ok;
        joints.push(e);
    }
    Evaluation {
        ari,
        n_points_scored: scored.len(),
        n_bodies_true: truth.n_bodies(),
        n_bodies_found: model.bodies.len(),
        joints_exact: all_ok,
        structure_exact: all_ok && (ari - 1.0).abs() < 1e-12,
        joints,
    }
}

/// Why true joint `k` is not right ([`JointMiss`]), `map` from [`body_map`]; `joined` when a
/// model joint links the two bodies.
fn miss(
    model: &Model,
    truth: &GroundTruth,
    map: &[usize],
    k: usize,
    floating: bool,
    joined: bool,
) -> JointMiss {
    let spec = &truth.mechanism.joints[k];
    if floating && spec.joint_type == JointType::Free {
        return JointMiss::RootNotFree;
    }
    if joined {
        return JointMiss::WrongType;
    }
    let standing_for = |t: usize| (0..map.len()).filter(move |&b| map[b] == t);
    let children: Vec<usize> = standing_for(spec.child).collect();
    let Some(&child) = children.first() else {
        return JointMiss::ChildMissing;
    };
    if standing_for(spec.parent).next().is_none() {
        return JointMiss::ParentMissing;
    }
    if model
        .joints
        .iter()
        .any(|j| map[j.parent] == spec.child && map[j.child] == spec.parent)
    {
        return JointMiss::Reversed;
    }
    if children.len() > 1 {
        return JointMiss::ChildSplit;
    }
    let Some(on) = model
        .joints
        .iter()
        .find(|j| j.child == child)
        .map(|j| map[j.parent])
    else {
        return JointMiss::ChildIsRoot;
    };
    let true_parent = |b: usize| truth.mechanism.parent_of(b);
    if true_parent(spec.parent) == Some(on) {
        return JointMiss::OnGrandparent;
    }
    if true_parent(on) == Some(spec.parent) {
        return JointMiss::OnSibling;
    }
    // Up from `on` through the true tree (a tree: at most one step per body).
    let mut up = Some(on);
    for _ in 0..truth.n_bodies() {
        match up {
            Some(b) if b == spec.child => return JointMiss::OnDescendant,
            Some(b) => up = true_parent(b),
            None => break,
        }
    }
    JointMiss::OnOther
}

/// Checks that `model` was discovered on tracks of `truth`'s keypoints and frames, and that
/// `truth` holds together, so that [`evaluate`] can compare them.
///
/// # Errors
/// [`Error::Malformed`] naming the field of the truth that does not fit, or
/// [`Error::Config`] for a mechanism that is not a tree.
pub fn check_comparable(model: &Model, truth: &GroundTruth) -> Result<()> {
    truth.mechanism.validate()?;
    let bad = |position: &str, message: String| Error::Malformed {
        position: position.into(),
        message,
    };
    let n = truth.point_body.len();
    if model.point_body.len() != n {
        return Err(bad(
            "point_body",
            format!("has {n} keypoints, the model {}", model.point_body.len()),
        ));
    }
    for (field, len) in [
        ("visible_frames", truth.visible_frames.len()),
        ("body_points", truth.body_points.len()),
    ] {
        if len != n {
            return Err(bad(field, format!("has {len} entries for {n} keypoints")));
        }
    }
    let bodies = truth.n_bodies();
    if let Some(i) = truth.point_body.iter().position(|&b| b >= bodies) {
        return Err(bad(
            &format!("point_body[{i}]"),
            format!("is body {}, of {bodies}", truth.point_body[i]),
        ));
    }
    let coordinates = truth.mechanism.n_coordinates();
    if truth.joint_positions.len() != coordinates {
        return Err(bad(
            "joint_positions",
            format!(
                "has {} rows for the mechanism's {coordinates} coordinates",
                truth.joint_positions.len()
            ),
        ));
    }
    if let Some(i) = truth
        .joint_positions
        .iter()
        .position(|q| q.len() != model.n_frames)
    {
        return Err(bad(
            &format!("joint_positions[{i}]"),
            format!(
                "has {} frames, the model {}",
                truth.joint_positions[i].len(),
                model.n_frames
            ),
        ));
    }
    Ok(())
}

/// Points that no method can place: their noisy track fits another body's *true* motion as
/// well as noise allows (`chi^2 / k` under the Wilson-Hilferty bound at 4 standard deviations,
/// `k = 3 (frames - 1)`, per-coordinate noise `sigma_m`). Typically a point within a few noise
/// std-devs of a joint axis, or a body that barely moved while the point was visible. Points
/// seen in fewer than two frames are counted here too.
pub fn ambiguous_points(tracks: &Tracks, truth: &GroundTruth, sigma_m: f64) -> Vec<bool> {
    let sigma2 = sigma_m.max(1e-9).powi(2);
    let nb = truth.n_bodies();
    let cam_from_body: Vec<Vec<nalgebra::Isometry3<f64>>> = (0..tracks.n_frames())
        .map(|t| {
            let q: Vec<f64> = truth.joint_positions.iter().map(|p| p[t]).collect();
            truth
                .mechanism
                .forward(&q)
                .iter()
                .map(|w| truth.cam_from_world * w)
                .collect()
        })
        .collect();
    (0..tracks.n_points())
        .map(|i| {
            let seen: Vec<(usize, Point3<f64>)> = (0..tracks.n_frames())
                .filter_map(|t| tracks.get(t, i).map(|p| (t, p)))
                .collect();
            if seen.len() < 2 {
                return true;
            }
            let k = 3.0 * (seen.len() - 1) as f64;
            let bound = kinetree_core::stats::chi2_per_dof_quantile(k, 4.0);
            (0..nb).filter(|&b| b != truth.point_body[i]).any(|b| {
                let z: Vec<Vector3<f64>> = seen
                    .iter()
                    .map(|(t, p)| cam_from_body[*t][b].inverse_transform_point(p).coords)
                    .collect();
                let mean = z.iter().sum::<Vector3<f64>>() / z.len() as f64;
                let chi2 = z.iter().map(|v| (v - mean).norm_squared()).sum::<f64>() / sigma2;
                chi2 / k <= bound
            })
        })
        .collect()
}

/// Adjusted Rand index of the model's segmentation over the points that are not
/// [`ambiguous_points`].
pub fn identifiable_ari(model: &Model, truth: &GroundTruth, ambiguous: &[bool]) -> f64 {
    let keep: Vec<usize> = (0..truth.point_body.len())
        .filter(|&i| !ambiguous.get(i).copied().unwrap_or(true))
        .collect();
    let predicted: Vec<i64> = keep.iter().map(|&i| model.point_body[i]).collect();
    let t: Vec<usize> = keep.iter().map(|&i| truth.point_body[i]).collect();
    adjusted_rand_index(&predicted, &t)
}
