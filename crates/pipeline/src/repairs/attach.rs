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
}

impl Default for AttachParams {
    fn default() -> Self {
        Self { enabled: true }
    }
}

impl AttachParams {
    /// Checks the ranges (there are none).
    ///
    /// # Errors
    /// Never.
    pub fn validate(&self) -> Result<()> {
        Ok(())
    }
}

/// Attaches points on no body where exactly one body's poses explain them; asked once per
/// bodies phase, and again after each split.
#[derive(Debug, Clone)]
pub struct Attach {
    _params: AttachParams,
}

impl Attach {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: AttachParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { _params: params })
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
