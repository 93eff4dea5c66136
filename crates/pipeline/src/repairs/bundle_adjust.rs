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
    /// Most Gauss-Newton steps ([`kinetree_fit::BundleLimits::max_steps`], default 20).
    pub max_steps: usize,
    /// The adjustment stops below this gain in noise variances
    /// ([`kinetree_fit::BundleLimits::min_gain_in_variances`], default 0.1).
    pub min_gain_in_variances: f64,
    /// Most frames the adjustment works on, evenly spaced over longer recordings
    /// ([`kinetree_fit::BundleLimits::max_frames`], default 20 000).
    pub max_frames: usize,
    /// Most observations whose visible points are kept between the steps; over more they
    /// are formed again at each use, with the same result
    /// ([`kinetree_fit::BundleLimits::max_kept_observations`], default 2 000 000).
    pub max_kept_observations: usize,
}

impl Default for BundleAdjustParams {
    fn default() -> Self {
        let b = kinetree_fit::BundleLimits::default();
        Self {
            enabled: true,
            max_steps: b.max_steps,
            min_gain_in_variances: b.min_gain_in_variances,
            max_frames: b.max_frames,
            max_kept_observations: b.max_kept_observations,
        }
    }
}

impl BundleAdjustParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming
    /// `pipeline.repairs.bundle_adjust.<parameter>`.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "bundle_adjust";
        super::count_in_range(NAME, "max_steps", self.max_steps, 1, 1000)?;
        super::count_in_range(NAME, "max_frames", self.max_frames, 2, usize::MAX)?;
        super::in_range(
            NAME,
            "min_gain_in_variances",
            self.min_gain_in_variances,
            0.0,
            1e6,
        )
    }

    /// The adjustment's limits.
    pub fn limits(&self) -> kinetree_fit::BundleLimits {
        kinetree_fit::BundleLimits {
            max_steps: self.max_steps,
            min_gain_in_variances: self.min_gain_in_variances,
            max_frames: self.max_frames,
            max_kept_observations: self.max_kept_observations,
        }
    }
}

/// Bundle-adjusts the followed single-DoF joints.
#[derive(Debug, Clone)]
pub struct BundleAdjust {
    params: BundleAdjustParams,
}

impl BundleAdjust {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: BundleAdjustParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
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
                let (state, changed) =
                    kinetree_fit::bundle_adjust(model, ctx.tracks, state, &self.params.limits())?;
                Ok((state, changed.then(Vec::new)))
            },
            |_| "joint axes, pivots and reference poses bundle-adjusted over every frame".into(),
        )
    }
}
