//! Bodies that mix points of bodies that move apart split in two.
//!
//! A body is split when its median fit residual is over `residual_in_sigma`, when its two
//! halves (the `halves` clustering slot on the body's own sub-matrix; a side of fewer than
//! three points is left on no body) are apart on average in the pairwise measure, or when the
//! halves, posed as bodies of their own, fit its points far better than the body does
//! ([`Split::halves_gain`]); a slender body (a rod's keypoints) is also tried cut along its
//! long axis, where two rods in line that bend at a joint barely change their keypoints'
//! distances. One point of each part goes into the `cannot_link` constraints so that the
//! merge does not rejoin them (a part with poor poses can "test rigid" against a body it moves
//! against), and the body's points into `undone_bodies`, so that the attachment does not
//! remake it.

use super::{count_in_range, cut_in_two, halves, in_range, mean_cross, poses_of};
use kinetree_core::nalgebra::{Matrix3, Point3};
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
    /// Slender bodies (a rod's keypoints: the reference shape spreads across its long axis by
    /// less than this fraction of its spread along it, as `pose.slender_aspect`) are tried cut
    /// along that axis, at the cut whose halves fit best, kept when they fit better than the
    /// body and than any other halves (default 0.1; 0 turns it off; `docs/decisions.md`,
    /// `split.axis_cut_aspect`). Two rods in line that bend at a joint barely change their
    /// keypoints' distances.
    pub axis_cut_aspect: f64,
    /// Most cut positions tried along a slender body's axis, spread evenly over its points
    /// (default 12).
    pub axis_cut_positions: usize,
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
            axis_cut_aspect: 0.1,
            axis_cut_positions: 12,
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
        in_range(NAME, "profile_contrast", self.profile_contrast, 0.0, 100.0)?;
        in_range(NAME, "axis_cut_aspect", self.axis_cut_aspect, 0.0, 1.0)?;
        count_in_range(
            NAME,
            "axis_cut_positions",
            self.axis_cut_positions,
            1,
            1_000_000,
        )
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

    /// How much better a body's two halves, each posed as a rigid body, explain its points than
    /// the body's own poses, against what two extra poses could: over the frames where all
    /// three are posed, the drop in the sum of squared residuals, in noise variances per
    /// degree of freedom, over the chi-square bound with 6 degrees of freedom per frame (the
    /// second half's pose) at `lr_bound_in_std` standard deviations, times `lr_slack`. The
    /// halves fit better when it is over 1; `None` when too few frames judge them.
    ///
    /// A small slider merged with the link that turns on it can fit as one at a median 1.5
    /// sigma, with the halves' mean dissimilarity under the cut, while the halves' fits lower
    /// the residual by about 3 times the 6 variances per frame an extra pose buys
    /// (`docs/decisions.md`, `split.lr_slack`).
    fn halves_gain(
        &self,
        union: &BodyTrack,
        first: &BodyTrack,
        second: &BodyTrack,
        sigma: f64,
    ) -> Option<f64> {
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
            return None;
        }
        let k = 6.0 * frames as f64;
        Some(
            drop / (sigma * sigma)
                / k
                / (self.params.lr_slack
                    * kinetree_core::stats::chi2_per_dof_quantile(k, self.params.lr_bound_in_std)),
        )
    }
}

impl Split {
    /// For each `(body, halves)` of two halves, how much better the halves, posed as bodies of
    /// their own (all in one call), fit the body's points ([`Split::halves_gain`]; over 1 when
    /// they fit better).
    fn halves_gains(
        &self,
        ctx: &RepairContext<'_>,
        bodies: &[BodyTrack],
        sets: &[(usize, &[Vec<usize>])],
        sigma: f64,
    ) -> Result<Vec<Option<f64>>> {
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
                let (ia, ib) = (index_of(parts[0][0])?, index_of(parts[1][0])?);
                let (first, second) = (&half_poses.bodies[ia], &half_poses.bodies[ib]);
                self.halves_gain(&bodies[*b], first, second, sigma)
            })
            .collect())
    }
}

