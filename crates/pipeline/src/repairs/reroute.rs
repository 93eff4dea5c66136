//! Tree edges the whole-tree fit cannot follow by far left out: the model is made again without
//! them, and replaces the first when fewer of its joints are multi-DoF or freed.
//!
//! A hand's fingers flex about parallel axes, so a phalanx of one finger can pass the pair test
//! as hinged on a phalanx of another, and the tree takes that edge. The whole-tree fit then
//! frees the joint (its child misses the fit by hundreds of noise variances a point), but the
//! tree stays; without the edge, the tree takes the finger's own joint.

use super::{in_range, not_followed, tree_inputs};
use kinetree_core::{Draft, Edit, Proposal, Repair, RepairContext, RepairPhase, Result, Warning};
use serde::{Deserialize, Serialize};

/// Parameters of [`Reroute`] (`[pipeline.repairs.reroute]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RerouteParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A freed joint's edge is left out when its child missed the whole-tree fit by more than
    /// this many noise variances a point beyond its own pose (the `joint_not_followed`
    /// warning's excess; default 100, `docs/decisions.md`, `reroute`).
    pub min_excess_in_sigma2: f64,
}

impl Default for RerouteParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_excess_in_sigma2: 100.0,
        }
    }
}

impl RerouteParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        in_range(
            "reroute",
            "min_excess_in_sigma2",
            self.min_excess_in_sigma2,
            0.0,
            1e12,
        )
    }
}

/// Joints of `m` that no joint type explains: multi-DoF, or freed by its whole-tree fit. A
/// universal or ball joint the fit follows is a joint, unlike in `retest`'s count: the rerouted
/// tree of a hand has one at every knuckle.
fn unexplained_joints(m: &kinetree_core::Model) -> usize {
    let multi = m
        .joints
        .iter()
        .filter(|j| j.joint_type == kinetree_core::model::JointType::MultiDof)
        .count();
    multi + not_followed(m).len()
}

/// Makes the model again without the edges of joints its whole-tree fit misses by far.
#[derive(Debug, Clone)]
pub struct Reroute {
    params: RerouteParams,
}

impl Reroute {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: RerouteParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for Reroute {
    fn name(&self) -> &str {
        "reroute"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Model
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        // Pair tests redone on other poses (`retest`) leave none here; the edges are then
        // those tests' to choose.
        if draft.pairs.is_none() {
            return Ok(None);
        }
        let (models, found, poses, pairs) = tree_inputs(self.name(), ctx, draft)?;
        let freed = not_followed(&found.model);
        let mut far: Vec<(usize, usize)> = found
            .model
            .warnings
            .iter()
            .filter_map(|w| match *w {
                Warning::JointNotFollowed {
                    parent,
                    child,
                    excess_in_sigma2,
                } if excess_in_sigma2 > self.params.min_excess_in_sigma2 => Some((parent, child)),
                _ => None,
            })
            .filter(|edge| freed.contains(edge))
            .collect();
        far.sort_unstable();
        far.dedup();
        if far.is_empty() {
            return Ok(None);
        }
        let before = unexplained_joints(&found.model);
        let again = models.make_without(&draft.segmentation, poses, pairs, &far, &found.history)?;
        let after = unexplained_joints(&again.model);
        if after >= before {
            return Ok(None);
        }
        let summary = format!(
            "model made again without the edges {far:?}, which its fit missed by far: {before} -> {after} joints multi-DoF or freed"
        );
        Ok(Some(Proposal::new(
            Edit::Model {
                model: Box::new(again),
                poses: poses.clone(),
            },
            summary,
        )))
    }
}
