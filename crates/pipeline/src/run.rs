//! Running the pipeline on tracks: segmentation, poses, DoF tests, structure, model.

use crate::config::{NoiseEstimator, PipelineConfig};
use kinetree_core::geom::cam_from;
use kinetree_core::model::{
    Body, Joint, NoiseInfo, NoiseSource, Ranks, RigidTransform, SCHEMA_VERSION, StageNames,
};
use kinetree_core::{
    BodyPoses, BodyTrack, Clustering, ClusteringInput, Dissimilarity, DissimilarityInput,
    DissimilarityMatrix, DofInput, DofTester, Error, JointKind, Model, PairDof, PairStats,
    PoseEstimator, PoseInput, Result, Segmentation, Tracks, Warning,
};
use kinetree_dissimilarity::{
    estimate_noise_sigma, estimate_noise_sigma_nearest_rigid, pair_stats, refine_noise_sigma,
};
use kinetree_structure::FittedMotions;
use rayon::prelude::*;

/// The stages, built from a [`PipelineConfig`] or supplied by the caller.
#[derive(Debug)]
pub struct Pipeline {
    /// Dissimilarity measure.
    pub dissimilarity: Box<dyn Dissimilarity>,
    /// Clustering method.
    pub clustering: Box<dyn Clustering>,
    /// Pose estimator.
    pub pose: Box<dyn PoseEstimator>,
    /// DoF tester.
    pub dof: Box<dyn DofTester>,
    /// Per-coordinate noise, metres; estimated when `None`.
    pub noise_sigma_m: Option<f64>,
    /// How the noise is estimated when `noise_sigma_m` is `None`.
    pub noise_estimator: NoiseEstimator,
    /// Seed for the stages.
    pub seed: u64,
    /// Whether links seen too few keypoints at a time are posed through hinges (see
    /// [`PipelineConfig::hinged_bodies`]).
    pub hinged_bodies: bool,
}

/// Everything a run produces: the model and the intermediate results behind it.
#[derive(Debug, Clone)]
pub struct Discovery {
    /// The model (bodies renumbered in tree order).
    pub model: Model,
    /// Pair statistics.
    pub stats: PairStats,
    /// The dissimilarity matrix used for the final segmentation.
    pub dissimilarity: DissimilarityMatrix,
    /// Final segmentation (segmentation numbering).
    pub segmentation: Segmentation,
    /// Poses per body (segmentation numbering).
    pub poses: BodyPoses,
    /// `model body id -> segmentation body id`.
    pub body_order: Vec<usize>,
}

/// Stage 1's results ([`Pipeline::group`]): what [`Pipeline::run`] builds the bodies from.
#[derive(Debug, Clone)]
pub struct Grouping {
    /// Pair statistics.
    pub stats: PairStats,
    /// Per-coordinate noise, metres (given, or estimated and refined).
    pub noise_sigma_m: f64,
    /// Whether the noise level was given or estimated.
    pub noise_source: NoiseSource,
    /// The dissimilarity matrix at that noise level.
    pub dissimilarity: DissimilarityMatrix,
    /// The clustering's bodies (before any pose, split or point move).
    pub segmentation: Segmentation,
    /// Warnings so far: points never visible or never paired, inferred pairs, the noise
    /// estimate, discarded clusters.
    pub warnings: Vec<Warning>,
}

/// A discovery's own parts, before the pair statistics and the matrix join them.
#[derive(Debug)]
struct Found {
    model: Model,
    body_order: Vec<usize>,
    segmentation: Segmentation,
    poses: BodyPoses,
    /// The segmentation's warnings the model was made with (its own come on top).
    history: Vec<Warning>,
}

/// Tree edges whose child another body reaches at an edge cost at most this much higher are
/// near ties, settled by whole-tree fits. 0.05 of cost is 0.1 of fit ratio; the tie that
/// motivated the rule was 5e-4 (see `Pipeline::model`). A first choice, not tuned.
const TREE_TIE_MARGIN: f64 = 0.05;
/// Most near-tied edges tried per model (each costs a whole-tree fit of every frame).
const MAX_TREE_ALTERNATIVES: usize = 3;
/// Near ties are looked for only in models of at most this many bodies: on a 21-body tree
/// (the noise test's scene, 1 mm, seed 3) the alternatives' fits took the discovery from
/// 48 s to 93 s with no joint gained (release build, one run each).
const MAX_TIE_BODIES: usize = 12;
/// An alternative tree replaces the model when its keypoints' re-prediction RMS is lower by
/// this fraction (first in a plain whole-tree fit, then finished).
const TREE_TIE_GAIN: f64 = 0.02;

/// A group of keypoints is posed through a hinge when it fits it within this bound on
/// `chi^2 / dof` (Wilson-Hilferty at 4 std-devs, times this slack for the approximations of
/// the predicted variance; the same rule as `kinetree_pose::attach_unassigned`'s).
const HINGE_SLACK: f64 = 2.0;
/// ... and its angle sweeps at least this many std-devs of one frame's angle: below, the
/// group hardly turns and the hinge's axis is a guess.
const MIN_HINGE_ARC_IN_STD: f64 = 20.0;
/// ... and its keypoints' RMS distance from where the hinge puts them is at most this many
/// noise std-devs: the `chi^2` counts the parent's pose noise at each keypoint's lever arm,
/// so a poorly posed parent passes almost any hinge (a link 20 mm RMS off a sibling's hinge
/// passed at 1.8 against a bound of 2.6); pure keypoint noise gives about sqrt 3.
const MAX_HINGE_RMS_IN_SIGMA: f64 = 3.0;
/// A body registered in at most this share of the frames that show one of its keypoints is
/// tried for a hinge (`Pipeline::reposed_through_hinges`) ...
const MAX_REPOSED_SHARE: f64 = 0.5;
/// ... and posed through it when that poses it in at least this many times as many frames.
const MIN_REPOSE_GAIN: f64 = 1.5;

/// Joints of `m` that are multi-DoF, not followed by its whole-tree fit, or typed by it.
fn doubtful_joints(m: &Model) -> usize {
    multi_dof_joints(m) + not_followed(m).len() + typed_by_fit(m)
}

/// Joints of `m` typed multi-DoF.
fn multi_dof_joints(m: &Model) -> usize {
    m.joints
        .iter()
        .filter(|j| j.joint_type == "multi_dof")
        .count()
}

/// Joints of `m` its whole-tree fit typed (a `joint_typed_by_fit` warning).
fn typed_by_fit(m: &Model) -> usize {
    m.warnings
        .iter()
        .filter(|w| matches!(w, Warning::JointTypedByFit { .. }))
        .count()
}

/// How many times a model's fitted motions may move points to another body before the
/// bodies are redone ([`kinetree_structure::FittedMotions::points_fitting_another_body`]).
const MODEL_PASSES: usize = 2;
/// How many times rigidly co-moving bodies are merged and the poses redone.
const MAX_MERGE_ROUNDS: usize = 3;
/// Observed pairs a point needs with a body to be judged against it.
const REASSIGN_MIN_PAIRS: usize = 2;
/// Largest relative change the within-body refinement may make to the first noise guess.
const REFINE_LIMIT: f64 = 0.1;
/// Noise re-estimation rounds after segmentation.
const NOISE_ROUNDS: usize = 2;

/// A body whose median fit residual exceeds this many noise std-devs mixes points of bodies
/// that move apart. With the reference shapes refined by Gauss-Newton (session 9), the
/// discovered bodies of 60 random mechanisms (3-7 joints, 20 % occlusion) with points of one
/// true body fitted at a median 1.21 sigma and at most 1.42 (1.99 before the refinement).
/// 3.0 -> 2.5: one more run of the occlusion sweep with every joint right, none lost in any
/// sweep; at 2.0 the tennis serve's segments were split (ARI against its segment notes
/// 1.0 -> 0.92, re-prediction 2.3 -> 3.6 sigma): markers on skin are not rigid.
const SPLIT_RESIDUAL_IN_SIGMA: f64 = 2.5;
/// Rounds of splitting before giving up (a non-rigid body would otherwise be split forever).
const MAX_SPLIT_ROUNDS: usize = 8;

