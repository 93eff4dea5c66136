//! Freed joints put back into the fit when, refined against their child's keypoints with the
//! parent posed by the fit, the fit then follows them ([`kinetree_fit::readmit_freed_joints`]):
//! a small parent's noisy poses can mislead the tester about a true joint. Joints of random
//! mechanisms whose small parents had misled the tester came back at 0.7-1.9; human joints of
//! the real recordings at 21-25, and with them in the fit the re-prediction rose from 2.3 to
//! 2.8 sigma (`docs/decisions.md`, `readmit_joints.max_excess`).

use super::{in_range, refit};
use kinetree_core::{Draft, Proposal, Repair, RepairContext, RepairPhase, Result};
use serde::{Deserialize, Serialize};

/// Parameters of [`ReadmitJoints`] (`[pipeline.repairs.readmit_joints]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReadmitJointsParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A refined joint is put back when its excess is within this (default 10).
    pub max_excess: f64,
    /// ... and every other joint's within this (default 30, the freeing bound).
    pub others_max_excess: f64,
}

impl Default for ReadmitJointsParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_excess: 10.0,
            others_max_excess: kinetree_fit::MAX_JOINT_EXCESS,
        }
    }
}

impl ReadmitJointsParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        in_range("readmit_joints", "max_excess", self.max_excess, 0.0, 1e12)?;
        in_range(
            "readmit_joints",
            "others_max_excess",
            self.others_max_excess,
            0.0,
            1e12,
        )
    }
}

/// Puts freed joints back when they fit again.
#[derive(Debug, Clone)]
pub struct ReadmitJoints {
    params: ReadmitJointsParams,
}

impl ReadmitJoints {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: ReadmitJointsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for ReadmitJoints {
    fn name(&self) -> &str {
        "readmit_joints"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Fit
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let p = self.params;
        refit(
            self.name(),
            ctx,
            draft,
            |model, state| {
                let (state, back) = kinetree_fit::readmit_freed_joints(
                    model,
                    ctx.tracks,
                    state,
                    p.max_excess,
                    p.others_max_excess,
                )?;
                Ok((state, (!back.is_empty()).then_some(back)))
            },
            |n| format!("{n} freed joint(s) refined and put back into the fit"),
        )
    }
}
