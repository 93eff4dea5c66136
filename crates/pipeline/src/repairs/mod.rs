//! The built-in repairs, one file each, and their configuration (`[pipeline.repairs.<name>]`).
//!
//! Adding a repair: a file here with a params struct (`Default` with `enabled: true`, serde
//! with `deny_unknown_fields`, `validate()`) and the [`Repair`] impl, and a line in the
//! `repairs_config!` list below (its place is the order within the phase). Every built-in
//! repair goes through [`crate::conformance::check_repair`] in `tests/tests/repairs.rs`.

mod attach;
mod balls;
mod bundle_adjust;
mod drop_unposed;
mod eject_points;
mod free_joints;
mod hinge_groups;
mod hinges;
mod joint_spoilers;
mod merge;
mod move_points;
mod noise_refinement;
mod readmit_joints;
mod regroup;
mod reroute;
mod retest;
mod share_points;
mod sibling_ties;
mod split;
mod tree_ties;
mod type_by_fit;

pub use attach::{Attach, AttachParams};
pub use balls::{BallBounds, BallGroups, BallGroupsParams, Balls, BallsParams};
pub use bundle_adjust::{BundleAdjust, BundleAdjustParams};
pub use drop_unposed::{DropUnposed, DropUnposedParams};
pub use eject_points::{EjectPoints, EjectPointsParams};
pub use free_joints::{FreeJoints, FreeJointsParams};
pub use hinge_groups::{HingeGroups, HingeGroupsParams};
pub use hinges::{HingeBounds, Hinges, HingesParams};
pub use joint_spoilers::{JointSpoilers, JointSpoilersParams};
pub use merge::{Merge, MergeParams};
pub use move_points::{MovePoints, MovePointsParams};
pub use noise_refinement::{NoiseRefinement, NoiseRefinementParams};
pub use readmit_joints::{ReadmitJoints, ReadmitJointsParams};
pub use regroup::{Regroup, RegroupParams};
pub use reroute::{Reroute, RerouteParams};
pub use retest::{Retest, RetestParams};
pub use share_points::{SharePoints, SharePointsParams};
pub use sibling_ties::{SiblingTies, SiblingTiesParams};
pub use split::{Split, SplitParams};
pub use tree_ties::{TreeTies, TreeTiesParams};
pub use type_by_fit::{TypeByFit, TypeByFitParams};

use kinetree_core::{
    BodyPoses, BodyTrack, ClusteringInput, DissimilarityMatrix, Draft, Error, Model, ModelDraft,
    ModelMaker, PoseInput, Repair, RepairContext, Result, Segmentation, Tracks,
};
use serde::{Deserialize, Serialize};

