//! The axes, pivots and reference poses of the single-DoF joints the fit follows
//! bundle-adjusted with every frame's configuration, all keypoints at once
//! ([`kinetree_fit::bundle_adjust`]).

use super::refit;
use kinetree_core::{Draft, Proposal, Repair, RepairContext, RepairPhase, Result};
use serde::{Deserialize, Serialize};

/// Parameters of [`BundleAdjust`] (`[pipeline.repairs.bundle_adjust]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BundleAdjustParams {
    /// Whether the repair runs. Off, the joints keep the parameters of their pair tests.
    pub enabled: bool,
}

impl Default for BundleAdjustParams {
    fn default() -> Self {
        Self { enabled: true }
    }
}

impl BundleAdjustParams {
    /// Checks the ranges (there are none).
    ///
    /// # Errors
    /// Never.
    pub fn validate(&self) -> Result<()> {
        Ok(())
    }
}

/// Bundle-adjusts the followed single-DoF joints.
#[derive(Debug, Clone)]
pub struct BundleAdjust {
    _params: BundleAdjustParams,
}

impl BundleAdjust {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: BundleAdjustParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { _params: params })
    }
}

impl Repair for BundleAdjust {
    fn name(&self) -> &str {
        "bundle_adjust"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Fit
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        refit(
            self.name(),
            ctx,
            draft,
            |model, state| {
                let (state, changed) = kinetree_fit::bundle_adjust(model, ctx.tracks, state)?;
                Ok((state, changed.then(Vec::new)))
            },
            |_| "joint axes, pivots and reference poses bundle-adjusted over every frame".into(),
        )
    }
}
