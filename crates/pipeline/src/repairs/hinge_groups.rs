//! Points on no body that turn together about one axis of a posed body (or of the camera)
//! made a body, which the `hinges` repair then poses through that hinge. A group that does not
//! turn as one is cut in two by the `halves` slot, down to `min_points` keypoints.
//!
//! A link hidden by its neighbours so that at most two of its keypoints show at once gets no
//! pose of its own; its children then look multi-DoF on the base.

use super::hinges::{HingeBounds, best_hinge};
use super::{accepted_groups, count_in_range, poses_of};
use kinetree_core::{
    Draft, Edit, Proposal, Repair, RepairContext, RepairLimit, RepairPhase, Result,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`HingeGroups`] (`[pipeline.repairs.hinge_groups]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HingeGroupsParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Frames a keypoint must be seen in (default 10, `kinetree_pose::MIN_HINGE_FRAMES`).
    pub min_frames: usize,
    /// Smallest group (default 2).
    pub min_points: usize,
    /// Slack on the hinge's `chi^2` bound ([`HingeBounds::slack`], default 2.0).
    pub slack: f64,
    /// Std-devs of the hinge's `chi^2` bound ([`HingeBounds::bound_in_std`], default 4.0).
    pub bound_in_std: f64,
    /// Least sweep of the hinge angle ([`HingeBounds::min_arc_in_std`], default 20).
    pub min_arc_in_std: f64,
    /// Largest RMS misfit of the hinge ([`HingeBounds::max_rms_in_sigma`], default 3.0).
    pub max_rms_in_sigma: f64,
    /// A keypoint a body's poses explain within this many std-devs (the attachment's rule,
    /// `kinetree_pose::explains_point`; default 4) is not grouped.
    pub explained_bound_in_std: f64,
    /// Slack on that bound (default 2).
    pub explained_slack: f64,
    /// As [`super::HingesParams::min_fit_frames`] (default 10).
    pub min_fit_frames: usize,
    /// As [`super::HingesParams::min_spread_in_sigma`] (default 5).
    pub min_spread_in_sigma: f64,
    /// As [`super::HingesParams::min_lever_in_sigma`] (default 3).
    pub min_lever_in_sigma: f64,
}

impl Default for HingeGroupsParams {
    fn default() -> Self {
        let b = HingeBounds::default();
        Self {
            enabled: true,
            min_frames: kinetree_pose::MIN_HINGE_FRAMES,
            min_points: 2,
            slack: b.slack,
            bound_in_std: b.bound_in_std,
            min_arc_in_std: b.min_arc_in_std,
            max_rms_in_sigma: b.max_rms_in_sigma,
            explained_bound_in_std: kinetree_pose::ATTACH_BOUND.0,
            explained_slack: kinetree_pose::ATTACH_BOUND.1,
            min_fit_frames: b.fit.min_frames,
            min_spread_in_sigma: b.fit.min_spread_in_sigma,
            min_lever_in_sigma: b.fit.min_lever_in_sigma,
        }
    }
}

impl HingeGroupsParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "hinge_groups";
        count_in_range(NAME, "min_frames", self.min_frames, 2, 1_000_000)?;
        count_in_range(NAME, "min_points", self.min_points, 1, 1_000_000)?;
        super::in_range(
            NAME,
            "explained_bound_in_std",
            self.explained_bound_in_std,
            0.0,
            20.0,
        )?;
        super::in_range(NAME, "explained_slack", self.explained_slack, 0.1, 100.0)?;
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

/// Makes bodies of unassigned keypoints that turn together on a hinge; asked once per bodies
/// phase.
#[derive(Debug, Clone)]
pub struct HingeGroups {
    params: HingeGroupsParams,
}

impl HingeGroups {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: HingeGroupsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for HingeGroups {
    fn name(&self) -> &str {
        "hinge_groups"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Once
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let (tracks, sigma, seg) = (ctx.tracks, ctx.noise_sigma_m, &draft.segmentation);
        let nb = poses.bodies.len();
        let explained = (
            self.params.explained_bound_in_std,
            self.params.explained_slack,
        );
        let left: Vec<usize> = super::unassigned_points(tracks, seg, self.params.min_frames)
            .into_iter()
            .filter(|&i| {
                !(0..nb)
                    .any(|b| kinetree_pose::explains_point(tracks, poses, b, i, sigma, explained))
            })
            .collect();
        let bounds = self.params.bounds();
        let turns =
            |group: &[usize]| best_hinge(&bounds, tracks, poses, group, None, sigma, ctx.memo);
        // The clusters discarded as too small for a pose first: rigid groups the clustering
        // found, which halving the rest would not reach (its clusterer keeps no part under
        // three keypoints). Two markers of a segment whose others sit on its joint's axis
        // are one.
        let mut groups = Vec::new();
        let mut rest = left;
        for g in &seg.discarded_groups {
            let g: Vec<usize> = g.iter().copied().filter(|i| rest.contains(i)).collect();
            if g.len() >= self.params.min_points && turns(&g).is_some() {
                rest.retain(|i| !g.contains(i));
                groups.push(g);
            }
        }
        groups.extend(accepted_groups(
            ctx,
            rest,
            self.params.min_points,
            |group| Ok(turns(group).is_some()),
        )?);
        groups.sort();
        if groups.is_empty() {
            return Ok(None);
        }
        let mut p = Proposal::new(
            Edit::Segmentation(super::with_new_bodies(seg, &groups)),
            format!(
                "{} group(s) of keypoints turning on a hinge made bodies",
                groups.len()
            ),
        );
        p.points = groups.iter().flatten().copied().collect();
        p.points.sort_unstable();
        Ok(Some(p))
    }
}