/// Declares [`RepairsConfig`] from one list of `field: Params => Repair`, so that its fields,
/// their validation, the repairs built from them and `all_off` cannot disagree.
macro_rules! repairs_config {
    ($($(#[doc = $doc:expr])* $field:ident: $params:ident => $repair:ident,)*) => {
        /// Every built-in repair's parameters (`[pipeline.repairs.<name>]`), in the order the
        /// runner asks the repairs within a phase. Each has `enabled` and the thresholds it
        /// uses; defaults are the documented values.
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
        #[serde(deny_unknown_fields, default)]
        pub struct RepairsConfig {
            $($(#[doc = $doc])* pub $field: $params,)*
        }

        impl RepairsConfig {
            /// The built-in repairs' names, in order.
            pub const NAMES: &'static [&'static str] = &[$(stringify!($field)),*];

            /// Checks every repair's parameters.
            ///
            /// # Errors
            /// [`Error::InvalidParameter`] naming `pipeline.repairs.<name>.<parameter>`.
            pub fn validate(&self) -> Result<()> {
                $(self.$field.validate()?;)*
                Ok(())
            }

            /// The enabled repairs, in order.
            ///
            /// # Errors
            /// As [`RepairsConfig::validate`].
            pub fn build(&self) -> Result<Vec<Box<dyn Repair>>> {
                self.validate()?;
                let mut out: Vec<Box<dyn Repair>> = Vec::new();
                $(if self.$field.enabled {
                    out.push(Box::new($repair::new(self.$field)?));
                })*
                Ok(out)
            }

            /// Every repair turned off.
            pub fn all_off() -> Self {
                let mut c = Self::default();
                $(c.$field.enabled = false;)*
                c
            }
        }
    };
}

repairs_config! {
    /// Grouping: the estimated noise level refined inside the bodies found.
    noise_refinement: NoiseRefinementParams => NoiseRefinement,
    /// Bodies: bodies registered in few frames posed through a hinge.
    hinges: HingesParams => Hinges,
    /// Bodies: bodies registered in few frames posed through a ball joint.
    balls: BallsParams => Balls,
    /// Bodies: bodies registered in too few frames dropped.
    drop_unposed: DropUnposedParams => DropUnposed,
    /// Bodies: bodies that mix points of several bodies split in two.
    split: SplitParams => Split,
    /// Bodies: points on no body attached where one body's poses explain them.
    attach: AttachParams => Attach,
    /// Bodies: unassigned points that move as one rigid body made one.
    regroup: RegroupParams => Regroup,
    /// Bodies: clusters too small for a pose made bodies with other bodies' points rigid
    /// with them, which then belong to both.
    share_points: SharePointsParams => SharePoints,
    /// Bodies: unassigned points that turn together on a hinge made a body.
    hinge_groups: HingeGroupsParams => HingeGroups,
    /// Bodies: clusters too small for a pose whose points turn about a point of a body made
    /// bodies.
    ball_groups: BallGroupsParams => BallGroups,
    /// Bodies: bodies that move rigidly together merged.
    merge: MergeParams => Merge,
    /// Tree: near-tied tree edges settled by whole-tree fits.
    tree_ties: TreeTiesParams => TreeTies,
    /// Tree: a body that moves with its parent about one axis hung on the grandparent when a
    /// whole-tree fit fits both trees alike.
    sibling_ties: SiblingTiesParams => SiblingTies,
    /// Fit: joints the whole-tree fit cannot follow freed.
    free_joints: FreeJointsParams => FreeJoints,
    /// Fit: the followed joints bundle-adjusted over every frame.
    bundle_adjust: BundleAdjustParams => BundleAdjust,
    /// Fit: freed joints put back when they fit again.
    readmit_joints: ReadmitJointsParams => ReadmitJoints,
    /// Fit: multi-DoF and freed joints typed by the fit.
    type_by_fit: TypeByFitParams => TypeByFit,
    /// Points: points another body's fitted motion explains better moved there.
    move_points: MovePointsParams => MovePoints,
    /// Points: points that fit no body's motion left on none.
    eject_points: EjectPointsParams => EjectPoints,
    /// Points: a keypoint that alone makes a joint multi-DoF left on none.
    joint_spoilers: JointSpoilersParams => JointSpoilers,
    /// Model: pair tests redone on the whole-tree fit's poses.
    retest: RetestParams => Retest,
    /// Model: the model made again without the edges of joints its fit misses by far.
    reroute: RerouteParams => Reroute,
}

/// Checks that `value` is finite and within `[min, max]`.
pub(crate) fn in_range(repair: &str, name: &str, value: f64, min: f64, max: f64) -> Result<()> {
    kinetree_core::limits::check_within(
        &format!("pipeline.repairs.{repair}.{name}"),
        value,
        min,
        max,
    )
}

/// Checks that a count is within `[min, max]`.
pub(crate) fn count_in_range(
    repair: &str,
    name: &str,
    value: usize,
    min: usize,
    max: usize,
) -> Result<()> {
    count_within(
        &format!("pipeline.repairs.{repair}.{name}"),
        value,
        min,
        max,
    )
}

/// Checks that the count at the config key `key` (its whole dotted path) is within
/// `[min, max]`.
pub(crate) fn count_within(key: &str, value: usize, min: usize, max: usize) -> Result<()> {
    kinetree_core::limits::check_count(key, value, min, max)
}

/// The draft's poses, or a typed error naming the repair that needed them.
pub(crate) fn poses_of<'a>(repair: &str, poses: Option<&'a BodyPoses>) -> Result<&'a BodyPoses> {
    poses.ok_or_else(|| Error::Degenerate(format!("repair `{repair}` needs the draft's poses")))
}

/// What a tree repair compares trees with: the model maker, the draft's model, its poses and
/// pair tests, or a typed error naming `repair`.
pub(crate) fn tree_inputs<'a>(
    repair: &str,
    ctx: &RepairContext<'a>,
    draft: &'a Draft,
) -> Result<(
    &'a dyn ModelMaker,
    &'a ModelDraft,
    &'a BodyPoses,
    &'a [kinetree_core::PairDof],
)> {
    match (
        ctx.models,
        draft.model.as_ref(),
        draft.poses.as_ref(),
        draft.pairs.as_ref(),
    ) {
        (Some(models), Some(first), Some(poses), Some(pairs)) => Ok((models, first, poses, pairs)),
        _ => Err(Error::Degenerate(format!(
            "repair `{repair}` needs a model, its poses and pair tests"
        ))),
    }
}

