//! Bodies that mix points of bodies that move apart split in two.
//!
//! A body is split when its median fit residual is over `residual_in_sigma`, when its two
//! halves (the `halves` clustering slot on the body's own sub-matrix; a side of fewer than
//! three points is left on no body) are apart on average in the pairwise measure, or when the
//! halves, posed as bodies of their own, fit its points far better than the body does
//! ([`Split::halves_fit_better`]). One point of each part goes into the `cannot_link`
//! constraints so that the merge does not rejoin them (a part with poor poses can "test
//! rigid" against a body it moves against), and the body's points into `undone_bodies`, so
//! that the attachment does not remake it.

use super::{count_in_range, cut_in_two, halves, in_range, mean_cross, poses_of};
use kinetree_core::{
    BodyTrack, Constraints, DissimilarityMatrix, Draft, Edit, MIN_BODY_POINTS, PoseInput,
    PoseQuality, Proposal, Repair, RepairContext, RepairLimit, RepairPhase, Result, Segmentation,
    Warning,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`Split`] (`[pipeline.repairs.split]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SplitParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A body whose median fit residual exceeds this many noise std-devs is split (default
    /// 2.5; `docs/decisions.md`, `split.residual_in_sigma`).
    pub residual_in_sigma: f64,
    /// Slack on the chi-square bound of the halves' likelihood ratio (default 1.6) for the
    /// approximations behind it (reference shapes from the same frames, an estimated noise
    /// level).
    pub lr_slack: f64,
    /// Std-devs of that chi-square bound (default 4.0).
    pub lr_bound_in_std: f64,
    /// Least share of the body's registered frames in which both halves are posed for the
    /// likelihood ratio to count (default 0.25; `docs/decisions.md`, `split.min_frame_share`).
    pub min_frame_share: f64,
    /// Least number of such frames (default 10, `kinetree_fit::MIN_FRAMES`).
    pub min_frames: usize,
    /// Splits per bodies phase (default 8): a body that is not rigid would otherwise be split
    /// forever.
    pub max_rounds: usize,
    /// Bodies of at most this many points whose halves by the pairwise measure do not fit
    /// better are cut again by their points' profiles against every other point (default
    /// 300; 0 turns it off; `docs/decisions.md`, `split.profile_max_points`).
    pub profile_max_points: usize,
    /// Points the profiles are taken against, spread evenly over the keypoints (default 200).
    pub profile_points: usize,
    /// Times a profile cut that sets off fewer than three points (a stray keypoint) is redone
    /// on the rest (default 2).
    pub profile_peel: usize,
    /// Least contrast of profile halves, as a fraction of the measure's cut: their mean
    /// dissimilarity across must exceed the larger mean within a half by this much (default
    /// 0.25). A body carrying a few keypoints of another cuts into halves that mix both, as
    /// alike across as within; two bodies cut apart are not.
    pub profile_contrast: f64,
}

impl Default for SplitParams {
    fn default() -> Self {
        Self {
            enabled: true,
            residual_in_sigma: 2.5,
            lr_slack: 1.6,
            lr_bound_in_std: 4.0,
            min_frame_share: 0.25,
            min_frames: kinetree_fit::MIN_FRAMES,
            max_rounds: 8,
            profile_max_points: 300,
            profile_points: 200,
            profile_peel: 2,
            profile_contrast: 0.25,
        }
    }
}

impl SplitParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "split";
        in_range(NAME, "residual_in_sigma", self.residual_in_sigma, 0.1, 1e6)?;
        in_range(NAME, "lr_slack", self.lr_slack, 0.1, 100.0)?;
        in_range(NAME, "lr_bound_in_std", self.lr_bound_in_std, 0.0, 20.0)?;
        in_range(NAME, "min_frame_share", self.min_frame_share, 0.0, 1.0)?;
        count_in_range(NAME, "min_frames", self.min_frames, 1, 1_000_000)?;
        count_in_range(NAME, "max_rounds", self.max_rounds, 0, 1000)?;
        count_in_range(
            NAME,
            "profile_max_points",
            self.profile_max_points,
            0,
            1_000_000,
        )?;
        count_in_range(NAME, "profile_points", self.profile_points, 1, 1_000_000)?;
        count_in_range(NAME, "profile_peel", self.profile_peel, 0, 100)?;
        in_range(NAME, "profile_contrast", self.profile_contrast, 0.0, 100.0)
    }
}

/// Splits bodies whose points do not move as one.
#[derive(Debug, Clone)]
pub struct Split {
    params: SplitParams,
}

impl Split {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SplitParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }

    /// Whether a body's two halves, each posed as a rigid body, explain its points better than
    /// the body's own poses by more than two extra poses could: over the frames where all
    /// three are posed, the drop in the sum of squared residuals, in noise variances, against
    /// the chi-square bound with 6 degrees of freedom per frame (the second half's pose) at
    /// `lr_bound_in_std` standard deviations, times `lr_slack`.
    ///
    /// A small slider merged with the link that turns on it can fit as one at a median 1.5
    /// sigma, with the halves' mean dissimilarity under the cut, while the halves' fits lower
    /// the residual by about 3 times the 6 variances per frame an extra pose buys
    /// (`docs/decisions.md`, `split.lr_slack`).
    fn halves_fit_better(
        &self,
        union: &BodyTrack,
        first: &BodyTrack,
        second: &BodyTrack,
        sigma: f64,
    ) -> bool {
        let sse = |q: &PoseQuality| q.rms_residual_m.powi(2) * q.n_visible as f64;
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
        if frames < self.params.min_frames || share < self.params.min_frame_share || sigma <= 0.0 {
            return false;
        }
        let k = 6.0 * frames as f64;
        drop / (sigma * sigma) / k
            > self.params.lr_slack
                * kinetree_core::stats::chi2_per_dof_quantile(k, self.params.lr_bound_in_std)
    }
}

impl Split {
    /// For each `(body, halves)` of two halves, whether the halves, posed as bodies of their
    /// own (all in one call), fit the body's points better ([`Split::halves_fit_better`]).
    fn better_halves(
        &self,
        ctx: &RepairContext<'_>,
        bodies: &[BodyTrack],
        sets: &[(usize, &[Vec<usize>])],
        sigma: f64,
    ) -> Result<Vec<bool>> {
        if sets.is_empty() {
            return Ok(Vec::new());
        }
        let mut half_labels: Vec<Option<usize>> = vec![None; ctx.tracks.n_points()];
        for (k, (_, parts)) in sets.iter().enumerate() {
            for (h, part) in parts.iter().enumerate() {
                for &i in part {
                    half_labels[i] = Some(2 * k + h);
                }
            }
        }
        let half_poses = ctx.stages.pose.estimate(&PoseInput {
            tracks: ctx.tracks,
            segmentation: &Segmentation::from_raw(&half_labels, 1),
            noise_sigma_m: sigma,
        })?;
        let index_of = |point: usize| {
            half_poses
                .bodies
                .iter()
                .position(|t| t.points.binary_search(&point).is_ok())
        };
        Ok(sets
            .iter()
            .map(|(b, parts)| {
                let (Some(ia), Some(ib)) = (index_of(parts[0][0]), index_of(parts[1][0])) else {
                    return false;
                };
                let (first, second) = (&half_poses.bodies[ia], &half_poses.bodies[ib]);
                self.halves_fit_better(&bodies[*b], first, second, sigma)
            })
            .collect())
    }
}

/// Mean dissimilarity over the observed pairs within `points`; `None` when no pair was
/// observed.
fn mean_within(m: &DissimilarityMatrix, points: &[usize]) -> Option<f64> {
    let (mut sum, mut count) = (0.0, 0usize);
    for (x, &i) in points.iter().enumerate() {
        for &j in &points[x + 1..] {
            if let Some(d) = m.get(i, j) {
                sum += d;
                count += 1;
            }
        }
    }
    (count > 0).then(|| sum / count as f64)
}

/// The two halves of `points` by their profiles: the `halves` slot on the mean absolute
/// difference of two points' dissimilarities to `n_reference` keypoints spread evenly over
/// all (pairs unknown on either side left out). Two points of one body stand alike against
/// every other point, while the pairwise measure alone can miss a slide across the pairs'
/// directions (their distances barely change). A cut that sets off a side of under three
/// points is redone on the rest, up to `peel` times; the result has fewer than two halves
/// when no cut leaves two sides of three points.
fn profile_halves(
    ctx: &RepairContext<'_>,
    points: &[usize],
    n_reference: usize,
    peel: usize,
) -> Result<Vec<Vec<usize>>> {
    let mut parts = profile_cut(ctx, points, n_reference)?;
    for _ in 0..peel {
        match &parts[..] {
            [rest] if rest.len() < points.len() && rest.len() >= 2 * MIN_BODY_POINTS => {
                parts = profile_cut(ctx, rest, n_reference)?;
            }
            _ => break,
        }
    }
    Ok(parts)
}

/// One cut of [`profile_halves`].
fn profile_cut(
    ctx: &RepairContext<'_>,
    points: &[usize],
    n_reference: usize,
) -> Result<Vec<Vec<usize>>> {
    let dmat = ctx.dissimilarity;
    let n = dmat.n_points;
    let step = n.div_ceil(n_reference.max(1)).max(1);
    let reference: Vec<usize> = (0..n).step_by(step).collect();
    let profile: Vec<Vec<Option<f64>>> = points
        .iter()
        .map(|&i| {
            reference
                .iter()
                .map(|&k| if k == i { None } else { dmat.get(i, k) })
                .collect()
        })
        .collect();
    let mut values = Vec::with_capacity(kinetree_core::n_pairs(points.len()));
    for x in 0..points.len() {
        for y in x + 1..points.len() {
            let (mut sum, mut count) = (0.0, 0usize);
            for (a, b) in profile[x].iter().zip(&profile[y]) {
                if let (Some(a), Some(b)) = (a, b) {
                    sum += (a - b).abs();
                    count += 1;
                }
            }
            values.push(if count > 0 {
                sum / count as f64
            } else {
                f64::NAN
            });
        }
    }
    let sub = DissimilarityMatrix {
        n_points: points.len(),
        values,
        suggested_cut: dmat.suggested_cut,
        measure: format!("{} profile", dmat.measure),
    };
    cut_in_two(ctx, &sub, points)
}

impl Repair for Split {
    fn name(&self) -> &str {
        "split"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Edits(self.params.max_rounds)
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let (seg, dmat, sigma) = (&draft.segmentation, ctx.dissimilarity, ctx.noise_sigma_m);
        // (body, residual in sigma, halves, whether to split)
        let mut candidates: Vec<(usize, f64, Vec<Vec<usize>>, bool)> = Vec::new();
        for (b, track) in poses.bodies.iter().enumerate() {
            let Some(residual) = track.median_residual_m() else {
                continue;
            };
            let ratio = residual / sigma;
            if track.points.len() < 4 {
                continue;
            }
            let parts = halves(ctx, &track.points)?;
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
            let split = ratio > self.params.residual_in_sigma || apart;
            candidates.push((b, ratio, parts, split));
        }
        // The halves of the other bodies, posed as bodies of their own, all in one call.
        let undecided: Vec<usize> = (0..candidates.len())
            .filter(|&c| !candidates[c].3 && candidates[c].2.len() == 2)
            .collect();
        let sets: Vec<(usize, &[Vec<usize>])> = undecided
            .iter()
            .map(|&c| (candidates[c].0, &candidates[c].2[..]))
            .collect();
        let better = self.better_halves(ctx, &poses.bodies, &sets, sigma)?;
        for (&c, better) in undecided.iter().zip(better) {
            candidates[c].3 = better;
        }
        // Bodies whose halves by the pairwise measure do not fit better: halves by profile.
        let profiled: Vec<(usize, Vec<Vec<usize>>)> = candidates
            .iter()
            .enumerate()
            .filter(|(_, c)| !c.3)
            .filter(|(_, c)| {
                let n = poses.bodies[c.0].points.len();
                n >= 2 * MIN_BODY_POINTS && n <= self.params.profile_max_points
            })
            .map(|(k, c)| {
                let parts = profile_halves(
                    ctx,
                    &poses.bodies[c.0].points,
                    self.params.profile_points,
                    self.params.profile_peel,
                )?;
                Ok((k, parts))
            })
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .filter(|(k, parts)| parts.len() == 2 && *parts != candidates[*k].2)
            .filter(|(_, parts)| {
                let within = |p: &[usize]| mean_within(dmat, p).unwrap_or(f64::INFINITY);
                mean_cross(dmat, &parts[0], &parts[1]).is_some_and(|across| {
                    across - within(&parts[0]).max(within(&parts[1]))
                        > self.params.profile_contrast * dmat.suggested_cut
                })
            })
            .collect();
        let sets: Vec<(usize, &[Vec<usize>])> = profiled
            .iter()
            .map(|(c, parts)| (candidates[*c].0, &parts[..]))
            .collect();
        let better = self.better_halves(ctx, &poses.bodies, &sets, sigma)?;
        for ((c, parts), better) in profiled.into_iter().zip(better) {
            if better {
                candidates[c].2 = parts;
                candidates[c].3 = true;
            }
        }
        let mut labels: Vec<Option<usize>> = seg.labels().to_vec();
        let mut next_id = seg.n_bodies();
        let mut p = Proposal::new(Edit::Segmentation(seg.clone()), "");
        let mut constraints = Constraints::default();
        for (b, ratio, parts, split) in candidates {
            if !split {
                continue;
            }
            let pts = &poses.bodies[b].points;
            p.warnings.push(Warning::BodySplit {
                points: pts.clone(),
                residual_in_sigma: ratio,
            });
            constraints.undone_bodies.push(pts.clone());
            constraints.split_origins.push(pts.clone());
            p.points.extend(pts);
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
                constraints.cannot_link.push((first[0], second[0]));
            }
            next_id += 1;
        }
        if p.warnings.is_empty() {
            return Ok(None);
        }
        let mut out = Segmentation::from_raw(&labels, kinetree_core::MIN_BODY_POINTS);
        out.discarded_groups
            .extend(seg.discarded_groups.iter().cloned());
        out.discarded_groups.sort();
        p.summary = format!("{} body(ies) split in two", p.warnings.len());
        p.points.sort_unstable();
        p.edit = Edit::Segmentation(out);
        p.constraints = constraints;
        Ok(Some(p))
    }
}