/// Splits every body that mixes bodies: its median fit residual is over
/// [`SPLIT_RESIDUAL_IN_SIGMA`], its two halves (average linkage on the body's own sub-matrix,
/// cut into two clusters; a side of fewer than three points is discarded) are apart on
/// average in the pairwise measure, or the halves, posed as bodies of their own
/// (`pose_halves`), fit its points far better than the body does ([`halves_fit_better`]).
/// The two parts, by one point each, go into `cannot_link` so the rigid merge does not
/// rejoin them (a part with poor poses can "test rigid" against a body it moves against).
/// Returns `None` when no body needs splitting.
fn split_mixed_bodies(
    dmat: &DissimilarityMatrix,
    seg: &Segmentation,
    poses: &BodyPoses,
    sigma: f64,
    warnings: &mut Vec<Warning>,
    cannot_link: &mut Vec<(usize, usize)>,
    pose_halves: impl FnOnce(&Segmentation) -> Result<BodyPoses>,
) -> Result<Option<Segmentation>> {
    let mut labels: Vec<Option<usize>> = seg.labels().to_vec();
    let mut next_id = seg.n_bodies();
    let mut any = false;
    let mut candidates: Vec<(usize, f64, Vec<Vec<usize>>, bool)> = Vec::new();
    for (b, track) in poses.bodies.iter().enumerate() {
        let Some(residual) = track.median_residual_m() else {
            continue;
        };
        let ratio = residual / sigma;
        if track.points.len() < 4 {
            continue;
        }
        let parts = halves(dmat, &track.points)?;
        if parts.is_empty() {
            continue;
        }
        // The pairwise measure keeps the two parts apart, as the merge guard would.
        let apart = match &parts[..] {
            [first, second] => {
                mean_cross(dmat, first, second).is_some_and(|d| d > dmat.suggested_cut)
            }
            _ => false,
        };
        candidates.push((b, ratio, parts, ratio > SPLIT_RESIDUAL_IN_SIGMA || apart));
    }
    // The halves of the other bodies, posed as bodies of their own: a split whose two rigid
    // fits explain the points far better than the one of the union (see
    // `halves_fit_better`).
    let undecided: Vec<usize> = (0..candidates.len())
        .filter(|&c| !candidates[c].3 && candidates[c].2.len() == 2)
        .collect();
    if !undecided.is_empty() {
        let mut half_labels: Vec<Option<usize>> = vec![None; labels.len()];
        for (k, &c) in undecided.iter().enumerate() {
            for (h, part) in candidates[c].2.iter().enumerate() {
                for &i in part {
                    half_labels[i] = Some(2 * k + h);
                }
            }
        }
        let halves_seg = Segmentation::from_raw(&half_labels, 1);
        let half_poses = pose_halves(&halves_seg)?;
        let index_of = |point: usize| {
            half_poses
                .bodies
                .iter()
                .position(|t| t.points.binary_search(&point).is_ok())
        };
        for &c in &undecided {
            let (b, _, parts, _) = &candidates[c];
            let (Some(ia), Some(ib)) = (index_of(parts[0][0]), index_of(parts[1][0])) else {
                continue;
            };
            let (first, second) = (&half_poses.bodies[ia], &half_poses.bodies[ib]);
            if !halves_fit_better(&poses.bodies[*b], first, second, sigma) {
                continue;
            }
            candidates[c].3 = true;
        }
    }
    for (b, ratio, parts, split) in candidates {
        if !split {
            continue;
        }
        let pts = &poses.bodies[b].points;
        any = true;
        warnings.push(Warning::BodySplit {
            points: pts.clone(),
            residual_in_sigma: ratio,
        });
        // A side under three points is left unassigned.
        for &i in pts {
            labels[i] = None;
        }
        for (k, part) in parts.iter().enumerate() {
            for &i in part {
                labels[i] = Some(if k == 0 { b } else { next_id });
            }
        }
        if let [first, second] = &parts[..] {
            cannot_link.push((first[0], second[0]));
        }
        next_id += 1;
    }
    if !any {
        return Ok(None);
    }
    let mut out = Segmentation::from_raw(&labels, kinetree_core::MIN_BODY_POINTS);
    out.discarded_groups
        .extend(seg.discarded_groups.iter().cloned());
    out.discarded_groups.sort();
    Ok(Some(out))
}

/// Whether a body's two halves, each posed as a rigid body, explain its points better than
/// the body's own poses by more than two extra poses could: over the frames where all three
/// are posed, the drop in the sum of squared residuals, in noise variances, against the
/// chi-square bound with 6 degrees of freedom per frame (the second half's pose) at 4
/// standard deviations, times [`SPLIT_LR_SLACK`].
///
/// A 3.9 cm, 6-point slider merged with the 18.5 cm link that turns on it by +-0.65 rad
/// (rate-test case 178, 2 mm of noise): the union fits at a median 1.5 sigma (the split
/// threshold is 3) and the mean dissimilarity between the halves is under the cut, yet the
/// halves' fits lower the residual by about 3 times the 6 variances per frame an extra pose
/// buys.
fn halves_fit_better(
    union: &kinetree_core::BodyTrack,
    first: &kinetree_core::BodyTrack,
    second: &kinetree_core::BodyTrack,
    sigma: f64,
) -> bool {
    let sse = |q: &kinetree_core::PoseQuality| q.rms_residual_m.powi(2) * q.n_visible as f64;
    let (mut drop, mut frames) = (0.0, 0usize);
    for t in 0..union.quality.len() {
        let (Some(u), Some(a), Some(b)) = (
            union.quality[t],
            first.quality.get(t).copied().flatten(),
            second.quality.get(t).copied().flatten(),
        ) else {
            continue;
        };
        if u.n_visible != a.n_visible + b.n_visible {
            continue;
        }
        drop += sse(&u) - sse(&a) - sse(&b);
        frames += 1;
    }
    let share = frames as f64 / union.n_registered().max(1) as f64;
    if frames < kinetree_structure::MIN_FRAMES || share < MIN_SPLIT_FRAME_SHARE || sigma <= 0.0 {
        return false;
    }
    let k = 6.0 * frames as f64;
    drop / (sigma * sigma) / k
        > SPLIT_LR_SLACK * kinetree_core::stats::chi2_per_dof_quantile(k, 4.0)
}

/// [`halves_fit_better`] judges a body only on the frames where both halves are posed; under
/// this share of the body's registered frames, a half rests on a point seen in few frames,
/// and the split is left to the fitted motions' point moves. On the mechanisms sweep a point
/// of another link, seen in 17 of 200 frames, sat in a body registered in 116; the halves'
/// fits over those 17 frames were far better (5.2 against a bound of 1.7 per degree of
/// freedom), but average linkage had put two of the body's own points in its half, and the
/// split cost the run its ARI of 1 (the model's fit moved the point home without it). Case
/// 178 of the rate test, a true merge, was judged on half its body's frames.
const MIN_SPLIT_FRAME_SHARE: f64 = 0.25;

/// Slack on the chi-square bound of [`halves_fit_better`] for the approximations behind it
/// (reference shapes estimated from the same frames, an estimated noise level).
const SPLIT_LR_SLACK: f64 = 1.6;

/// The bodies of `model` a split made: all their points were in one body a `body_split`
/// warning names.
fn split_born(model: &Model) -> Vec<usize> {
    let splits: Vec<&Vec<usize>> = model
        .warnings
        .iter()
        .filter_map(|w| match w {
            Warning::BodySplit { points, .. } => Some(points),
            _ => None,
        })
        .collect();
    (0..model.bodies.len())
        .filter(|&b| {
            let points = &model.bodies[b].points;
            splits
                .iter()
                .any(|s| points.iter().all(|p| s.binary_search(p).is_ok()))
        })
        .collect()
}