/// The fit ratio of a pair whose tests call it rigid within their bounds: a rigid pair's, or
/// that of a slide the chi-square rule found under its bound (`hidden_slide_ratio`: no
/// rotation, and a translation within its rank-0 bound), which moves by no more than the
/// model error allowed for and so may be two parts of one body; `None` for other pairs.
pub(crate) fn rigid_within_bounds(p: &kinetree_core::PairDof) -> Option<f64> {
    match p.joint {
        kinetree_core::JointKind::Rigid => Some(p.fit_ratio),
        kinetree_core::JointKind::Prismatic { .. } if p.rotation.rank == 0 => {
            let (&s, &b) = (
                p.translation.chi2_per_dof.first()?,
                p.translation.chi2_bound.first()?,
            );
            (b > 0.0 && s <= b).then(|| p.rotation.next_rank_ratio().max(s / b))
        }
        _ => None,
    }
}

/// Whether the model of `after` stands against that of `before`: no more doubtful joints, and
/// a re-prediction RMS that `accept(after's, before's)` takes.
pub(crate) fn tree_stands(
    before: &Draft,
    after: &Draft,
    accept: impl Fn(f64, f64) -> bool,
) -> bool {
    let (Some(b), Some(a)) = (before.model.as_ref(), after.model.as_ref()) else {
        return false;
    };
    let (alt, model) = (&a.model, &b.model);
    doubtful_joints(alt) <= doubtful_joints(model)
        && matches!(
            (alt.reprediction_rms_in_sigma, model.reprediction_rms_in_sigma),
            (Some(x), Some(m)) if accept(x, m)
        )
}

/// The keypoints' squared residual of a plain whole-tree fit of every frame.
pub(crate) fn plain_sse(model: &Model, tracks: &Tracks) -> Result<f64> {
    let fits = kinetree_fit::Observer::new(model)?.fit_sequence(tracks)?;
    Ok(fits.iter().map(|f| f.sum_sq_m2).sum())
}

/// The dissimilarities among `points` (unknown pairs NaN), with the matrix's cut and measure.
fn sub_matrix(dmat: &DissimilarityMatrix, points: &[usize]) -> DissimilarityMatrix {
    let mut values = Vec::with_capacity(kinetree_core::n_pairs(points.len()));
    for (x, &i) in points.iter().enumerate() {
        for &j in &points[x + 1..] {
            values.push(dmat.get(i, j).unwrap_or(f64::NAN));
        }
    }
    DissimilarityMatrix {
        n_points: points.len(),
        values,
        suggested_cut: dmat.suggested_cut,
        measure: dmat.measure.clone(),
    }
}

/// The two halves of `points` by the `halves` slot on their own sub-matrix (each of at least
/// three points; fewer halves when a side is smaller).
pub(crate) fn halves(ctx: &RepairContext<'_>, points: &[usize]) -> Result<Vec<Vec<usize>>> {
    cut_in_two(ctx, &sub_matrix(ctx.dissimilarity, points), points)
}

/// The two halves of `points` by the `halves` slot on `sub`, a matrix over `points` in their
/// order (each half of at least three points; fewer halves when a side is smaller).
pub(crate) fn cut_in_two(
    ctx: &RepairContext<'_>,
    sub: &DissimilarityMatrix,
    points: &[usize],
) -> Result<Vec<Vec<usize>>> {
    let parts = ctx.stages.halves.cluster(&ClusteringInput {
        dissimilarity: sub,
        seed: 0,
        pair_frames: None,
    })?;
    Ok(parts
        .members()
        .iter()
        .map(|m| m.iter().map(|&x| points[x]).collect())
        .collect())
}

/// Mean dissimilarity over the observed pairs between two groups of points; `None` when no
/// pair was observed.
pub(crate) fn mean_cross(m: &DissimilarityMatrix, a: &[usize], b: &[usize]) -> Option<f64> {
    let (mut sum, mut count) = (0.0, 0usize);
    for &i in a {
        for &j in b {
            if let Some(d) = m.get(i, j) {
                sum += d;
                count += 1;
            }
        }
    }
    (count > 0).then(|| sum / count as f64)
}

/// `points` posed by the pose slot as one body by themselves; `None` when the stage returns
/// no body.
pub(crate) fn posed_as_one(ctx: &RepairContext<'_>, points: &[usize]) -> Result<Option<BodyTrack>> {
    let mut raw = vec![None; ctx.tracks.n_points()];
    for &p in points {
        raw[p] = Some(0);
    }
    let fitted = ctx.stages.pose.estimate(&PoseInput {
        tracks: ctx.tracks,
        segmentation: &Segmentation::from_raw(&raw, 1),
        noise_sigma_m: ctx.noise_sigma_m,
    })?;
    Ok(fitted.bodies.into_iter().next())
}