impl Split {
    /// Cuts the slender bodies among `candidates` along their long axis
    /// ([`SplitParams::axis_cut_aspect`]): of the cuts between consecutive points in their
    /// order along it, at most `axis_cut_positions` spread evenly with three points or more on
    /// each side, the one whose halves fit best, when they fit better than the body and than
    /// the halves it was to be split into otherwise.
    fn cut_along_axes(
        &self,
        ctx: &RepairContext<'_>,
        bodies: &[BodyTrack],
        candidates: &mut [(usize, f64, Vec<Vec<usize>>, bool)],
        sigma: f64,
    ) -> Result<()> {
        if self.params.axis_cut_aspect <= 0.0 {
            return Ok(());
        }
        // (candidate, points in order along the axis, cut positions)
        let rods: Vec<(usize, Vec<usize>, Vec<usize>)> = candidates
            .iter()
            .enumerate()
            .filter_map(|(k, c)| {
                let order = along_long_axis(&bodies[c.0], self.params.axis_cut_aspect)?;
                let cuts = cut_positions(order.len(), self.params.axis_cut_positions);
                (!cuts.is_empty()).then_some((k, order, cuts))
            })
            .collect();
        // A rod split already (its residual, or halves by another measure) keeps its halves
        // unless a cut along its axis fits better than they do.
        let mut best: Vec<(f64, usize)> = vec![(1.0, 0); rods.len()];
        let (split, sets): (Vec<usize>, Vec<_>) = rods
            .iter()
            .enumerate()
            .map(|(r, (k, _, _))| (r, &candidates[*k]))
            .filter(|(_, c)| c.3 && c.2.len() == 2)
            .map(|(r, c)| (r, (c.0, &c.2[..])))
            .unzip();
        let gains = self.halves_gains(ctx, bodies, &sets, sigma)?;
        for (&r, gain) in split.iter().zip(gains) {
            best[r].0 = best[r].0.max(gain.unwrap_or(1.0));
        }
        // One call per slot poses every rod's cut at that slot; each rod keeps its best cut.
        let slots = rods.iter().map(|r| r.2.len()).max().unwrap_or(0);
        for slot in 0..slots {
            let halves: Vec<(usize, usize, [Vec<usize>; 2])> = rods
                .iter()
                .enumerate()
                .filter_map(|(r, (k, order, cuts))| {
                    let &at = cuts.get(slot)?;
                    Some((r, candidates[*k].0, split_at(order, at)))
                })
                .collect();
            let sets: Vec<(usize, &[Vec<usize>])> = halves
                .iter()
                .map(|(_, b, parts)| (*b, &parts[..]))
                .collect();
            let gains = self.halves_gains(ctx, bodies, &sets, sigma)?;
            for ((r, _, _), gain) in halves.iter().zip(gains) {
                if let Some(g) = gain.filter(|&g| g > best[*r].0) {
                    best[*r] = (g, rods[*r].2[slot]);
                }
            }
        }
        // `best` starts at a gain of 1 (or the other halves'), so a rod has a cut only when its
        // halves fit better than the body and than those.
        for ((k, order, _), (_, at)) in rods.into_iter().zip(best) {
            if at > 0 {
                candidates[k].2 = split_at(&order, at).to_vec();
                candidates[k].3 = true;
            }
        }
        Ok(())
    }
}

/// Whether halves fit better than their body ([`Split::halves_gain`] over 1).
fn fits_better(gain: Option<f64>) -> bool {
    gain.is_some_and(|g| g > 1.0)
}

/// A body's placed points in their order along the long axis of its reference shape, when
/// the shape is slender: it spreads across that axis (the second principal axis's standard
/// deviation) by less than `aspect` times its spread along it. `None` for fuller shapes and
/// bodies of fewer than six placed points.
fn along_long_axis(body: &BodyTrack, aspect: f64) -> Option<Vec<usize>> {
    let (points, shape): (Vec<usize>, Vec<Point3<f64>>) = body
        .points
        .iter()
        .zip(&body.shape)
        .zip(&body.placed)
        .filter(|(_, placed)| **placed)
        .map(|((&i, &p), _)| (i, p))
        .unzip();
    // The pose stage's own measure of a slender body (`pose.slender_aspect`).
    let spread = kinetree_pose::spread(&shape);
    if points.len() < 2 * MIN_BODY_POINTS || spread[1] >= aspect * spread[0] {
        return None;
    }
    let centre = kinetree_core::geom::centroid(&shape);
    let scatter: Matrix3<f64> = shape
        .iter()
        .map(|p| (p - centre) * (p - centre).transpose())
        .sum();
    let eigen = scatter.symmetric_eigen();
    let along = eigen.eigenvectors.column(eigen.eigenvalues.imax());
    let mut order: Vec<(f64, usize)> = points
        .iter()
        .zip(&shape)
        .map(|(&i, p)| ((p - centre).dot(&along), i))
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    Some(order.into_iter().map(|(_, i)| i).collect())
}

