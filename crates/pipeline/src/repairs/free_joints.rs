//! Joints the whole-tree fit cannot follow freed, one at a time
//! ([`kinetree_fit::free_unfollowed_joints`]): the child is then posed freely in the fit, and
//! the joint's positions come from the two bodies' fitted poses (a `joint_not_followed`
//! warning). On random mechanisms the largest excess of a model was under 4 in nine of ten and
//! 10-30 where a pivot was a few centimetres off; joints the model gets wrong reach 50-200
//! (`docs/decisions.md`, `free_joints.max_excess`).

use super::{count_in_range, in_range, refit};
use kinetree_core::{Draft, Proposal, Repair, RepairContext, RepairPhase, Result};
use serde::{Deserialize, Serialize};

/// Parameters of [`FreeJoints`] (`[pipeline.repairs.free_joints]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FreeJointsParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A joint whose child misses the fit by more than this, in `sigma^2` per point beyond
    /// its own pose, is freed (default 30).
    pub max_excess: f64,
    /// With more candidate joints than `screen_keep`, each is first fitted on every
    /// `screen_stride`-th frame only, from the current fit of each such frame (default 4; 1
    /// fits every candidate on every frame) ...
    pub screen_stride: usize,
    /// ... and only the `screen_keep` best there are fitted on every frame (default 2).
    pub screen_keep: usize,
}

impl Default for FreeJointsParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_excess: kinetree_fit::MAX_JOINT_EXCESS,
            screen_stride: kinetree_fit::FreeLimits::default().screen_stride,
            screen_keep: kinetree_fit::FreeLimits::default().screen_keep,
        }
    }
}

impl FreeJointsParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        in_range("free_joints", "max_excess", self.max_excess, 0.0, 1e12)?;
        count_in_range(
            "free_joints",
            "screen_stride",
            self.screen_stride,
            1,
            1_000_000,
        )?;
        count_in_range("free_joints", "screen_keep", self.screen_keep, 1, 1_000_000)
    }

    /// The limits of [`kinetree_fit::free_unfollowed_joints`].
    pub fn limits(&self) -> kinetree_fit::FreeLimits {
        kinetree_fit::FreeLimits {
            max_excess: self.max_excess,
            screen_stride: self.screen_stride,
            screen_keep: self.screen_keep,
        }
    }
}

/// Frees the joints the fit cannot follow.
#[derive(Debug, Clone)]
pub struct FreeJoints {
    params: FreeJointsParams,
}

impl FreeJoints {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: FreeJointsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for FreeJoints {
    fn name(&self) -> &str {
        "free_joints"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Fit
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let limits = self.params.limits();
        refit(
            self.name(),
            ctx,
            draft,
            |model, state| {
                let (state, freed) =
                    kinetree_fit::free_unfollowed_joints(model, ctx.tracks, state, &limits)?;
                Ok((state, (!freed.is_empty()).then_some(freed)))
            },
            |n| format!("{n} joint(s) the fit cannot follow freed"),
        )
    }
}
