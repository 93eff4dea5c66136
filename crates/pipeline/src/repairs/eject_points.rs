//! Points that fit no body's fitted motion (far off their own) left on no body, and kept off
//! the attachment for the rest of the run
//! ([`kinetree_fit::FittedMotions::points_fitting_no_body`]).

use super::move_points::{fitted_model, points_settle};
use super::{count_in_range, in_range};
use kinetree_core::{
    Constraints, Draft, Edit, Proposal, Repair, RepairContext, RepairPhase, Result, Warning,
};
use kinetree_fit::MotionLimits;
use serde::{Deserialize, Serialize};

/// Parameters of [`EjectPoints`] (`[pipeline.repairs.eject_points]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EjectPointsParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Frames a point needs with a body's fitted pose to count in the body's median misfit
    /// ([`MotionLimits::min_frames`], default 10).
    pub min_frames: usize,
    /// Frames a point needs with a body's fitted pose to be placed on it or judged on it
    /// ([`MotionLimits::min_frames_to_place`], default 5).
    pub min_frames_to_place: usize,
    /// A point is taken off when it fits its body this many times worse than the larger of
    /// the body's median and the bound, and no other body within the bound
    /// ([`MotionLimits::outlier_ratio`], default 5).
    pub outlier_ratio: f64,
}

impl Default for EjectPointsParams {
    fn default() -> Self {
        let l = MotionLimits::default();
        Self {
            enabled: true,
            min_frames: l.min_frames,
            min_frames_to_place: l.min_frames_to_place,
            outlier_ratio: l.outlier_ratio,
        }
    }
}

impl EjectPointsParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "eject_points";
        count_in_range(NAME, "min_frames", self.min_frames, 2, 1_000_000)?;
        count_in_range(
            NAME,
            "min_frames_to_place",
            self.min_frames_to_place,
            2,
            1_000_000,
        )?;
        in_range(NAME, "outlier_ratio", self.outlier_ratio, 1.0, 1e6)
    }

    /// The motion limits of these parameters (the defaults for the rest).
    pub fn limits(&self) -> MotionLimits {
        MotionLimits {
            min_frames: self.min_frames,
            min_frames_to_place: self.min_frames_to_place,
            outlier_ratio: self.outlier_ratio,
            ..MotionLimits::default()
        }
    }
}

/// Takes off bodies the points whose track no body's fitted motion explains.
#[derive(Debug, Clone)]
pub struct EjectPoints {
    params: EjectPointsParams,
}

impl EjectPoints {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: EjectPointsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
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
        let (found, motions) = fitted_model(self.name(), draft, self.params.limits())?;
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
        points_settle(self.name(), ctx, edit, after, self.params.limits())
    }
}
