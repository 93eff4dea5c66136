//! Bodies that turn or slide with their parent about one axis hung on the grandparent when a
//! whole-tree fit tells the two trees apart by no more than noise.
//!
//! Two gripper fingers on one pin or one rail each move relative to the hand and to each
//! other by a joint of the same type, so a chain through one finger fits the data as well as
//! both fingers on the hand. [`kinetree_structure::spanning_tree`] hoists such a body when its
//! pair tests say so within a fit margin; the pair tests' fit ratios scatter too much for that
//! margin to catch every tie (`docs/decisions.md`, `sibling_ties`). For each body it leaves
//! (`kinetree_structure::fit_margin_ties`), this repair fits the tree with the body on its
//! grandparent whole, and proposes it when the keypoints' squared residual grows by at most
//! `max_cost_per_frame` noise variances per frame the body is seen with the grandparent: a
//! joint a few degrees off the parent's axis costs more. The proposal stands when the
//! finished model has no more doubtful joints and re-predicts the keypoints within
//! `rms_tolerance` of the model.

use super::{count_in_range, in_range, plain_sse, tree_inputs, tree_stands};
use kinetree_core::{Draft, Edit, Proposal, Repair, RepairContext, RepairPhase, Result};
use kinetree_structure::find_pair;
use serde::{Deserialize, Serialize};

/// Parameters of [`SiblingTies`] (`[pipeline.repairs.sibling_ties]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SiblingTiesParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Largest growth of the keypoints' squared residual, in noise variances per frame the
    /// body is seen with its grandparent, for the two trees to count as tied (default 1.0).
    pub max_cost_per_frame: f64,
    /// Largest relative growth of the finished model's re-prediction RMS for the tree with
    /// the body on its grandparent to stand (default 0.01).
    pub rms_tolerance: f64,
    /// Most bodies tried per model (default 3; each costs a whole-tree fit of every frame).
    pub max_alternatives: usize,
}

impl Default for SiblingTiesParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_cost_per_frame: 1.0,
            rms_tolerance: 0.01,
            max_alternatives: 3,
        }
    }
}

impl SiblingTiesParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "sibling_ties";
        in_range(
            NAME,
            "max_cost_per_frame",
            self.max_cost_per_frame,
            0.0,
            1e6,
        )?;
        in_range(NAME, "rms_tolerance", self.rms_tolerance, 0.0, 1.0)?;
        count_in_range(NAME, "max_alternatives", self.max_alternatives, 0, 100)
    }
}

/// Proposes the tree with a tied body on its grandparent.
#[derive(Debug, Clone)]
pub struct SiblingTies {
    params: SiblingTiesParams,
}

impl SiblingTies {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SiblingTiesParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for SiblingTies {
    fn name(&self) -> &str {
        "sibling_ties"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Tree
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let (models, first, poses, pairs) = tree_inputs(self.name(), ctx, draft)?;
        let nb = draft.segmentation.n_bodies();
        let Some(tree) = kinetree_structure::spanning_tree(nb, pairs, &ctx.tree) else {
            return Ok(None);
        };
        let ties = kinetree_structure::fit_margin_ties(pairs, &tree);
        if ties.is_empty() {
            return Ok(None);
        }
        let variance = first.model.noise.sigma_m.powi(2).max(f64::MIN_POSITIVE);
        let own = plain_sse(&first.model, ctx.tracks)?;
        let mut best: Option<((usize, usize), f64)> = None;
        for (w, u, v) in ties.into_iter().take(self.params.max_alternatives) {
            let edge = (u, v);
            let hoisted = kinetree_structure::spanning_tree_without(nb, pairs, &[edge], &ctx.tree);
            if hoisted.is_none_or(|t| t.parent[v] != Some(w)) {
                continue;
            }
            let frames = find_pair(pairs, Some(w), v).map_or(0, |p| p.translation.n_columns);
            if frames == 0 {
                continue;
            }
            let alt =
                models.assemble(&draft.segmentation, poses, pairs, &[edge], &first.history)?;
            let cost = (plain_sse(&alt.model, ctx.tracks)? - own) / variance / frames as f64;
            if cost <= self.params.max_cost_per_frame && best.is_none_or(|b| cost < b.1) {
                best = Some((edge, cost));
            }
        }
        Ok(best.map(|(edge, cost)| {
            Proposal::new(
                Edit::Tree(vec![edge]),
                format!("tree without edge {edge:?} costs {cost:.3} noise variances per frame"),
            )
        }))
    }

    fn stands(
        &self,
        _ctx: &RepairContext<'_>,
        _edit: &Edit,
        before: &Draft,
        after: &Draft,
    ) -> Result<bool> {
        Ok(tree_stands(before, after, |x, m| {
            x <= m * (1.0 + self.params.rms_tolerance)
        }))
    }
}
