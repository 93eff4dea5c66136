//! Multi-DoF joints whose child still moves as a hinge or a slide in the whole-tree fit typed
//! by the fit, and freed single-DoF joints given the other single-DoF type
//! ([`kinetree_fit::type_joints_by_fit`]; a `joint_typed_by_fit` warning). A small body's
//! noisy poses can fake a second degree of freedom in its pair test (`docs/decisions.md`,
//! `type_by_fit`).

use super::{count_in_range, in_range, refit};
use kinetree_core::{Draft, Proposal, Repair, RepairContext, RepairPhase, Result};
use kinetree_fit::TypeByFitLimits;
use serde::{Deserialize, Serialize};

/// Parameters of [`TypeByFit`] (`[pipeline.repairs.type_by_fit]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TypeByFitParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A typed joint's excess must be within this (default 3.0).
    pub max_excess: f64,
    /// ... and every other joint's within this (default 30, the freeing bound).
    pub others_max_excess: f64,
    /// Only joints whose pair test found at most this many rotation directions are tried
    /// (default 1).
    pub max_rotation_rank: usize,
    /// ... and at most this many translation directions (default 2). Spherical and
    /// universal joints are tried as hinges whatever their ranks...
    pub max_translation_rank: usize,
    /// ... when their fitted rotations stray from one axis (a universal joint: one of its
    /// angles spreads) by at most this many standard deviations, RMS (default 20).
    pub max_ball_off_axis_in_std: f64,
    /// A universal joint is typed spherical first when the ball lowers the fit's squared
    /// residual, in noise variances, by more than the `K` frames with angles plus this many
    /// `sqrt(2 K)` (a chance gain's standard deviation), or, freed, when the fit follows the
    /// ball (default 5).
    pub min_ball_gain_in_std: f64,
    /// Whether every hinge the fit follows is tried as a universal joint, parents first
    /// (default false: each trial costs two whole-tree fits and a bundle adjustment).
    pub hinges_as_universal: bool,
    /// Such a hinge is typed universal when the second axis lowers the fit's squared
    /// residual, in noise variances, by more than the `K` frames where both joints have
    /// positions plus this many `sqrt(2 K)` (default 5).
    pub min_universal_gain_in_std: f64,
    /// ... and by at least this many noise variances per frame (default 5;
    /// `docs/decisions.md`).
    pub min_universal_gain_per_frame: f64,
    /// Only hinges whose child a ball about the pivot places better than the hinge by at
    /// least this many noise variances per frame, on the parent's fitted poses, are tried
    /// (default 2.5; a true hinge gains about two; `docs/decisions.md`).
    pub universal_screen_per_frame: f64,
    /// A candidate whose excess before its bundle adjustment is above this is dropped
    /// unadjusted (default 1000; `docs/decisions.md`).
    pub max_excess_to_adjust: f64,
    /// Whether a candidate is first bundle-adjusted with only the joints that share a body
    /// with it, and dropped when its excess is then above `max_local_excess` (default true;
    /// a fraction of the cost of adjusting every joint).
    pub screen_locally: bool,
    /// That bound (default 9; `docs/decisions.md`).
    pub max_local_excess: f64,
    /// Most bundle-adjustment steps on each candidate type (default 20, as
    /// `bundle_adjust.max_steps`).
    pub bundle_max_steps: usize,
    /// Its stopping gain in noise variances (default 0.1, as
    /// `bundle_adjust.min_gain_in_variances`).
    pub bundle_min_gain_in_variances: f64,
}

