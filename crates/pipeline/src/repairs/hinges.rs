//! Bodies registered in few frames posed through a hinge on a posed body (or the camera) where
//! they lack a pose of their own; a keypoint that does not turn with the hinge is taken off
//! first.
//!
//! A link hidden by its neighbours in most frames (a few frames with three keypoints, many
//! with one or two) is registered only in those few; its joints are then tested over them
//! alone, and its children's over the frames they share.

use super::{in_range, poses_of};
use kinetree_core::memo::{Fingerprint, Memo};
use kinetree_core::{
    BodyPoses, Constraints, Draft, Edit, Proposal, Repair, RepairContext, RepairPhase, Result,
    Tracks, Warning,
};
use kinetree_pose::Hinge;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// When a group of keypoints is taken to turn on a hinge (`best_hinge`); used by [`Hinges`]
/// and [`super::HingeGroups`], each with these four parameters in its own config section.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HingeBounds {
    /// Slack on the `chi^2 / dof` bound at `bound_in_std` std-devs (Wilson-Hilferty) for the
    /// approximations of the predicted variance (default 2.0, the rule of
    /// `kinetree_pose::attach_unassigned`).
    pub slack: f64,
    /// Std-devs of the `chi^2` bound (default 4.0).
    pub bound_in_std: f64,
    /// Least sweep of the hinge angle, in std-devs of one frame's angle (default 20): below,
    /// the group hardly turns and the axis is a guess.
    pub min_arc_in_std: f64,
    /// Largest RMS distance of the keypoints from where the hinge puts them, in noise
    /// std-devs (default 3.0): the `chi^2` counts the parent's pose noise at each keypoint's
    /// lever arm, so a poorly posed parent passes almost any hinge (`docs/decisions.md`,
    /// `hinges.max_rms_in_sigma`).
    pub max_rms_in_sigma: f64,
    /// When a hinge can be fitted at all: frames, spread across the axis, lever arm.
    pub fit: kinetree_pose::HingeLimits,
}

impl Default for HingeBounds {
    fn default() -> Self {
        Self {
            slack: 2.0,
            bound_in_std: 4.0,
            min_arc_in_std: 20.0,
            max_rms_in_sigma: 3.0,
            fit: kinetree_pose::HingeLimits::default(),
        }
    }
}

impl HingeBounds {
    pub(crate) fn validate(&self, repair: &str) -> Result<()> {
        in_range(repair, "slack", self.slack, 0.1, 100.0)?;
        in_range(repair, "bound_in_std", self.bound_in_std, 0.0, 20.0)?;
        in_range(repair, "min_arc_in_std", self.min_arc_in_std, 0.0, 1e6)?;
        in_range(repair, "max_rms_in_sigma", self.max_rms_in_sigma, 0.0, 1e6)?;
        super::count_in_range(repair, "min_fit_frames", self.fit.min_frames, 3, 1_000_000)?;
        in_range(
            repair,
            "min_spread_in_sigma",
            self.fit.min_spread_in_sigma,
            0.0,
            1e6,
        )?;
        in_range(
            repair,
            "min_lever_in_sigma",
            self.fit.min_lever_in_sigma,
            0.0,
            1e6,
        )
    }

    pub(crate) fn bound(&self, dof: f64) -> f64 {
        kinetree_pose::misfit_bound(dof, self.bound_in_std, self.slack)
    }
}

/// Parameters of [`Hinges`] (`[pipeline.repairs.hinges]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HingesParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A body registered in at most this share of the frames that show one of its keypoints
    /// is tried (default 0.5).
    pub max_reposed_share: f64,
    /// ... and posed through the hinge when that poses it in at least this many times as many
    /// frames (default 1.5).
    pub min_repose_gain: f64,
    /// A body registered in fewer frames than this (one `drop_unposed` would drop, at its
    /// default) that no hinge poses has the keypoint taken off without which one does
    /// (default 3; 0 turns it off; `docs/decisions.md`, `hinges.peel_below_frames`).
    pub peel_below_frames: usize,
    /// Slack on the hinge's `chi^2` bound ([`HingeBounds::slack`], default 2.0).
    pub slack: f64,
    /// Std-devs of the hinge's `chi^2` bound ([`HingeBounds::bound_in_std`], default 4.0).
    pub bound_in_std: f64,
    /// Least sweep of the hinge angle ([`HingeBounds::min_arc_in_std`], default 20).
    pub min_arc_in_std: f64,
    /// Largest RMS misfit of the hinge ([`HingeBounds::max_rms_in_sigma`], default 3.0).
    pub max_rms_in_sigma: f64,
    /// Fewest frames with the parent posed and a keypoint seen for a hinge fit
    /// ([`kinetree_pose::HingeLimits::min_frames`], default 10).
    pub min_fit_frames: usize,
    /// Least spread of the keypoint tracks across the axis
    /// ([`kinetree_pose::HingeLimits::min_spread_in_sigma`], default 5).
    pub min_spread_in_sigma: f64,
    /// Least lever arm of a keypoint that tells the angle
    /// ([`kinetree_pose::HingeLimits::min_lever_in_sigma`], default 3).
    pub min_lever_in_sigma: f64,
}