/// Whether `points` fit as one rigid body: their median pose residual, posed alone, is at most
/// `residual_in_sigma` noise std-devs.
pub(crate) fn points_fit_as_one(
    ctx: &RepairContext<'_>,
    points: &[usize],
    residual_in_sigma: f64,
) -> Result<bool> {
    Ok(posed_as_one(ctx, points)?
        .as_ref()
        .and_then(BodyTrack::median_residual_m)
        .is_some_and(|r| r <= residual_in_sigma * ctx.noise_sigma_m))
}

/// Whether the pairwise measure keeps the two halves of `points` apart: the mean
/// dissimilarity across the halves of [`halves`] (a side under three points being the rest) is
/// above the measure's cut. `false` when no half has three points.
///
/// The pose fit of a group alone misses points of two bodies that are seldom seen together:
/// its median residual comes from the frames that show one body's points only (see
/// `docs/decisions.md`, `regroup`).
pub(crate) fn halves_apart(ctx: &RepairContext<'_>, points: &[usize]) -> Result<bool> {
    let parts = halves(ctx, points)?;
    let (a, b) = match parts.as_slice() {
        [a, b] => (a.clone(), b.clone()),
        [a] => {
            let rest = points.iter().filter(|p| !a.contains(p)).copied().collect();
            (a.clone(), rest)
        }
        _ => return Ok(false),
    };
    let dmat = ctx.dissimilarity;
    Ok(mean_cross(dmat, &a, &b).is_some_and(|d| d > dmat.suggested_cut))
}

/// `seg` with each of `groups` (points on no body) made a body of its own.
pub(crate) fn with_new_bodies(seg: &Segmentation, groups: &[Vec<usize>]) -> Segmentation {
    let mut labels = seg.labels().to_vec();
    for (k, g) in groups.iter().enumerate() {
        for &p in g {
            labels[p] = Some(seg.n_bodies() + k);
        }
    }
    let grouped: Vec<usize> = groups.iter().flatten().copied().collect();
    let mut out = Segmentation::from_raw(&labels, 1).with_shared_of(seg, &labels);
    out.discarded_groups = seg.discarded_groups_without(&grouped);
    out
}

/// The groups of `points` (ascending) that `accept` takes: a group it refuses is split in two
/// by the `halves` slot and each part tried, down to `min_points`. Sorted.
pub(crate) fn accepted_groups(
    ctx: &RepairContext<'_>,
    points: Vec<usize>,
    min_points: usize,
    mut accept: impl FnMut(&[usize]) -> Result<bool>,
) -> Result<Vec<Vec<usize>>> {
    let mut stack = vec![points];
    let mut out = Vec::new();
    while let Some(group) = stack.pop() {
        if group.len() < min_points {
            continue;
        }
        if accept(&group)? {
            out.push(group);
            continue;
        }
        let parts = halves(ctx, &group)?;
        if parts.len() == 1 && parts[0].len() == group.len() {
            continue;
        }
        stack.extend(parts);
    }
    out.sort();
    Ok(out)
}

/// Points on no body that are seen in at least `min_visible` frames.
pub(crate) fn unassigned_points(
    tracks: &Tracks,
    seg: &Segmentation,
    min_visible: usize,
) -> Vec<usize> {
    (0..tracks.n_points())
        .filter(|&i| seg.body_of(i).is_none() && tracks.visible_count(i) >= min_visible)
        .collect()
}

/// The draft's model, or a typed error naming `repair`.
pub(crate) fn model_of<'a>(
    repair: &str,
    draft: &'a kinetree_core::Draft,
) -> Result<&'a kinetree_core::ModelDraft> {
    draft
        .model
        .as_ref()
        .ok_or_else(|| Error::Degenerate(format!("repair `{repair}` needs a model")))
}

/// The whole-tree fit of `m`: the cached one when it is still the model's, else made anew.
pub(crate) fn fit_state(
    ctx: &RepairContext<'_>,
    m: &kinetree_core::ModelDraft,
) -> Result<kinetree_fit::FitState> {
    let cached = m
        .cache
        .as_ref()
        .and_then(|c| c.downcast_ref::<kinetree_fit::FitState>())
        .filter(|s| s.is_of(&m.model));
    match cached {
        Some(s) => Ok(s.clone()),
        None => kinetree_fit::FitState::new(&m.model, ctx.tracks),
    }
}