impl Default for TypeByFitParams {
    fn default() -> Self {
        let l = TypeByFitLimits::default();
        Self {
            enabled: true,
            max_excess: l.max_excess,
            others_max_excess: l.others_max_excess,
            max_rotation_rank: l.max_rotation_rank,
            max_translation_rank: l.max_translation_rank,
            max_ball_off_axis_in_std: l.max_ball_off_axis_in_std,
            min_ball_gain_in_std: l.min_ball_gain_in_std,
            hinges_as_universal: l.hinges_as_universal,
            min_universal_gain_in_std: l.min_universal_gain_in_std,
            min_universal_gain_per_frame: l.min_universal_gain_per_frame,
            universal_screen_per_frame: l.universal_screen_per_frame,
            max_excess_to_adjust: l.max_excess_to_adjust,
            screen_locally: l.screen_locally,
            max_local_excess: l.max_local_excess,
            bundle_max_steps: l.bundle.max_steps,
            bundle_min_gain_in_variances: l.bundle.min_gain_in_variances,
        }
    }
}

impl TypeByFitParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "type_by_fit";
        in_range(NAME, "max_excess", self.max_excess, 0.0, 1e12)?;
        in_range(NAME, "others_max_excess", self.others_max_excess, 0.0, 1e12)?;
        count_in_range(NAME, "max_rotation_rank", self.max_rotation_rank, 0, 3)?;
        count_in_range(
            NAME,
            "max_translation_rank",
            self.max_translation_rank,
            0,
            3,
        )?;
        in_range(
            NAME,
            "max_ball_off_axis_in_std",
            self.max_ball_off_axis_in_std,
            0.0,
            1e12,
        )?;
        in_range(
            NAME,
            "min_ball_gain_in_std",
            self.min_ball_gain_in_std,
            0.0,
            1e6,
        )?;
        in_range(
            NAME,
            "min_universal_gain_in_std",
            self.min_universal_gain_in_std,
            0.0,
            1e6,
        )?;
        in_range(
            NAME,
            "min_universal_gain_per_frame",
            self.min_universal_gain_per_frame,
            0.0,
            1e6,
        )?;
        in_range(
            NAME,
            "universal_screen_per_frame",
            self.universal_screen_per_frame,
            0.0,
            1e6,
        )?;
        in_range(
            NAME,
            "max_excess_to_adjust",
            self.max_excess_to_adjust,
            0.0,
            1e300,
        )?;
        in_range(NAME, "max_local_excess", self.max_local_excess, 0.0, 1e300)?;
        count_in_range(NAME, "bundle_max_steps", self.bundle_max_steps, 1, 1000)?;
        in_range(
            NAME,
            "bundle_min_gain_in_variances",
            self.bundle_min_gain_in_variances,
            0.0,
            1e6,
        )
    }
}

/// Types joints by the whole-tree fit.
#[derive(Debug, Clone)]
pub struct TypeByFit {
    params: TypeByFitParams,
}

impl TypeByFit {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: TypeByFitParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for TypeByFit {
    fn name(&self) -> &str {
        "type_by_fit"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Fit
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let p = &self.params;
        let limits = TypeByFitLimits {
            max_excess: p.max_excess,
            others_max_excess: p.others_max_excess,
            max_rotation_rank: p.max_rotation_rank,
            max_translation_rank: p.max_translation_rank,
            max_ball_off_axis_in_std: p.max_ball_off_axis_in_std,
            min_ball_gain_in_std: p.min_ball_gain_in_std,
            hinges_as_universal: p.hinges_as_universal,
            min_universal_gain_in_std: p.min_universal_gain_in_std,
            min_universal_gain_per_frame: p.min_universal_gain_per_frame,
            universal_screen_per_frame: p.universal_screen_per_frame,
            max_excess_to_adjust: p.max_excess_to_adjust,
            screen_locally: p.screen_locally,
            max_local_excess: p.max_local_excess,
            bundle: kinetree_fit::BundleLimits {
                max_steps: p.bundle_max_steps,
                min_gain_in_variances: p.bundle_min_gain_in_variances,
                ..kinetree_fit::BundleLimits::default()
            },
        };
        refit(
            self.name(),
            ctx,
            draft,
            |model, state| {
                let (state, typed) =
                    kinetree_fit::type_joints_by_fit(model, ctx.tracks, state, &limits)?;
                Ok((state, (!typed.is_empty()).then_some(typed)))
            },
            |n| format!("{n} joint(s) typed by the whole-tree fit"),
        )
    }
}