impl Default for HingesParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_reposed_share: 0.5,
            min_repose_gain: 1.5,
            peel_below_frames: 3,
            slack: HingeBounds::default().slack,
            bound_in_std: HingeBounds::default().bound_in_std,
            min_arc_in_std: HingeBounds::default().min_arc_in_std,
            max_rms_in_sigma: HingeBounds::default().max_rms_in_sigma,
            min_fit_frames: kinetree_pose::MIN_HINGE_FRAMES,
            min_spread_in_sigma: kinetree_pose::MIN_HINGE_SPREAD_IN_SIGMA,
            min_lever_in_sigma: kinetree_pose::MIN_LEVER_IN_SIGMA,
        }
    }
}

impl HingesParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "hinges";
        in_range(NAME, "max_reposed_share", self.max_reposed_share, 0.0, 1.0)?;
        in_range(NAME, "min_repose_gain", self.min_repose_gain, 1.0, 1e6)?;
        super::count_in_range(
            NAME,
            "peel_below_frames",
            self.peel_below_frames,
            0,
            1_000_000,
        )?;
        self.bounds().validate(NAME)
    }

    /// The hinge bounds of these parameters.
    pub fn bounds(&self) -> HingeBounds {
        HingeBounds {
            slack: self.slack,
            bound_in_std: self.bound_in_std,
            min_arc_in_std: self.min_arc_in_std,
            max_rms_in_sigma: self.max_rms_in_sigma,
            fit: kinetree_pose::HingeLimits {
                min_frames: self.min_fit_frames,
                min_spread_in_sigma: self.min_spread_in_sigma,
                min_lever_in_sigma: self.min_lever_in_sigma,
            },
        }
    }
}

/// Poses bodies registered in few frames through their best hinge; asked after every pose
/// estimate, as the other bodies' poses change.
#[derive(Debug, Clone)]
pub struct Hinges {
    params: HingesParams,
}

