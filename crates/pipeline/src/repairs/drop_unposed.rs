//! Bodies registered in too few frames for a pose track dropped (their points go on no body).

use super::{count_in_range, poses_of};
use kinetree_core::{Draft, Edit, Proposal, Repair, RepairContext, RepairPhase, Result, Warning};
use serde::{Deserialize, Serialize};

/// Parameters of [`DropUnposed`] (`[pipeline.repairs.drop_unposed]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DropUnposedParams {
    /// Whether the repair runs. Off, a body registered in under `min_frames` frames stays
    /// and its pair tests are degenerate.
    pub enabled: bool,
    /// Registered frames a body needs (default 3: over two frames a pair test has one
    /// centred column, whose rank-one fit leaves no degree of freedom, so rigid and moving
    /// differ only by rounding, which follows the point order; `docs/decisions.md`).
    pub min_frames: usize,
}

impl Default for DropUnposedParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_frames: 3,
        }
    }
}

impl DropUnposedParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        count_in_range("drop_unposed", "min_frames", self.min_frames, 1, 1_000_000)
    }
}

/// Drops every body registered in fewer than `min_frames` frames.
#[derive(Debug, Clone)]
pub struct DropUnposed {
    params: DropUnposedParams,
}

impl DropUnposed {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: DropUnposedParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for DropUnposed {
    fn name(&self) -> &str {
        "drop_unposed"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn propose(&self, _ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let need = self.params.min_frames;
        let drop: Vec<usize> = (0..poses.bodies.len())
            .filter(|&b| poses.bodies[b].n_registered() < need)
            .collect();
        if drop.is_empty() {
            return Ok(None);
        }
        let mut p = Proposal::new(
            Edit::Segmentation(draft.segmentation.without_bodies(&drop)),
            format!(
                "{} body(ies) registered in under {need} frames dropped",
                drop.len()
            ),
        );
        for &b in &drop {
            let track = &poses.bodies[b];
            p.points.extend(&track.points);
            p.warnings.push(Warning::BodyDropped {
                points: track.points.clone(),
                reason: format!(
                    "registered in {} frame(s); {need} are needed",
                    track.n_registered()
                ),
            });
        }
        p.points.sort_unstable();
        Ok(Some(p))
    }
}
