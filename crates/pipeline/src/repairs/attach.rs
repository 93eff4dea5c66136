//! Points on no body given to the one body whose poses explain them
//! ([`kinetree_pose::attach_unassigned`]); never a point the constraints keep off, and never
//! so as to remake a body a split undid.

use super::poses_of;
use kinetree_core::{
    Draft, Edit, Proposal, Repair, RepairContext, RepairLimit, RepairPhase, Result, Warning,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`Attach`] (`[pipeline.repairs.attach]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AttachParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Std-devs of the Wilson-Hilferty quantile that bounds a point's `chi^2 / k` misfit to a
    /// body's poses (`kinetree_pose::misfit_bound`; default 4).
    pub bound_in_std: f64,
    /// Slack on that bound for the approximations in the predicted variance (default 2).
    pub slack: f64,
    /// Fewest points of its own (shared points not counted) a body needs to take a point
    /// (default 3): a body posed through its joint by two markers explains far markers
    /// too loosely on skin data.
    pub min_own_points: usize,
}

impl Default for AttachParams {
    fn default() -> Self {
        Self {
            enabled: true,
            bound_in_std: kinetree_pose::ATTACH_BOUND.0,
            slack: kinetree_pose::ATTACH_BOUND.1,
            min_own_points: 3,
        }
    }
}

impl AttachParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `pipeline.repairs.attach.<parameter>`.
    pub fn validate(&self) -> Result<()> {
        use super::in_range;
        in_range("attach", "bound_in_std", self.bound_in_std, 0.0, 20.0)?;
        in_range("attach", "slack", self.slack, 0.1, 100.0)?;
        super::count_in_range("attach", "min_own_points", self.min_own_points, 1, 1000)
    }
}

/// Attaches points on no body where exactly one body's poses explain them; asked once per
/// bodies phase, and again after each split.
#[derive(Debug, Clone)]
pub struct Attach {
    params: AttachParams,
}

impl Attach {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: AttachParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for Attach {
    fn name(&self) -> &str {
        "attach"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Once
    }

    fn reopened_by(&self) -> &[&str] {
        &["split"]
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let c = &draft.constraints;
        let (refined, attached) = kinetree_pose::attach_unassigned(
            ctx.tracks,
            poses,
            &draft.segmentation,
            ctx.noise_sigma_m,
            &[c.kept_off.as_slice(), &c.off_hinge].concat(),
            &c.undone_bodies,
            kinetree_pose::AttachRule {
                bound: (self.params.bound_in_std, self.params.slack),
                min_own: self.params.min_own_points,
            },
        );
        if attached.is_empty() {
            return Ok(None);
        }
        let mut p = Proposal::new(
            Edit::Segmentation(refined),
            format!(
                "{} point(s) attached to the body whose poses explain them",
                attached.len()
            ),
        );
        p.points.clone_from(&attached);
        p.warnings
            .push(Warning::PointsAttached { points: attached });
        Ok(Some(p))
    }
}