impl Hinges {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: HingesParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }

    /// Bodies registered in at most `max_reposed_share` of the frames that show one of their
    /// keypoints that turn on another body about one axis, with the hinge, when it poses them
    /// in at least `min_repose_gain` times as many frames. By body.
    fn reposed(
        &self,
        tracks: &Tracks,
        poses: &BodyPoses,
        sigma: f64,
        memo: Option<&Memo>,
    ) -> Vec<(usize, Hinge)> {
        // Bodies in parallel; an indexed collect keeps them in order.
        (0..poses.bodies.len())
            .into_par_iter()
            .filter_map(|b| {
                let track = &poses.bodies[b];
                let own = super::sparsely_registered(tracks, track, self.params.max_reposed_share)?;
                let h = best_hinge(
                    &self.params.bounds(),
                    tracks,
                    poses,
                    &track.points,
                    Some(b),
                    sigma,
                    memo,
                )?;
                (h.track.n_registered() as f64 >= self.params.min_repose_gain * own as f64)
                    .then_some((b, h))
            })
            .collect()
    }

    /// Per body registered in under `peel_below_frames` frames that no hinge poses (none of
    /// `reposed`), the keypoint without which one does (the lowest RMS residual, then the
    /// earlier keypoint): a keypoint of another body grouped with a poorly seen link keeps
    /// every hinge from holding, and the link, never seen by three keypoints at once, would
    /// be dropped with all of them. Never one of `done`, never from a body of three or fewer.
    fn peeled(
        &self,
        tracks: &Tracks,
        poses: &BodyPoses,
        reposed: &[(usize, Hinge)],
        sigma: f64,
        done: &[usize],
        memo: Option<&Memo>,
    ) -> Vec<usize> {
        let bounds = self.params.bounds();
        (0..poses.bodies.len())
            .filter(|b| reposed.iter().all(|(r, _)| r != b))
            .filter_map(|b| {
                let track = &poses.bodies[b];
                if track.points.len() <= kinetree_core::MIN_BODY_POINTS
                    || track.n_registered() >= self.params.peel_below_frames
                {
                    return None;
                }
                let hinges = scored_without_each(&track.points, done, |rest| {
                    best_hinge(&bounds, tracks, poses, rest, Some(b), sigma, memo)
                        .map(|h| h.rms_residual_m)
                });
                hinges
                    .into_iter()
                    .min_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)))
                    .map(|(_, p)| p)
            })
            .collect()
    }

    /// The keypoint of `points` (posed through `hinge`) that does not turn with it, if one
    /// clearly does not: the hinge refitted on the same parent without it lowers the `chi^2`
    /// by more than the hinge bound allows for the degrees of freedom it had (the worst such
    /// keypoint); never one of `done`, and never from a body of three or fewer.
    ///
    /// A keypoint of a poorly seen link clustered onto its neighbour rides along when the
    /// neighbour is posed through its hinge, since the fit weighs it by its few frames; the
    /// neighbour's joint then tests multi-DoF (`docs/decisions.md`, `hinges`).
    fn off_hinge_point(
        &self,
        ctx: &RepairContext<'_>,
        poses: &BodyPoses,
        points: &[usize],
        hinge: &Hinge,
        done: &[usize],
    ) -> Option<usize> {
        if points.len() <= kinetree_core::MIN_BODY_POINTS {
            return None;
        }
        let (tracks, sigma, memo) = (ctx.tracks, ctx.noise_sigma_m, ctx.memo);
        let chi2 = hinge.chi2_per_dof * hinge.dof;
        let limits = self.params.bounds().fit;
        let gains = scored_without_each(points, done, |rest| {
            let without = hinged_body(tracks, poses, hinge.parent, rest, sigma, &limits, memo)?;
            let dof = hinge.dof - without.dof;
            let gain = (chi2 - without.chi2_per_dof * without.dof) / dof;
            (dof >= 1.0 && gain > self.params.bounds().bound(dof)).then_some(gain)
        });
        gains
            .into_iter()
            .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)))
            .map(|(_, p)| p)
    }
}

/// `(score, keypoint)` for each keypoint of `points` not in `done` that `score` gives a value
/// with that keypoint left out, in the order of `points`; the keypoints are tried in
/// parallel.
fn scored_without_each(
    points: &[usize],
    done: &[usize],
    score: impl Fn(&[usize]) -> Option<f64> + Sync,
) -> Vec<(f64, usize)> {
    let tried: Vec<usize> = points
        .iter()
        .copied()
        .filter(|p| !done.contains(p))
        .collect();
    let scores: Vec<Option<(f64, usize)>> = tried
        .par_iter()
        .map(|&p| {
            let rest: Vec<usize> = points.iter().copied().filter(|&q| q != p).collect();
            score(&rest).map(|v| (v, p))
        })
        .collect();
    scores.into_iter().flatten().collect()
}

/// [`kinetree_pose::hinged_body`], looked up in `memo` when the same group was fitted on the
/// same parent track before (the fit reads the tracks, which a discovery never changes, the
/// parent's track and the arguments).
fn hinged_body(
    tracks: &Tracks,
    poses: &BodyPoses,
    parent: Option<usize>,
    group: &[usize],
    sigma: f64,
    limits: &kinetree_pose::HingeLimits,
    memo: Option<&Memo>,
) -> Option<Hinge> {
    let fit = || kinetree_pose::hinged_body(tracks, poses, parent, group, sigma, limits);
    // The camera as parent has no track; a parent out of range is left to the fit to refuse.
    let track = parent.map_or(Some(None), |b| poses.bodies.get(b).map(Some));
    let (Some(memo), Some(track)) = (memo, track) else {
        return fit();
    };
    let mut key = Fingerprint::new("hinged body");
    key.option_usize(parent)
        .indices(group)
        .usize(poses.n_frames)
        .f64(sigma)
        .usize(limits.min_frames)
        .f64(limits.min_spread_in_sigma)
        .f64(limits.min_lever_in_sigma);
    if let Some(track) = track {
        key.track(track);
    }
    memo.get_or_compute(key.finish(), fit, |h| {
        h.as_ref()
            .map_or(0, |h| kinetree_core::memo::track_bytes(&h.track))
    })
}

