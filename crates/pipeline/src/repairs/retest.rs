//! When the model has doubtful joints (multi-DoF, not followed by its whole-tree fit, or typed
//! by it), every pair is tested again on the poses of its whole-tree fit, which pose a small
//! body through its joint and every keypoint below it rather than from its own few points,
//! and the model is rebuilt on them; the rebuilt model replaces it when it has fewer doubtful
//! joints and re-predicts the keypoints about as well (`max_rms_growth`).
//!
//! A body hidden by its neighbours in nine frames of ten shares a handful of frames with each
//! other body; over ten frames two siblings turning about one anchor can pass for a hinge with
//! a better fit ratio than their true joints with the base over a hundred, and the tree takes
//! them. The fit then frees those joints, but the tree stays (`docs/decisions.md`, `retest`).

use super::{doubtful_joints, multi_dof_joints, not_followed, typed_by_fit};
use crate::runner::all_pairs;
use kinetree_core::{
    Draft, Edit, Error, Proposal, Repair, RepairContext, RepairPhase, Result, Warning,
};
use kinetree_fit::FittedMotions;
use kinetree_structure::find_pair;
use serde::{Deserialize, Serialize};

/// Parameters of [`Retest`] (`[pipeline.repairs.retest]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RetestParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Largest relative growth of the keypoints' re-prediction RMS for the rebuilt model to
    /// replace the first (default 0.25; `docs/decisions.md`, `retest.max_rms_growth`). Pair
    /// tests on the fitted poses confirm the joints those poses were fitted through, so a
    /// tree rebuilt on them can have fewer doubtful joints and explain the keypoints worse.
    /// The motion-capture preset sets 1e6, no bound.
    pub max_rms_growth: f64,
}

impl Default for RetestParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_rms_growth: 0.25,
        }
    }
}

impl RetestParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`](kinetree_core::Error::InvalidParameter) naming the
    /// parameter.
    pub fn validate(&self) -> Result<()> {
        super::in_range("retest", "max_rms_growth", self.max_rms_growth, 0.0, 1e6)
    }
}

/// Rebuilds the model on pair tests of its whole-tree fit's poses.
#[derive(Debug, Clone)]
pub struct Retest {
    params: RetestParams,
}

impl Retest {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: RetestParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for Retest {
    fn name(&self) -> &str {
        "retest"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Model
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let (Some(models), Some(found), Some(poses)) =
            (ctx.models, draft.model.as_ref(), draft.poses.as_ref())
        else {
            return Err(Error::Degenerate(
                "repair `retest` needs a model and its poses".into(),
            ));
        };
        // A joint typed by the fit was multi-DoF or not followed as its pair test typed it: a
        // hinge and a slide in series on a wrong tree edge can pass for one slide, so it
        // counts as doubtful here too.
        let before = doubtful_joints(&found.model);
        if before == 0 {
            return Ok(None);
        }
        // Joints typed by the fit, and universal joints, are left free for these poses: posed
        // through such a joint, a child would test as exactly that joint (a hinge taken for a
        // universal joint would stay one).
        let typed: Vec<(usize, usize)> = found
            .model
            .joints
            .iter()
            .filter(|j| {
                j.fit == kinetree_core::model::JointFit::TypedByFit
                    || j.joint_type == kinetree_core::model::JointType::Universal
            })
            .map(|j| (j.parent, j.child))
            .collect();
        let motions = if typed.is_empty() {
            let fitted = found.fitted.clone().ok_or_else(|| {
                Error::Degenerate("repair `retest` needs the model's whole-tree fit".into())
            })?;
            FittedMotions::from_fitted(fitted)
        } else {
            FittedMotions::freeing(&found.model, ctx.tracks, &typed)?
        };
        let fitted = motions.onto_body_poses(poses)?;
        let mut pairs = all_pairs(ctx.stages.dof, &fitted, ctx.noise_sigma_m, ctx.memo)?;
        // The static body keeps its test against the camera on its own poses: the fit poses
        // the root freely, from its keypoints and those below it, so the misfit of the doubtful
        // joints under it moves it and that test would find motion that is not there.
        if let (Some(s), Some(own)) = (found.model.static_body, draft.pairs.as_ref())
            && let Some(own) = find_pair(own, None, s)
            && let Some(slot) = pairs.iter_mut().find(|p| p.a.is_none() && p.b == s)
        {
            *slot = own.clone();
        }
        // The rebuilt model costs as much as the first: build it only if its tree has fewer
        // multi-DoF edges or gives a joint the fit did not follow another parent.
        let tree =
            kinetree_structure::spanning_tree(draft.segmentation.n_bodies(), &pairs, &ctx.tree)
                .ok_or_else(|| Error::Degenerate("no bodies".into()))?;
        let multi_edges = (0..tree.parent.len())
            .filter_map(|child| Some((tree.parent[child]?, child)))
            .filter(|&(p, c)| {
                !kinetree_structure::find_pair(&pairs, Some(p), c)
                    .is_some_and(|q| q.joint.is_single_dof())
            })
            .count();
        let reattached = not_followed(&found.model)
            .iter()
            .any(|&(p, c)| tree.parent.get(c).is_some_and(|&q| q != Some(p)));
        if multi_edges >= multi_dof_joints(&found.model) + typed_by_fit(&found.model) && !reattached
        {
            return Ok(None);
        }
        let mut again = models.make(&draft.segmentation, &fitted, &pairs, &found.history)?;
        let after = doubtful_joints(&again.model);
        if after >= before {
            return Ok(None);
        }
        let explains = match (
            again.model.reprediction_rms_in_sigma,
            found.model.reprediction_rms_in_sigma,
        ) {
            (Some(x), Some(m)) => x <= m * (1.0 + self.params.max_rms_growth),
            _ => false,
        };
        if !explains {
            return Ok(None);
        }
        again.model.warnings.push(Warning::PairsRetested {
            multi_dof_before: before,
            multi_dof_after: after,
        });
        Ok(Some(Proposal::new(
            Edit::Model {
                model: Box::new(again),
                poses: fitted,
            },
            format!("model rebuilt on the fitted poses: {before} -> {after} doubtful joints"),
        )))
    }
}
