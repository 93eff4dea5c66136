//! Points that fit no body's fitted motion (far off their own) left on no body, and kept off
//! the attachment for the rest of the run
//! ([`kinetree_fit::FittedMotions::points_fitting_no_body`]).

use super::move_points::{fitted_model, points_settle};
use kinetree_core::{
    Constraints, Draft, Edit, Proposal, Repair, RepairContext, RepairPhase, Result, Warning,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`EjectPoints`] (`[pipeline.repairs.eject_points]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EjectPointsParams {
    /// Whether the repair runs.
    pub enabled: bool,
}

impl Default for EjectPointsParams {
    fn default() -> Self {
        Self { enabled: true }
    }
}

impl EjectPointsParams {
    /// Checks the ranges (there are none).
    ///
    /// # Errors
    /// Never.
    pub fn validate(&self) -> Result<()> {
        Ok(())
    }
}

/// Takes off bodies the points whose track no body's fitted motion explains.
#[derive(Debug, Clone)]
pub struct EjectPoints {
    _params: EjectPointsParams,
}

impl EjectPoints {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: EjectPointsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { _params: params })
    }
}

impl Repair for EjectPoints {
    fn name(&self) -> &str {
        "eject_points"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Points
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let (found, motions) = fitted_model(self.name(), draft)?;
        let ejected: Vec<usize> = motions
            .points_fitting_no_body(&found.model, ctx.tracks)?
            .into_iter()
            .filter(|i| !draft.pending.iter().any(|(p, _)| p == i))
            .collect();
        if ejected.is_empty() {
            return Ok(None);
        }
        let mut p = Proposal::new(
            Edit::Points(ejected.iter().map(|&i| (i, None)).collect()),
            format!(
                "{} point(s) that fit no body's motion left on none",
                ejected.len()
            ),
        );
        p.points.clone_from(&ejected);
        p.points.sort_unstable();
        p.constraints = Constraints {
            kept_off: ejected.clone(),
            ..Constraints::default()
        };
        p.warnings
            .push(Warning::PointsUnassigned { points: ejected });
        Ok(Some(p))
    }

    fn stands(
        &self,
        ctx: &RepairContext<'_>,
        edit: &Edit,
        _before: &Draft,
        after: &Draft,
    ) -> Result<bool> {
        points_settle(self.name(), ctx, edit, after)
    }
}