/// The joints of `model` its whole-tree fit does not follow (named by a `joint_not_followed`
/// warning), as `(parent, child)` model body ids.
fn not_followed(model: &Model) -> Vec<(usize, usize)> {
    model
        .warnings
        .iter()
        .filter_map(|w| match w {
            Warning::JointNotFollowed { parent, child, .. } => Some((*parent, *child)),
            _ => None,
        })
        .filter(|&(p, c)| model.joints.iter().any(|j| j.parent == p && j.child == c))
        .collect()
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

/// The two halves of `points` by average linkage on their own sub-matrix (each of at least
/// three points; fewer halves when a side is smaller).
fn halves(dmat: &DissimilarityMatrix, points: &[usize]) -> Result<Vec<Vec<usize>>> {
    let splitter =
        kinetree_clustering::Hierarchical::new(kinetree_clustering::HierarchicalParams {
            n_clusters: Some(2),
            ..kinetree_clustering::HierarchicalParams::default()
        })?;
    let parts = splitter.cluster(&ClusteringInput {
        dissimilarity: &sub_matrix(dmat, points),
        seed: 0,
    })?;
    Ok(parts
        .members()
        .iter()
        .map(|m| m.iter().map(|&x| points[x]).collect())
        .collect())
}

/// Whether the pairwise measure keeps the two halves of `points` apart, as [`pairwise_apart`]
/// keeps bodies apart: the mean dissimilarity across the halves of [`halves`] (a side under
/// three points being the rest) is above the measure's cut. `false` when no half has three
/// points.
///
/// The pose fit of a group alone misses points of two bodies that are seldom seen together:
/// its median residual comes from the frames that show one body's points only. Measured: five
/// points left over from two links turning on the base, each seen in 10-70 of 200 frames, fitted
/// as one at a median under 2.5 sigma with q = 1.00 on four of the eight observed cross pairs;
/// the made-up body became the parent of six links (mechanisms sweep, 10-joint revolute tree,
/// seed 5).
fn halves_apart(dmat: &DissimilarityMatrix, points: &[usize]) -> Result<bool> {
    let parts = halves(dmat, points)?;
    let (a, b) = match parts.as_slice() {
        [a, b] => (a.clone(), b.clone()),
        [a] => {
            let rest = points.iter().filter(|p| !a.contains(p)).copied().collect();
            (a.clone(), rest)
        }
        _ => return Ok(false),
    };
    Ok(mean_cross(dmat, &a, &b).is_some_and(|d| d > dmat.suggested_cut))
}

/// `seg` with each of `groups` (points on no body) made a body of its own.
fn with_new_bodies(seg: &Segmentation, groups: &[Vec<usize>]) -> Segmentation {
    let mut labels = seg.labels().to_vec();
    for (k, g) in groups.iter().enumerate() {
        for &p in g {
            labels[p] = Some(seg.n_bodies() + k);
        }
    }
    let grouped: Vec<usize> = groups.iter().flatten().copied().collect();
    let mut out = Segmentation::from_raw(&labels, 1);
    out.discarded_groups = seg.discarded_groups_without(&grouped);
    out
}

/// The groups of `points` (ascending) that `accept` takes: a group it refuses is split in two
/// by the dissimilarity (`halves`) and each part tried, down to `min_points`. Sorted.
fn accepted_groups(
    dmat: &DissimilarityMatrix,
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
        let parts = halves(dmat, &group)?;
        if parts.len() == 1 && parts[0].len() == group.len() {
            continue;
        }
        stack.extend(parts);
    }
    out.sort();
    Ok(out)
}

/// How poorly a body is posed, and how far it travels: the median over its registered frames
/// of its rotation's standard deviation per unit noise (infinite when never registered), and
/// the path length of its origin over its registered frames. Both depend on the body's
/// keypoints, their visibility and motion, not on how the bodies or points are numbered, where
/// the camera is, or which way time runs.
fn pose_spread(track: &BodyTrack) -> (f64, f64) {
    let Some(spread) = track.median_quality(|q| q.rot_std_per_sigma) else {
        return (f64::INFINITY, 0.0);
    };
    let origins: Vec<_> = track
        .cam_from_body
        .iter()
        .flatten()
        .map(|p| p.translation.vector)
        .collect();
    let travel = origins.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    (spread, travel)
}

/// The pair of bodies `i`, `j` as `(frame, moving)`: `j` is the frame when it is better
/// posed, or equally well posed (within rounding) and travels less; else `i`. Exact ties keep
/// `i` (identical bodies moving identically).
fn frame_and_moving(spread: &[(f64, f64)], i: usize, j: usize) -> (usize, usize) {
    let differs = |a: f64, b: f64| (a - b).abs() > 1e-9 * a.abs().max(b.abs());
    let ((si, ti), (sj, tj)) = (spread[i], spread[j]);
    let j_first = if differs(si, sj) {
        sj < si
    } else if differs(ti, tj) {
        tj < ti
    } else {
        false
    };
    if j_first { (j, i) } else { (i, j) }
}

/// Pairs of bodies the pairwise measure keeps apart: the mean dissimilarity over their
/// observed cross pairs is above the measure's cut. The rigid merge never joins them.
///
/// The pose-based DoF test carries a slack for model error, so it can call a small, barely
/// moving body rigid to its parent; the distance F-test has no such slack and sees the motion
/// plainly. Measured: a 15 cm, 6-point link swinging +-5 deg at 1 mm noise had q = 1.00 on
/// most cross pairs while the rotation test gave chi2/dof 1.3 against a bound of 3.3, and the
/// merge undid a correct segmentation. A body the clusterer split by mistake has cross pairs
/// near q = 0.5 and still merges.
fn pairwise_apart(m: &DissimilarityMatrix, seg: &Segmentation) -> Vec<(usize, usize)> {
    let members = seg.members();
    let mut out = Vec::new();
    for a in 0..members.len() {
        for b in a + 1..members.len() {
            if mean_cross(m, &members[a], &members[b]).is_some_and(|d| d > m.suggested_cut) {
                out.push((a, b));
            }
        }
    }
    out
}

/// Mean dissimilarity over the observed pairs between two groups of points; `None` when no
/// pair was observed.
fn mean_cross(m: &DissimilarityMatrix, a: &[usize], b: &[usize]) -> Option<f64> {
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

/// Groups of bodies to merge because they move rigidly together: complete linkage over the
/// `Rigid` body pairs, clearest first. Two groups merge only when every pair across them
/// tests rigid, so one body with poor poses (which "tests rigid" against everything because
/// its noise hides all motion) cannot chain unrelated bodies together. Bodies listed together
/// in `forbidden` (parts of an earlier split) never end in one group. Returns a group id per
/// body.
fn rigid_groups(n_bodies: usize, pairs: &[PairDof], forbidden: &[(usize, usize)]) -> Vec<usize> {
    let rigid = |a: usize, b: usize| {
        pairs.iter().any(|p| {
            matches!(p.joint, JointKind::Rigid)
                && ((p.a == Some(a) && p.b == b) || (p.a == Some(b) && p.b == a))
        })
    };
    let mut candidates: Vec<&PairDof> = pairs
        .iter()
        .filter(|p| p.a.is_some() && matches!(p.joint, JointKind::Rigid))
        .collect();
    candidates.sort_by(|x, y| {
        x.fit_ratio
            .total_cmp(&y.fit_ratio)
            .then((x.a, x.b).cmp(&(y.a, y.b)))
    });
    let mut group: Vec<usize> = (0..n_bodies).collect();
    for p in candidates {
        let Some(a) = p.a else { continue };
        let (ga, gb) = (group[a], group[p.b]);
        if ga == gb {
            continue;
        }
        let in_a: Vec<usize> = (0..n_bodies).filter(|&b| group[b] == ga).collect();
        let in_b: Vec<usize> = (0..n_bodies).filter(|&b| group[b] == gb).collect();
        let all_rigid = in_a.iter().all(|&x| in_b.iter().all(|&y| rigid(x, y)));
        let split_before = forbidden.iter().any(|&(p, q)| {
            (in_a.contains(&p) && in_b.contains(&q)) || (in_a.contains(&q) && in_b.contains(&p))
        });
        let all_rigid = all_rigid && !split_before;
        if all_rigid {
            for g in &mut group {
                if *g == gb {
                    *g = ga;
                }
            }
        }
    }
    group
}

/// The keypoint of `points` (posed through `hinge`) that does not turn with it, if one
/// clearly does not: the hinge refitted on the same parent without it lowers the `chi^2` by
/// more than the bound of [`best_hinge`] allows for the degrees of freedom it had (the
/// worst such keypoint); never one of `done`, and never from a body of three or fewer.
///
/// A keypoint of a poorly seen link clustered onto its neighbour rides along when the
/// neighbour is posed through its hinge, since the fit weighs it by its few frames; the
/// neighbour's joint then tests multi-DoF. Measured: the mechanisms sweep's 10-joint revolute
/// tree, seed 13: a keypoint seen in 15 of 200 frames, on a link hinged to the base, raised
/// the hinge's `chi^2` by 567 for its 39 degrees of freedom (the rest fit at 0.91 per degree
/// of freedom) and made that link's joint and its child's 5-DoF; hidden, every joint of the
/// tree is right.
fn off_hinge_point(
    tracks: &Tracks,
    poses: &BodyPoses,
    points: &[usize],
    hinge: &kinetree_pose::Hinge,
    sigma: f64,
    done: &[usize],
) -> Option<usize> {
    if points.len() <= kinetree_core::MIN_BODY_POINTS {
        return None;
    }
    let chi2 = hinge.chi2_per_dof * hinge.dof;
    points
        .iter()
        .filter(|p| !done.contains(p))
        .filter_map(|&p| {
            let rest: Vec<usize> = points.iter().copied().filter(|&q| q != p).collect();
            let without = kinetree_pose::hinged_body(tracks, poses, hinge.parent, &rest, sigma)?;
            let dof = hinge.dof - without.dof;
            let gain = (chi2 - without.chi2_per_dof * without.dof) / dof;
            (dof >= 1.0 && gain > kinetree_pose::misfit_bound(dof, 4.0, HINGE_SLACK))
                .then_some((gain, p))
        })
        .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)))
        .map(|(_, p)| p)
}