/// Up to `most` cut positions (the first side's size) spread evenly over `3..=n - 3`.
fn cut_positions(n: usize, most: usize) -> Vec<usize> {
    if n < 2 * MIN_BODY_POINTS {
        return Vec::new();
    }
    let (lo, hi) = (MIN_BODY_POINTS, n - MIN_BODY_POINTS);
    let count = (hi - lo + 1).min(most.max(1));
    let mut cuts: Vec<usize> = (0..count)
        .map(|k| lo + (k * (hi - lo)).checked_div(count - 1).unwrap_or(0))
        .collect();
    cuts.dedup();
    cuts
}

/// `order`'s first `at` points and the rest, each ascending.
fn split_at(order: &[usize], at: usize) -> [Vec<usize>; 2] {
    let (mut first, mut second) = (order[..at].to_vec(), order[at..].to_vec());
    first.sort_unstable();
    second.sort_unstable();
    [first, second]
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
        let gains = self.halves_gains(ctx, &poses.bodies, &sets, sigma)?;
        for (&c, gain) in undecided.iter().zip(gains) {
            candidates[c].3 = fits_better(gain);
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
        let gains = self.halves_gains(ctx, &poses.bodies, &sets, sigma)?;
        for ((c, parts), gain) in profiled.into_iter().zip(gains) {
            if fits_better(gain) {
                candidates[c].2 = parts;
                candidates[c].3 = true;
            }
        }
        self.cut_along_axes(ctx, &poses.bodies, &mut candidates, sigma)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cut_positions_leave_three_points_a_side_and_spread_evenly() {
        assert!(cut_positions(5, 12).is_empty());
        assert_eq!(cut_positions(6, 12), vec![3]);
        assert_eq!(cut_positions(12, 12), (3..=9).collect::<Vec<_>>());
        let many = cut_positions(100, 12);
        assert_eq!(many.len(), 12);
        assert_eq!((many[0], many[11]), (3, 97));
        assert!(many.windows(2).all(|w| w[1] > w[0]));
    }

    fn body(shape: Vec<Point3<f64>>) -> BodyTrack {
        let n = shape.len();
        BodyTrack {
            points: (10..10 + n).collect(),
            placed: vec![true; n],
            shape,
            reference_frame: 0,
            cam_from_body: Vec::new(),
            quality: Vec::new(),
            frames_too_few_points: 0,
            frames_degenerate: 0,
        }
    }

    #[test]
    fn a_rods_points_are_ordered_along_it_and_a_box_is_not_slender() {
        // Six points along a 30 cm rod 4 mm across, listed out of order.
        let along = [0.1, -0.15, 0.05, 0.15, -0.05, -0.1];
        let rod: Vec<Point3<f64>> = along
            .iter()
            .enumerate()
            .map(|(k, &z)| Point3::new(0.002 * (k % 2) as f64, 0.001, z))
            .collect();
        let order = along_long_axis(&body(rod), 0.1).expect("slender");
        let z = |i: usize| along[i - 10];
        let ascending = order.windows(2).all(|w| z(w[0]) < z(w[1]));
        let descending = order.windows(2).all(|w| z(w[0]) > z(w[1]));
        assert!(ascending || descending, "{order:?}");
        let cube: Vec<Point3<f64>> = (0..8)
            .map(|k| Point3::new((k & 1) as f64, ((k >> 1) & 1) as f64, (k >> 2) as f64))
            .collect();
        assert!(along_long_axis(&body(cube), 0.1).is_none());
        assert!(along_long_axis(&body(vec![Point3::origin(); 5]), 0.1).is_none());
    }
}