/// A fit repair's proposal: `step` refits a copy of the draft's model from its whole-tree fit
/// and returns the new fit with the joints it changed (`None`: nothing changed). The proposal
/// carries the refitted model with its fit cached, and its summary (`summary` of the number
/// of joints) names them.
pub(crate) fn refit(
    repair: &str,
    ctx: &RepairContext<'_>,
    draft: &kinetree_core::Draft,
    step: impl FnOnce(
        &mut Model,
        kinetree_fit::FitState,
    ) -> Result<(kinetree_fit::FitState, Option<Vec<usize>>)>,
    summary: impl FnOnce(usize) -> String,
) -> Result<Option<kinetree_core::Proposal>> {
    let found = model_of(repair, draft)?;
    let state = fit_state(ctx, found)?;
    let mut model = found.model.clone();
    let (state, changed) = step(&mut model, state)?;
    let Some(joints) = changed else {
        return Ok(None);
    };
    let summary = summary(joints.len());
    Ok(Some(fit_proposal(found, model, state, summary, &joints)))
}

/// A fit repair's proposal: `model` (a refit of `found`'s) with its fit `state` cached; the
/// summary names the joints (`parent->child`, model ids) of `joints`.
fn fit_proposal(
    found: &kinetree_core::ModelDraft,
    model: Model,
    state: kinetree_fit::FitState,
    summary: String,
    joints: &[usize],
) -> kinetree_core::Proposal {
    let named: Vec<String> = joints
        .iter()
        .filter_map(|&k| model.joints.get(k))
        .map(|j| format!("{}->{}", j.parent, j.child))
        .collect();
    let summary = if named.is_empty() {
        summary
    } else {
        format!("{summary}: {}", named.join(", "))
    };
    let draft = kinetree_core::ModelDraft {
        model,
        body_order: found.body_order.clone(),
        fitted: None,
        history: found.history.clone(),
        cache: Some(std::sync::Arc::new(state)),
    };
    kinetree_core::Proposal::new(kinetree_core::Edit::Fit(Box::new(draft)), summary)
}

/// Joints of `m` typed multi-DoF, spherical or universal: a small body's noisy poses can fake
/// a second rotation, and every hinge has a fixed centre and fits two intersecting axes, so
/// a hinge seen so comes out spherical or universal.
pub(crate) fn multi_dof_joints(m: &Model) -> usize {
    use kinetree_core::model::JointType;
    m.joints
        .iter()
        .filter(|j| {
            matches!(
                j.joint_type,
                JointType::MultiDof | JointType::Spherical | JointType::Universal
            )
        })
        .count()
}

/// Joints of `m` its whole-tree fit typed.
pub(crate) fn typed_by_fit(m: &Model) -> usize {
    m.joints
        .iter()
        .filter(|j| j.fit == kinetree_core::model::JointFit::TypedByFit)
        .count()
}

/// The joints of `model` its whole-tree fit does not follow, as `(parent, child)` model body
/// ids.
pub(crate) fn not_followed(model: &Model) -> Vec<(usize, usize)> {
    model
        .joints
        .iter()
        .filter(|j| j.fit == kinetree_core::model::JointFit::Freed)
        .map(|j| (j.parent, j.child))
        .collect()
}

/// Joints of `m` that are multi-DoF or spherical, not followed by its whole-tree fit, or typed
/// by it.
pub(crate) fn doubtful_joints(m: &Model) -> usize {
    multi_dof_joints(m) + not_followed(m).len() + typed_by_fit(m)
}

/// The frames `track` is registered in, when that is at most `max_share` of the frames that
/// show one of its keypoints: a body the `hinges` and `balls` repairs may pose through a joint.
pub(crate) fn sparsely_registered(
    tracks: &Tracks,
    track: &BodyTrack,
    max_share: f64,
) -> Option<usize> {
    let shown = (0..tracks.n_frames())
        .filter(|&t| track.points.iter().any(|&i| tracks.get(t, i).is_some()))
        .count();
    let own = track.n_registered();
    (own as f64 <= max_share * shown as f64).then_some(own)
}

/// `points` paired greedily in order: each with the first later point `rigid` with it, the
/// two then taken out. Two markers of a segment the clustering left apart become a pair.
pub(crate) fn rigid_pairs(
    mut points: Vec<usize>,
    rigid: impl Fn(usize, usize) -> bool,
) -> Vec<Vec<usize>> {
    let mut pairs = Vec::new();
    while !points.is_empty() {
        let a = points.remove(0);
        if let Some(k) = points.iter().position(|&b| rigid(a, b)) {
            pairs.push(vec![a, points.remove(k)]);
        }
    }
    pairs
}