/// Of the hinges of `group` on the posed bodies other than `skip` and on the camera frame
/// that hold (within [`HINGE_SLACK`] of the noise, the group rigid, at most
/// [`MAX_HINGE_RMS_IN_SIGMA`] off, sweeping [`MIN_HINGE_ARC_IN_STD`]), the one that explains
/// the keypoints best (lowest RMS residual, then the most frames posed). A true hinge on a
/// body's parent, child or the camera gives the same poses, but a body turning about an
/// axis 3 deg from its sibling's through one anchor also fits a hinge on the sibling within
/// the `chi^2` bound; its residual is larger (2.9 mm against 1.6-1.7 mm at 1 mm noise).
fn best_hinge(
    tracks: &Tracks,
    poses: &BodyPoses,
    group: &[usize],
    skip: Option<usize>,
    sigma: f64,
) -> Option<kinetree_pose::Hinge> {
    // The group's rigidity does not depend on the parent: checked once, first.
    let (rigidity, rigidity_dof) = kinetree_pose::group_rigidity(tracks, group, sigma);
    if rigidity > kinetree_pose::misfit_bound(rigidity_dof, 4.0, HINGE_SLACK) {
        return None;
    }
    std::iter::once(None)
        .chain((0..poses.bodies.len()).map(Some))
        .filter(|&parent| parent.is_none() || parent != skip)
        .filter_map(|parent| kinetree_pose::hinged_body(tracks, poses, parent, group, sigma))
        .filter(|h| {
            h.chi2_per_dof <= kinetree_pose::misfit_bound(h.dof, 4.0, HINGE_SLACK)
                && h.arc_in_std >= MIN_HINGE_ARC_IN_STD
                && h.rms_residual_m <= MAX_HINGE_RMS_IN_SIGMA * sigma
        })
        .min_by(|x, y| {
            x.rms_residual_m
                .total_cmp(&y.rms_residual_m)
                .then(y.track.n_registered().cmp(&x.track.n_registered()))
        })
}

impl Pipeline {
    /// Builds every stage from a config.
    ///
    /// # Errors
    /// When a stage's parameters are invalid or the noise level is not positive.
    pub fn from_config(c: &PipelineConfig) -> Result<Self> {
        if let Some(s) = c.noise_sigma_m
            && !(s.is_finite() && s > 0.0)
        {
            return Err(Error::InvalidParameter {
                name: "noise_sigma_m".into(),
                message: format!("must be finite and positive, got {s}"),
            });
        }
        Ok(Self {
            dissimilarity: c.dissimilarity.build()?,
            clustering: c.clustering.build()?,
            pose: c.pose.build()?,
            dof: c.dof.build()?,
            noise_sigma_m: c.noise_sigma_m,
            noise_estimator: c.noise_estimator,
            seed: c.seed,
            hinged_bodies: c.hinged_bodies,
        })
    }

    fn segment(
        &self,
        tracks: &Tracks,
        stats: &PairStats,
        sigma: f64,
    ) -> Result<(DissimilarityMatrix, Segmentation)> {
        let d = self.dissimilarity.compute(&DissimilarityInput {
            tracks,
            stats,
            noise_sigma_m: sigma,
        })?;
        let s = self.clustering.cluster(&ClusteringInput {
            dissimilarity: &d,
            seed: self.seed,
        })?;
        let s = kinetree_clustering::reassign_points(&d, &s, d.suggested_cut, REASSIGN_MIN_PAIRS);
        Ok((d, s))
    }

    /// Every pair's DoF test: each body against the camera frame, and each pair of bodies
    /// with the better-posed one as the frame (see [`pose_spread`] and [`frame_and_moving`]). The
    /// test of `b` in `a`'s frame is not that of `a` in `b`'s (the frame's rotation noise acts
    /// at the lever arm of the other's origin), so the direction must not follow the body
    /// numbering, which follows the order of the points: with the lower index as the frame,
    /// permuting the points changed the tree on 7 of 200 random mechanisms.
    fn all_pairs(&self, poses: &BodyPoses, sigma: f64) -> Result<Vec<PairDof>> {
        let input = DofInput {
            poses,
            noise_sigma_m: sigma,
        };
        let n = poses.bodies.len();
        let spread: Vec<(f64, f64)> = poses.bodies.iter().map(pose_spread).collect();
        // Every body against the camera, then every pair in the frame of the one whose poses
        // are the steadier. The tests are independent: run in parallel, kept in this order.
        let mut pairs: Vec<(Option<usize>, usize)> = (0..n).map(|b| (None, b)).collect();
        for i in 0..n {
            for j in i + 1..n {
                let (frame, moving) = frame_and_moving(&spread, i, j);
                pairs.push((Some(frame), moving));
            }
        }
        let tested: Vec<Result<Option<PairDof>>> = pairs
            .par_iter()
            .map(|&(a, b)| match self.dof.test_pair(&input, a, b) {
                Ok(p) => Ok(Some(p)),
                Err(Error::Degenerate(_)) => Ok(None),
                Err(e) => Err(e),
            })
            .collect();
        let mut out = Vec::new();
        for t in tested {
            out.extend(t?);
        }
        Ok(out)
    }

    /// Groups of at least three points the segmentation left unassigned that move as one rigid
    /// body ([`Pipeline::points_fit_as_one`]): all of them if they do, else each half by
    /// average linkage, and so on down. The pairwise measure can break a small body apart (4
    /// points have 6 pairs, and with the F-test's `q` uniform on rigid pairs a point's mean to
    /// the others is over the cut one time in a dozen); its poses still show one body.
    fn regroup_unassigned(
        &self,
        tracks: &Tracks,
        dmat: &DissimilarityMatrix,
        seg: &Segmentation,
        sigma: f64,
    ) -> Result<Vec<Vec<usize>>> {
        let left: Vec<usize> = (0..tracks.n_points())
            .filter(|&i| seg.body_of(i).is_none() && tracks.visible_count(i) >= 2)
            .collect();
        accepted_groups(dmat, left, kinetree_core::MIN_BODY_POINTS, |group| {
            Ok(!halves_apart(dmat, group)? && self.points_fit_as_one(tracks, group, sigma)?)
        })
    }

    /// Whether the union of `bodies` fits as one rigid body: its median pose residual stays
    /// within [`SPLIT_RESIDUAL_IN_SIGMA`] noise std-devs.
    fn fits_as_one(
        &self,
        tracks: &Tracks,
        poses: &BodyPoses,
        bodies: &[usize],
        sigma: f64,
    ) -> Result<bool> {
        let points: Vec<usize> = bodies
            .iter()
            .flat_map(|&b| poses.bodies[b].points.iter().copied())
            .collect();
        self.points_fit_as_one(tracks, &points, sigma)
    }

    /// Whether `points` fit as one rigid body (as [`Pipeline::fits_as_one`]).
    fn points_fit_as_one(&self, tracks: &Tracks, points: &[usize], sigma: f64) -> Result<bool> {
        Ok(self
            .posed_as_one(tracks, points, sigma)?
            .as_ref()
            .and_then(BodyTrack::median_residual_m)
            .is_some_and(|r| r <= SPLIT_RESIDUAL_IN_SIGMA * sigma))
    }

    /// `points` posed by the pipeline's pose stage as one body by themselves; `None` when the
    /// stage returns no body.
    fn posed_as_one(
        &self,
        tracks: &Tracks,
        points: &[usize],
        sigma: f64,
    ) -> Result<Option<BodyTrack>> {
        let mut raw = vec![None; tracks.n_points()];
        for &p in points {
            raw[p] = Some(0);
        }
        let fitted = self.pose.estimate(&PoseInput {
            tracks,
            segmentation: &Segmentation::from_raw(&raw, 1),
            noise_sigma_m: sigma,
        })?;
        Ok(fitted.bodies.into_iter().next())
    }

