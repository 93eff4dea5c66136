//! The estimated noise level refined on the pairs inside the bodies found
//! ([`kinetree_dissimilarity::refine_noise_sigma`]), and the clustering redone at it.

use super::{count_in_range, in_range};
use kinetree_core::{
    Draft, Edit, Proposal, Repair, RepairContext, RepairLimit, RepairPhase, Result,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`NoiseRefinement`] (`[pipeline.repairs.noise_refinement]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseRefinementParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Refinement rounds, each followed by a new clustering (default 2).
    pub rounds: usize,
    /// Largest relative change from the first estimate (default 0.1): merged bodies inflate
    /// the refined level, the F-test then merges more, and the loop runs away
    /// (`docs/decisions.md`, `noise_refinement.limit`).
    pub limit: f64,
    /// Relative change under which the clustering is not redone and the refinement ends
    /// (default 0.01).
    pub min_change: f64,
}

impl Default for NoiseRefinementParams {
    fn default() -> Self {
        Self {
            enabled: true,
            rounds: 2,
            limit: 0.1,
            min_change: 0.01,
        }
    }
}

impl NoiseRefinementParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "noise_refinement";
        count_in_range(NAME, "rounds", self.rounds, 0, 100)?;
        in_range(NAME, "limit", self.limit, 0.0, 0.9)?;
        in_range(NAME, "min_change", self.min_change, 0.0, 1.0)
    }
}

/// Refines an estimated noise level inside the bodies of the current clustering, within
/// `limit` of the first estimate; asked `rounds` times.
#[derive(Debug, Clone)]
pub struct NoiseRefinement {
    params: NoiseRefinementParams,
}

impl NoiseRefinement {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: NoiseRefinementParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for NoiseRefinement {
    fn name(&self) -> &str {
        "noise_refinement"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Grouping
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Edits(self.params.rounds)
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let Some(first_guess) = ctx.estimated_noise_sigma_m else {
            return Ok(None);
        };
        let Some(s) = kinetree_dissimilarity::refine_noise_sigma(ctx.stats, &draft.segmentation)
        else {
            return Ok(None);
        };
        let limit = self.params.limit;
        let s = s.clamp(first_guess * (1.0 - limit), first_guess * (1.0 + limit));
        let changed = (s / ctx.noise_sigma_m - 1.0).abs() > self.params.min_change;
        Ok(Some(Proposal::new(
            Edit::NoiseLevel {
                sigma_m: s,
                redo_clustering: changed,
            },
            format!(
                "noise level {:.4e} m -> {s:.4e} m (first estimate {first_guess:.4e} m)",
                ctx.noise_sigma_m
            ),
        )))
    }
}