/// Of the hinges of `group` on the posed bodies other than `skip` and on the camera frame
/// that hold (within the `chi^2` bound, the group rigid, at most `max_rms_in_sigma` off,
/// sweeping `min_arc_in_std`), the one that explains the keypoints best (lowest RMS residual,
/// then the most frames posed). A true hinge on a body's parent, child or the camera gives the
/// same poses, but a body turning about an axis 3 deg from its sibling's through one anchor
/// also fits a hinge on the sibling within the `chi^2` bound; its residual is larger.
pub(crate) fn best_hinge(
    bounds: &HingeBounds,
    tracks: &Tracks,
    poses: &BodyPoses,
    group: &[usize],
    skip: Option<usize>,
    sigma: f64,
    memo: Option<&Memo>,
) -> Option<Hinge> {
    // The group's rigidity does not depend on the parent: checked once, first.
    let (rigidity, rigidity_dof) = kinetree_pose::group_rigidity(tracks, group, sigma);
    if rigidity > bounds.bound(rigidity_dof) {
        return None;
    }
    let parents: Vec<Option<usize>> = std::iter::once(None)
        .chain((0..poses.bodies.len()).map(Some))
        .filter(|&parent| parent.is_none() || parent != skip)
        .collect();
    // The hinge on each candidate parent is fitted in parallel; the best is chosen in order.
    let hinges: Vec<Option<Hinge>> = parents
        .par_iter()
        .map(|&parent| hinged_body(tracks, poses, parent, group, sigma, &bounds.fit, memo))
        .collect();
    hinges
        .into_iter()
        .flatten()
        .filter(|h| {
            h.chi2_per_dof <= bounds.bound(h.dof)
                && h.arc_in_std >= bounds.min_arc_in_std
                && h.rms_residual_m <= bounds.max_rms_in_sigma * sigma
        })
        .min_by(|x, y| {
            x.rms_residual_m
                .total_cmp(&y.rms_residual_m)
                .then(y.track.n_registered().cmp(&x.track.n_registered()))
        })
}

impl Repair for Hinges {
    fn name(&self) -> &str {
        "hinges"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let (tracks, sigma) = (ctx.tracks, ctx.noise_sigma_m);
        let reposed = self.reposed(tracks, poses, sigma, ctx.memo);
        let done = &draft.constraints.off_hinge;
        let mut off: Vec<usize> = reposed
            .iter()
            .filter_map(|(b, h)| {
                self.off_hinge_point(ctx, poses, &poses.bodies[*b].points, h, done)
            })
            .collect();
        if off.is_empty() {
            off = self.peeled(tracks, poses, &reposed, sigma, done, ctx.memo);
        }
        if reposed.is_empty() && off.is_empty() {
            return Ok(None);
        }
        if !off.is_empty() {
            let mut p = Proposal::new(
                Edit::Segmentation(draft.segmentation.without_points(&off)),
                "keypoints that do not turn with their body's hinge taken off",
            );
            p.points.clone_from(&off);
            p.points.sort_unstable();
            p.constraints = Constraints {
                off_hinge: off.clone(),
                ..Constraints::default()
            };
            p.warnings.push(Warning::PointsOffHinge { points: off });
            return Ok(Some(p));
        }
        let mut out = poses.clone();
        let (mut warnings, mut points) = (Vec::new(), Vec::new());
        for (b, h) in reposed {
            let (track, filled) = kinetree_pose::filled_from_hinge(&poses.bodies[b], &h);
            points.extend(&track.points);
            warnings.push(Warning::BodyPosedThroughHinge {
                points: track.points.clone(),
                parent: h.parent.map(|q| poses.bodies[q].points.clone()),
                frames: filled,
            });
            out.bodies[b] = track;
        }
        let mut p = Proposal::new(
            Edit::Poses(out),
            format!("{} body(ies) posed through a hinge", warnings.len()),
        );
        points.sort_unstable();
        (p.points, p.warnings) = (points, warnings);
        Ok(Some(p))
    }
}