    /// Stage 1 alone: the pair statistics, the noise level (given, or estimated and then
    /// refined on the pairs inside the bodies it yields), the dissimilarity matrix and the
    /// clustering. [`Pipeline::run`] starts from exactly this; a caller who only needs the
    /// bodies or the noise level is spared the poses, tests and whole-tree fits.
    ///
    /// # Errors
    /// As [`Pipeline::run`]'s first stage: bad tracks, a failing stage, no noise estimate.
    pub fn group(&self, tracks: &Tracks) -> Result<Grouping> {
        let mut warnings = Vec::new();
        let n = tracks.n_points();
        let visible: Vec<usize> = (0..n).map(|i| tracks.visible_count(i)).collect();
        for (i, &v) in visible.iter().enumerate() {
            if v == 0 {
                warnings.push(Warning::PointNeverVisible { point: i });
            }
        }
        let stats = pair_stats(tracks);
        let mut paired = vec![false; n];
        for i in 0..n {
            for j in i + 1..n {
                if stats.count(i, j) >= 2 {
                    paired[i] = true;
                    paired[j] = true;
                }
            }
        }
        for (i, &p) in paired.iter().enumerate() {
            if !p && visible[i] > 0 {
                warnings.push(Warning::PointUnpaired { point: i });
            }
        }
        let unknown_among_paired = (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .filter(|&(i, j)| paired[i] && paired[j] && stats.count(i, j) < 2)
            .count();
        if unknown_among_paired > 0 {
            warnings.push(Warning::PairsInferred {
                count: unknown_among_paired,
            });
        }
        let (mut sigma, noise_source) = match (self.noise_sigma_m, self.noise_estimator) {
            (Some(s), _) => (s, NoiseSource::Given),
            (None, NoiseEstimator::Mode) => (estimate_noise_sigma(&stats)?, NoiseSource::Estimated),
            (None, NoiseEstimator::NearestRigid) => (
                estimate_noise_sigma_nearest_rigid(&stats)?,
                NoiseSource::Estimated,
            ),
        };
        let (mut dmat, mut seg) = self.segment(tracks, &stats, sigma)?;
        if noise_source == NoiseSource::Estimated && self.noise_estimator == NoiseEstimator::Mode {
            let first_guess = sigma;
            for _ in 0..NOISE_ROUNDS {
                let Some(s) = refine_noise_sigma(&stats, &seg) else {
                    break;
                };
                // The refinement fine-tunes the first guess from the pairs inside bodies. When
                // bodies are merged, moving pairs inflate it, the F-test then merges more, and
                // the loop runs away (x3.3 measured on 25-body scenes at 10 mm), so it may move
                // the first guess by at most REFINE_LIMIT.
                let s = s.clamp(
                    first_guess * (1.0 - REFINE_LIMIT),
                    first_guess * (1.0 + REFINE_LIMIT),
                );
                let changed = (s / sigma - 1.0).abs() > 0.01;
                sigma = s;
                if !changed {
                    break;
                }
                (dmat, seg) = self.segment(tracks, &stats, sigma)?;
            }
        }
        if noise_source == NoiseSource::Estimated {
            warnings.push(Warning::NoiseEstimated { sigma_m: sigma });
        }
        for g in &seg.discarded_groups {
            warnings.push(Warning::ClusterDiscarded { points: g.clone() });
        }
        Ok(Grouping {
            stats,
            noise_sigma_m: sigma,
            noise_source,
            dissimilarity: dmat,
            segmentation: seg,
            warnings,
        })
    }

    /// Discovers the model of `tracks`: [`Pipeline::group`], then the bodies' poses, the pair
    /// tests, the tree and the whole-tree fit, with points moved between bodies over passes.
    ///
    /// # Errors
    /// [`Error::Degenerate`] when no body can be found or registered, and any stage's error.
    pub fn run(&self, tracks: &Tracks) -> Result<Discovery> {
        let Grouping {
            stats,
            noise_sigma_m: sigma,
            noise_source: source,
            dissimilarity: dmat,
            segmentation: mut seg,
            warnings,
        } = self.group(tracks)?;
        // Bodies, their poses and pair tests, then the model. Once a model exists, points that
        // another body's fitted motion explains better are moved there and the bodies redone,
        // at most MODEL_PASSES times; a pass stands only if the moved points then fit their
        // new bodies best (a point moved wrongly, once in 200 mechanisms, then fitted its new
        // body at chi2/dof 4.3 against 2.9 for its old one). A model left with nothing to move
        // but with multi-DoF joints is rebuilt on pair tests of its whole-tree fit's poses when
        // that removes some (`retest_on_fitted_poses`), and the rebuilt model's fit may move
        // points in turn (a wrong tree had hidden them). The segmentation's history (splits,
        // merges, moves) accumulates over the passes; the model's own warnings are made anew
        // by each.
        let mut history = warnings;
        let mut previous: Option<Found> = None;
        let mut moved: Vec<usize> = Vec::new();
        // Points a model found fitting no body's motion: not attached again by their poses.
        let mut unassigned: Vec<usize> = Vec::new();
        let mut pass = 0;
        let found = loop {
            let (bodies, poses, pairs) =
                self.bodies(tracks, &dmat, seg, sigma, &mut history, &unassigned)?;
            let mut found = self.model(
                tracks,
                &dmat,
                bodies,
                poses,
                pairs,
                sigma,
                source,
                history.clone(),
            )?;
            // One whole-tree fit of the new model serves both checks.
            let motions = FittedMotions::new(&found.model, tracks)?;
            if let Some(before) = previous.take()
                && !motions.points_settled(&found.model, tracks, &moved)?
            {
                break before;
            }
            let mut moves = if pass < MODEL_PASSES {
                // The two sets are disjoint: the first moves points of well fitted bodies (and
                // unassigned ones), the second of poorly fitted ones.
                let mut m = motions.points_fitting_another_body(&found.model, tracks)?;
                let split = split_born(&found.model);
                m.extend(motions.points_leaving_mixed_bodies(&found.model, tracks, &split)?);
                m
            } else {
                Vec::new()
            };
            let ejected: Vec<usize> = if pass < MODEL_PASSES {
                motions
                    .points_fitting_no_body(&found.model, tracks)?
                    .into_iter()
                    .filter(|i| !moves.iter().any(|(p, _)| p == i))
                    .collect()
            } else {
                Vec::new()
            };
            // When the fit moves and ejects nothing: keypoints that alone make a joint
            // multi-DoF, left on no body too. (Looked for alongside the moves on every pass:
            // two runs of the mechanisms sweep lost their ARI of 1, one of the stages sweep
            // gained its joints.)
            let spoilers = if pass < MODEL_PASSES && moves.is_empty() && ejected.is_empty() {
                self.points_spoiling_joints(tracks, &found, sigma)?
            } else {
                Vec::new()
            };
            let settled = ejected.is_empty() && spoilers.is_empty();
            if moves.is_empty()
                && settled
                && let Some(again) =
                    self.retest_on_fitted_poses(tracks, &dmat, &found, &motions, sigma, source)?
            {
                found = again;
                if pass < MODEL_PASSES {
                    moves = FittedMotions::new(&found.model, tracks)?
                        .points_fitting_another_body(&found.model, tracks)?;
                }
            }
            if moves.is_empty() && settled {
                break found;
            }
            let mut labels = found.segmentation.labels().to_vec();
            for &(point, body) in &moves {
                labels[point] = Some(found.body_order[body]);
            }
            for &point in ejected.iter().chain(&spoilers) {
                labels[point] = None;
            }
            moved = moves.iter().map(|&(point, _)| point).collect();
            if !moved.is_empty() {
                history.push(Warning::PointsReassigned {
                    points: moved.clone(),
                });
            }
            if !ejected.is_empty() {
                history.push(Warning::PointsUnassigned {
                    points: ejected.clone(),
                });
            }
            if !spoilers.is_empty() {
                history.push(Warning::PointsMakingJointsMultiDof {
                    points: spoilers.clone(),
                });
            }
            moved.extend(ejected.iter().chain(&spoilers));
            unassigned.extend(ejected.iter().chain(&spoilers));
            seg = Segmentation::from_raw(&labels, 1);
            seg.discarded_groups = found.segmentation.discarded_groups.clone();
            previous = Some(found);
            pass += 1;
        };
        Ok(Discovery {
            body_order: found.body_order,
            model: found.model,
            stats,
            dissimilarity: dmat,
            segmentation: found.segmentation,
            poses: found.poses,
        })
    }

    /// The model of a segmentation's bodies, poses and pair tests: the tree, joints and
    /// their positions from the whole-tree fit, and the segmentation diagnostics.
    #[allow(clippy::too_many_arguments)]
    fn model(
        &self,
        tracks: &Tracks,
        dmat: &DissimilarityMatrix,
        bodies: Segmentation,
        poses: BodyPoses,
        pairs: Vec<PairDof>,
        sigma: f64,
        source: NoiseSource,
        history: Vec<Warning>,
    ) -> Result<Found> {
        let diag = kinetree_clustering::diagnostics(dmat, &bodies);
        let assemble = |excluded: &[(usize, usize)]| {
            self.assemble(
                tracks,
                &bodies,
                &poses,
                pairs.clone(),
                sigma,
                source,
                history.clone(),
                excluded,
            )
        };
        let finish = |(mut model, body_order): (Model, Vec<usize>)| -> Result<(Model, Vec<usize>)> {
            model.point_confidence = diag.point_margin.clone();
            for body in &mut model.bodies {
                body.internal_dissimilarity = diag.body_spread[body_order[body.id]];
            }
            model.reprediction_rms_in_sigma =
                kinetree_structure::fit_model_positions(&mut model, tracks)?;
            Ok((model, body_order))
        };
        // Near-tied parents (see `kinetree_structure::near_tied_edges`): each tree without one
        // chosen edge is fitted whole, at first plainly (one whole-tree fit of every frame,
        // the joints as the pair tests gave them); the best one that lowers the keypoints'
        // squared residual by TREE_TIE_GAIN is then finished like the model (joints freed,
        // bundle-adjusted, typed) and replaces it when it still re-predicts better with no
        // more doubtful joints. Measured: a link turning on the base about an axis 3 deg from
        // its sibling's, through the same anchor, tied its edges with the base and with the
        // sibling within 5e-4; the tree through the sibling re-predicted at 1.78 sigma, the
        // true one at 1.61 (mechanisms sweep, 3-joint revolute tree, seed 0).
        let plain_sse = |model: &Model| -> Result<f64> {
            let fits = kinetree_structure::Observer::new(model)?.fit_sequence(tracks)?;
            Ok(fits.iter().map(|f| f.sum_sq_m2).sum())
        };
        let first = assemble(&[])?;
        let nb = bodies.n_bodies();
        let mut challenger: Option<((Model, Vec<usize>), f64)> = None;
        if nb <= MAX_TIE_BODIES
            && let Some(tree) = kinetree_structure::spanning_tree(nb, &pairs)
        {
            let ties = kinetree_structure::near_tied_edges(nb, &pairs, &tree, TREE_TIE_MARGIN);
            if !ties.is_empty() {
                let own = plain_sse(&first.0)?;
                for edge in ties.into_iter().take(MAX_TREE_ALTERNATIVES) {
                    let alt = assemble(&[edge])?;
                    let sse = plain_sse(&alt.0)?;
                    let bar = challenger.as_ref().map_or(own, |c| c.1);
                    if sse < bar * (1.0 - TREE_TIE_GAIN).powi(2) {
                        challenger = Some((alt, sse));
                    }
                }
            }
        }
        let (mut model, mut body_order) = finish(first)?;
        if let Some((alt, _)) = challenger {
            let (alt, alt_order) = finish(alt)?;
            if doubtful_joints(&alt) <= doubtful_joints(&model)
                && matches!(
                    (alt.reprediction_rms_in_sigma, model.reprediction_rms_in_sigma),
                    (Some(a), Some(m)) if a < m * (1.0 - TREE_TIE_GAIN)
                )
            {
                (model, body_order) = (alt, alt_order);
            }
        }
        Ok(Found {
            body_order,
            model,
            segmentation: bodies,
            poses,
            history,
        })
    }

    /// Points that make a joint multi-DoF: for every multi-DoF joint of the model, the
    /// keypoint of its parent or child body (bodies of more than three) without which the
    /// body, posed by itself again, and the other pass the pair test as a single-DoF joint,
    /// while with it, posed the same way over the same frames, they do not; when it is the
    /// only such keypoint of the two. It belongs to another body: left on none, the model's
    /// fitted motions may place it in the next pass.
    ///
    /// Why the same frames: fewer frames pass the test more easily. On a 10-joint tree
    /// (mechanisms sweep, revolute, seed 13) a link posed through its hinge in 170 frames was
    /// posed by itself in 15, and without any one of three of its keypoints (two its own) in
    /// 7-13, each time single-DoF: the frame count alone would have decided.
    ///
    /// A keypoint near a joint axis is rigid to both bodies pairwise and can be clustered
    /// onto the wrong one. Rate-test case 83: on a 4-keypoint slider seen three keypoints at
    /// a time, the slider's poses followed such a keypoint (it fitted them at `chi^2 / k`
    /// 0.00, its own link's at 0.48), so the model's moves kept it, and the slider's joint
    /// had a rotation. Judging the keypoint against the body posed without it does not find
    /// it: the poses of three or four keypoints are so loose that it fitted them at 0.40;
    /// the pair test does (one DoF without it over 76 frames, two with it over the same
    /// frames, two without any other of the 12 keypoints).
    /// The uniqueness guards against a joint at the edge of its test: it is one keypoint
    /// that spoils it, or none. Real recordings (markers on skin, ball joints): unchanged.
    fn points_spoiling_joints(
        &self,
        tracks: &Tracks,
        found: &Found,
        sigma: f64,
    ) -> Result<Vec<usize>> {
        let order = &found.body_order;
        let poses = &found.poses;
        let spread: Vec<(f64, f64)> = poses.bodies.iter().map(pose_spread).collect();
        // `None` when the points cannot be posed.
        let posed_alone =
            |points: &[usize]| self.posed_as_one(tracks, points, sigma).ok().flatten();
        let mut out: Vec<usize> = Vec::new();
        let mut trial = poses.clone();
        for joint in found
            .model
            .joints
            .iter()
            .filter(|j| j.joint_type == "multi_dof")
        {
            let (p, c) = (order[joint.parent], order[joint.child]);
            let (frame, moving) = frame_and_moving(&spread, p, c);
            // Whether the pair test with `side` posed as `track` finds a single-DoF joint.
            let mut single_dof = |side: usize, track: BodyTrack| {
                trial.bodies[side] = track;
                let input = DofInput {
                    poses: &trial,
                    noise_sigma_m: sigma,
                };
                let tested = self
                    .dof
                    .test_pair(&input, Some(frame), moving)
                    .ok()
                    .map(|pair| pair.joint.is_single_dof());
                trial.bodies[side] = poses.bodies[side].clone();
                tested
            };
            let mut single: Vec<usize> = Vec::new();
            for side in [c, p] {
                let points = &poses.bodies[side].points;
                if points.len() <= kinetree_core::MIN_BODY_POINTS {
                    continue;
                }
                // Posed by itself (its poses may have come through a hinge) with all its
                // points, the body must test multi-DoF on exactly the frames it keeps without
                // the point: fewer frames pass more easily.
                let Some(all) = posed_alone(points) else {
                    continue;
                };
                for &i in points {
                    let rest: Vec<usize> = points.iter().copied().filter(|&q| q != i).collect();
                    let Some(without) = posed_alone(&rest) else {
                        continue;
                    };
                    let mut with = all.clone();
                    for t in 0..with.cam_from_body.len() {
                        if without.cam_from_body.get(t).is_none_or(Option::is_none) {
                            with.cam_from_body[t] = None;
                            with.quality[t] = None;
                        }
                    }
                    if single_dof(side, without) == Some(true)
                        && single_dof(side, with) == Some(false)
                    {
                        single.push(i);
                    }
                }
            }
            if let [i] = single[..]
                && !out.contains(&i)
            {
                out.push(i);
            }
        }
        out.sort_unstable();
        Ok(out)
    }

    /// When the model has multi-DoF joints or joints its whole-tree fit cannot follow (a
    /// `joint_not_followed` warning), every pair is tested again on the poses of its
    /// whole-tree fit (`motions`), which pose a small body through its joint and every
    /// keypoint below it rather than from its own few points, and the model is rebuilt on
    /// them. Returns the rebuilt model when it has fewer such joints.
    ///
    /// A body hidden by its neighbours in nine frames of ten (21 of 200 registered on the
    /// mechanisms sweep's trees) shares a handful of frames with each other body; over ten
    /// frames two siblings turning about one anchor passed for a hinge with a better fit
    /// ratio than their true joints with the base over a hundred, and the tree took them.
    /// The fit then freed those joints, but the tree stayed.
    fn retest_on_fitted_poses(
        &self,
        tracks: &Tracks,
        dmat: &DissimilarityMatrix,
        found: &Found,
        motions: &FittedMotions,
        sigma: f64,
        source: NoiseSource,
    ) -> Result<Option<Found>> {
        // A joint typed by the fit was multi-DoF or not followed as its pair test typed it: a
        // hinge and a slide in series on a wrong tree edge can pass for one slide (rate-test
        // case 411), so it counts as doubtful here too (`doubtful_joints`).
        let before = doubtful_joints(&found.model);
        if before == 0 {
            return Ok(None);
        }
        // Joints typed by the fit are left free for these poses: posed through such a joint, a
        // child would test as exactly that joint.
        let freed;
        let motions = if typed_by_fit(&found.model) > 0 {
            let mut model = found.model.clone();
            for w in &found.model.warnings {
                if let Warning::JointTypedByFit { parent, child, .. } = w {
                    model.warnings.push(Warning::JointNotFollowed {
                        parent: *parent,
                        child: *child,
                        excess_in_sigma2: f64::NAN,
                    });
                }
            }
            freed = FittedMotions::new(&model, tracks)?;
            &freed
        } else {
            motions
        };
        let fitted = motions.onto_body_poses(&found.poses, &found.body_order)?;
        let pairs = self.all_pairs(&fitted, sigma)?;
        // The rebuilt model costs as much as the first (on 21-body scenes at 1 cm, 60 % of
        // the noise test's run time); build it only if its tree has fewer multi-DoF edges or
        // gives a joint the fit did not follow another parent.
        let tree = kinetree_structure::spanning_tree(found.segmentation.n_bodies(), &pairs)
            .ok_or_else(|| Error::Degenerate("no bodies".into()))?;
        let multi_edges = (0..tree.parent.len())
            .filter_map(|child| Some((tree.parent[child]?, child)))
            .filter(|&(p, c)| {
                !kinetree_structure::find_pair(&pairs, Some(p), c)
                    .is_some_and(|q| q.joint.is_single_dof())
            })
            .count();
        let order = &found.body_order;
        let reattached = not_followed(&found.model)
            .iter()
            .any(|&(p, c)| tree.parent.get(order[c]) != Some(&Some(order[p])));
        if multi_edges >= multi_dof_joints(&found.model) + typed_by_fit(&found.model) && !reattached
        {
            return Ok(None);
        }
        let mut again = self.model(
            tracks,
            dmat,
            found.segmentation.clone(),
            fitted,
            pairs,
            sigma,
            source,
            found.history.clone(),
        )?;
        let after = doubtful_joints(&again.model);
        if after >= before {
            return Ok(None);
        }
        again.model.warnings.push(Warning::PairsRetested {
            multi_dof_before: before,
            multi_dof_after: after,
        });
        Ok(Some(again))
    }

    /// From a segmentation to registered bodies and their pair tests: poses, filled through
    /// hinges for bodies registered in few frames; bodies with fewer than two registered
    /// frames dropped; bodies whose residuals show mixed points split; discarded points
    /// attached where one body explains them (once; never those in `keep_off`); unassigned
    /// points that move as one body made one (once); unassigned points that turn together on
    /// a hinge made one (once); bodies that move rigidly together merged when the union still
    /// fits as one. Returns the final segmentation, its poses and every pair's DoF test.
    fn bodies(
        &self,
        tracks: &Tracks,
        dmat: &DissimilarityMatrix,
        mut seg: Segmentation,
        sigma: f64,
        warnings: &mut Vec<Warning>,
        keep_off: &[usize],
    ) -> Result<(Segmentation, BodyPoses, Vec<PairDof>)> {
        let mut poses;
        let mut pairs;
        let mut round = 0;
        let mut attach_done = false;
        let mut regroup_done = false;
        let mut split_rounds = 0;
        let mut cannot_link: Vec<(usize, usize)> = Vec::new();
        // The point sets of the bodies split so far: the attachment may not remake one.
        let mut split_bodies: Vec<Vec<usize>> = Vec::new();
        let mut hinge_done = false;
        let mut posed_by_hinge: Vec<Warning> = Vec::new();
        // Points taken off a hinged body (`off_hinge_point`): not attached again by poses,
        // and not taken off twice.
        let mut off_hinges: Vec<usize> = Vec::new();
        loop {
            poses = self.pose.estimate(&PoseInput {
                tracks,
                segmentation: &seg,
                noise_sigma_m: sigma,
            })?;
            // Bodies registered in few frames (or none: the groups made below) are posed
            // through a hinge where they lack a pose of their own; redone on every pass, as
            // the other bodies' poses change.
            posed_by_hinge.clear();
            if self.hinged_bodies {
                let reposed = self.reposed_through_hinges(tracks, &poses, sigma);
                let off: Vec<usize> = reposed
                    .iter()
                    .filter_map(|(b, h)| {
                        off_hinge_point(
                            tracks,
                            &poses,
                            &poses.bodies[*b].points,
                            h,
                            sigma,
                            &off_hinges,
                        )
                    })
                    .collect();
                if !off.is_empty() {
                    seg = seg.without_points(&off);
                    off_hinges.extend(&off);
                    warnings.push(Warning::PointsOffHinge { points: off });
                    continue;
                }
                for (b, h) in reposed {
                    let (track, filled) = kinetree_pose::filled_from_hinge(&poses.bodies[b], &h);
                    posed_by_hinge.push(Warning::BodyPosedThroughHinge {
                        points: track.points.clone(),
                        parent: h.parent.map(|p| poses.bodies[p].points.clone()),
                        frames: filled,
                    });
                    poses.bodies[b] = track;
                }
            }
            let drop: Vec<usize> = (0..poses.bodies.len())
                .filter(|&b| poses.bodies[b].n_registered() < 2)
                .collect();
            if !drop.is_empty() {
                for &b in &drop {
                    warnings.push(Warning::BodyDropped {
                        points: poses.bodies[b].points.clone(),
                        reason: format!(
                            "registered in {} frame(s); two are needed",
                            poses.bodies[b].n_registered()
                        ),
                    });
                }
                seg = seg.without_bodies(&drop);
                continue;
            }
            let warned = warnings.len();
            if split_rounds < MAX_SPLIT_ROUNDS
                && let Some(split) = split_mixed_bodies(
                    dmat,
                    &seg,
                    &poses,
                    sigma,
                    warnings,
                    &mut cannot_link,
                    |halves| {
                        self.pose.estimate(&PoseInput {
                            tracks,
                            segmentation: halves,
                            noise_sigma_m: sigma,
                        })
                    },
                )?
            {
                split_rounds += 1;
                split_bodies.extend(warnings[warned..].iter().filter_map(|w| match w {
                    Warning::BodySplit { points, .. } => Some(points.clone()),
                    _ => None,
                }));
                seg = split;
                attach_done = false;
                continue;
            }
            if !attach_done {
                // Once: give discarded points to the one body whose poses explain them.
                attach_done = true;
                let (refined, attached) = kinetree_pose::attach_unassigned(
                    tracks,
                    &poses,
                    &seg,
                    sigma,
                    &[keep_off, &off_hinges].concat(),
                    &split_bodies,
                );
                if !attached.is_empty() {
                    warnings.push(Warning::PointsAttached { points: attached });
                    seg = refined;
                    continue;
                }
            }
            if !regroup_done {
                // Once, after the attachment: unassigned points that move as one body become one.
                regroup_done = true;
                let groups = self.regroup_unassigned(tracks, dmat, &seg, sigma)?;
                if !groups.is_empty() {
                    let out = with_new_bodies(&seg, &groups);
                    warnings.push(Warning::UnassignedPointsGrouped { groups });
                    seg = out;
                    continue;
                }
            }
            if self.hinged_bodies && !hinge_done {
                // Once, after the regrouping: unassigned points that turn together on a hinge
                // become a body, posed through it on the next pass.
                hinge_done = true;
                let groups = self.hinged_groups(tracks, dmat, &seg, &poses, sigma)?;
                if !groups.is_empty() {
                    seg = with_new_bodies(&seg, &groups);
                    continue;
                }
            }
            if seg.n_bodies() == 0 {
                return Err(Error::Degenerate(
                    "no rigid body of three or more points could be found and registered".into(),
                ));
            }
            pairs = self.all_pairs(&poses, sigma)?;
            let nb = seg.n_bodies();
            let mut forbidden: Vec<(usize, usize)> = cannot_link
                .iter()
                .filter_map(|&(p, q)| Some((seg.body_of(p)?, seg.body_of(q)?)))
                .collect();
            forbidden.extend(pairwise_apart(dmat, &seg));
            // A merge stands only if the merged body still fits like one rigid body.
            let group = loop {
                let group = rigid_groups(nb, &pairs, &forbidden);
                let mut rejected = false;
                for g in 0..nb {
                    let members: Vec<usize> = (0..nb).filter(|&b| group[b] == g).collect();
                    if members.len() < 2 || self.fits_as_one(tracks, &poses, &members, sigma)? {
                        continue;
                    }
                    rejected = true;
                    for (x, &p) in members.iter().enumerate() {
                        for &q in &members[x + 1..] {
                            forbidden.push((p, q));
                        }
                    }
                }
                if !rejected {
                    break group;
                }
            };
            let merged_any = group.iter().enumerate().any(|(b, &g)| g != b);
            if !merged_any || round >= MAX_MERGE_ROUNDS {
                break;
            }
            let mut groups: Vec<Vec<usize>> = Vec::new();
            for g in 0..nb {
                let members: Vec<usize> = (0..nb).filter(|&b| group[b] == g).collect();
                if members.len() > 1 {
                    groups.extend(members.iter().map(|&b| poses.bodies[b].points.clone()));
                }
            }
            warnings.push(Warning::BodiesMerged { groups });
            seg = seg.merged(&group);
            round += 1;
        }
        // Each pass of `run` poses the bodies anew: only this pass's hinges stand.
        warnings.retain(|w| !matches!(w, Warning::BodyPosedThroughHinge { .. }));
        warnings.extend(posed_by_hinge);
        Ok((seg, poses, pairs))
    }

    /// Bodies registered in under half the frames that show one of their keypoints (at most
    /// [`MAX_REPOSED_SHARE`]) that turn on another body about one axis (as in
    /// `hinged_groups`), posed through that hinge instead when it poses them in at least
    /// [`MIN_REPOSE_GAIN`] times as many frames. Returns `(body, hinge)` pairs, by body.
    ///
    /// A link hidden by its neighbours in most frames (a few frames with three keypoints,
    /// many with one or two) is registered only in those few; its joints are then tested
    /// over them alone, and its children's over the frames they share.
    fn reposed_through_hinges(
        &self,
        tracks: &Tracks,
        poses: &BodyPoses,
        sigma: f64,
    ) -> Vec<(usize, kinetree_pose::Hinge)> {
        (0..poses.bodies.len())
            .filter_map(|b| {
                let track = &poses.bodies[b];
                let shown = (0..poses.n_frames)
                    .filter(|&t| track.points.iter().any(|&i| tracks.get(t, i).is_some()))
                    .count();
                let own = track.n_registered();
                if own as f64 > MAX_REPOSED_SHARE * shown as f64 {
                    return None;
                }
                let h = best_hinge(tracks, poses, &track.points, Some(b), sigma)?;
                (h.track.n_registered() as f64 >= MIN_REPOSE_GAIN * own as f64).then_some((b, h))
            })
            .collect()
    }

    /// Groups of unassigned keypoints, each seen in [`kinetree_pose::MIN_HINGE_FRAMES`]
    /// frames or more and explained by no body's poses, that turn together about one axis of
    /// a posed body or of the camera frame (see [`best_hinge`]). A group that does not is
    /// split in two by the dissimilarity, as in `regroup_unassigned`, down to two keypoints.
    ///
    /// A link hidden by its neighbours so that at most two of its keypoints show at once
    /// (mechanisms sweep, 7-joint revolute tree seed 14: its keypoints 11 and 15 in 174 and
    /// 152 of 200 frames, never three) gets no pose of its own; its children then look
    /// multi-DoF on the base.
    fn hinged_groups(
        &self,
        tracks: &Tracks,
        dmat: &DissimilarityMatrix,
        seg: &Segmentation,
        poses: &BodyPoses,
        sigma: f64,
    ) -> Result<Vec<Vec<usize>>> {
        let nb = poses.bodies.len();
        let left: Vec<usize> = (0..tracks.n_points())
            .filter(|&i| {
                seg.body_of(i).is_none()
                    && tracks.visible_count(i) >= kinetree_pose::MIN_HINGE_FRAMES
                    && !(0..nb).any(|b| kinetree_pose::explains_point(tracks, poses, b, i, sigma))
            })
            .collect();
        accepted_groups(dmat, left, 2, |group| {
            Ok(best_hinge(tracks, poses, group, None, sigma).is_some())
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn assemble(
        &self,
        tracks: &Tracks,
        seg: &Segmentation,
        poses: &BodyPoses,
        pairs: Vec<PairDof>,
        sigma: f64,
        source: NoiseSource,
        mut warnings: Vec<Warning>,
        excluded: &[(usize, usize)],
    ) -> Result<(Model, Vec<usize>)> {
        let nb = seg.n_bodies();
        let tree = kinetree_structure::spanning_tree_without(nb, &pairs, excluded)
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
            let pair = self.dof.test_pair(&input, Some(parent), child)?;
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
                .map(|x| RigidTransform {
                    rotation_xyzw: [x.rotation.i, x.rotation.j, x.rotation.k, x.rotation.w],
                    translation: [x.translation.x, x.translation.y, x.translation.z],
                });
            let (axis_p, point_p) = match &pair.joint {
                JointKind::Revolute { axis, pivot } => (Some(*axis), Some(*pivot)),
                JointKind::Prismatic { axis } => (Some(*axis), None),
                _ => (None, None),
            };
            let arr = |v: kinetree_core::nalgebra::Vector3<f64>| [v.x, v.y, v.z];
            if !pair.joint.is_single_dof() {
                warnings.push(Warning::MultiDofJoint {
                    parent: new_id[parent],
                    child: new_id[child],
                    dof: pair.dof,
                });
            }
            joints.push(Joint {
                parent: new_id[parent],
                child: new_id[child],
                joint_type: pair.joint.name().into(),
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
                reference_frame,
                reference_pose,
                positions,
                // Set with the positions by `kinetree_structure::fit_model_positions`.
                position_std: Vec::new(),
                smoothed_positions: Vec::new(),
                smoothed_std: Vec::new(),
                range: None,
                dof: pair.dof,
                ranks: Ranks {
                    translation: pair.translation.rank,
                    rotation: pair.rotation.rank,
                    centre: pair.centre.rank,
                    sliding: pair.sliding.rank,
                },
                fit_ratio: pair.fit_ratio,
            });
        }
        for &b in &order {
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
        let chain = kinetree_structure::paper_chain(nb, &pairs)
            .map(|c| c.iter().map(|&b| new_id[b]).collect());
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
            stages: StageNames {
                dissimilarity: self.dissimilarity.name().into(),
                clustering: self.clustering.name().into(),
                pose: self.pose.name().into(),
                dof: self.dof.name().into(),
            },
            point_body,
            point_confidence: Vec::new(),
            static_body: statics.first().map(|&s| new_id[s]),
            root_body: new_id[tree.root],
            bodies,
            joints,
            chain,
            pairs: model_pairs,
            reprediction_rms_in_sigma: None,
            warnings,
        };
        Ok((model, order))
    }
}

#[cfg(test)]
mod tests {
    use super::rigid_groups;
    use kinetree_core::{JointKind, PairDof, RankTest};

    fn pair(a: usize, b: usize, joint: JointKind, fit_ratio: f64) -> PairDof {
        PairDof {
            a: Some(a),
            b,
            reference_frame: 0,
            translation: RankTest::empty(),
            rotation: RankTest::empty(),
            centre: RankTest::empty(),
            sliding: RankTest::empty(),
            centre_uncentred: RankTest::empty(),
            dof: usize::from(!matches!(joint, JointKind::Rigid)),
            joint,
            fit_ratio,
        }
    }

    #[test]
    fn a_poorly_posed_body_cannot_chain_moving_bodies_together() {
        // Body 1 "tests rigid" against 0 and 2 (its noise hides everything), while 0 and 2
        // clearly move relative to each other.
        let pairs = vec![
            pair(0, 1, JointKind::Rigid, 0.2),
            pair(1, 2, JointKind::Rigid, 0.5),
            pair(0, 2, JointKind::MultiDof, 0.1),
        ];
        let g = rigid_groups(3, &pairs, &[]);
        assert_eq!(g[0], g[1], "the clearest rigid pair merges");
        assert_ne!(g[0], g[2], "but 0 and 2 stay apart");
        // When every cross pair is rigid, all three merge.
        let all = vec![
            pair(0, 1, JointKind::Rigid, 0.2),
            pair(1, 2, JointKind::Rigid, 0.5),
            pair(0, 2, JointKind::Rigid, 0.1),
        ];
        let g = rigid_groups(3, &all, &[]);
        assert!(g.iter().all(|&x| x == g[0]));
        // ... unless two of them were split apart before.
        let g = rigid_groups(3, &all, &[(0, 2)]);
        assert_ne!(g[0], g[2]);
    }
}
