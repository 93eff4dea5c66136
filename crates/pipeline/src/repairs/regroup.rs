//! Points on no body that move as one rigid body made a body: all of them if they do, else
//! each half (the `halves` slot), and so on down to three points.
//!
//! The pairwise measure can break a small body apart (4 points have 6 pairs, and with the
//! F-test's `q` uniform on rigid pairs a point's mean to the others is over the cut one time
//! in a dozen); its poses still show one body. A group is taken only when the pairwise
//! measure does not keep its halves apart ([`super::halves_apart`]).

use super::{accepted_groups, halves_apart, in_range, points_fit_as_one, unassigned_points};
use kinetree_core::{
    Draft, Edit, Proposal, Repair, RepairContext, RepairLimit, RepairPhase, Result, Warning,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`Regroup`] (`[pipeline.repairs.regroup]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegroupParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A group fits as one body when its median pose residual is at most this many noise
    /// std-devs (default 2.5, the split's bound).
    pub residual_in_sigma: f64,
}

impl Default for RegroupParams {
    fn default() -> Self {
        Self {
            enabled: true,
            residual_in_sigma: 2.5,
        }
    }
}

impl RegroupParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        in_range(
            "regroup",
            "residual_in_sigma",
            self.residual_in_sigma,
            0.1,
            1e6,
        )
    }
}

/// Makes bodies of unassigned points that move as one; asked once per bodies phase.
#[derive(Debug, Clone)]
pub struct Regroup {
    params: RegroupParams,
}

impl Regroup {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: RegroupParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for Regroup {
    fn name(&self) -> &str {
        "regroup"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Once
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let left = unassigned_points(ctx.tracks, &draft.segmentation, 2);
        let bound = self.params.residual_in_sigma;
        let groups = accepted_groups(ctx, left, kinetree_core::MIN_BODY_POINTS, |group| {
            Ok(!halves_apart(ctx, group)? && points_fit_as_one(ctx, group, bound)?)
        })?;
        if groups.is_empty() {
            return Ok(None);
        }
        let mut p = Proposal::new(
            Edit::Segmentation(super::with_new_bodies(&draft.segmentation, &groups)),
            format!("{} group(s) of unassigned points made bodies", groups.len()),
        );
        p.points = groups.iter().flatten().copied().collect();
        p.points.sort_unstable();
        p.warnings.push(Warning::UnassignedPointsGrouped { groups });
        Ok(Some(p))
    }
}
