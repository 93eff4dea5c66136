//! Near-tied tree edges settled by whole-tree fits.
//!
//! A tree edge whose child another body reaches at an edge cost at most `margin` higher is a
//! near tie ([`kinetree_structure::near_tied_edges`]). Each tree without one such edge is
//! fitted whole, at first plainly (one whole-tree fit of every frame, the joints as the pair
//! tests gave them); the best one that lowers the keypoints' squared residual by `gain` is
//! proposed, finished by the runner like the model, and kept when it still re-predicts better
//! with no more doubtful joints. A link turning on the base about an axis 3 deg from its
//! sibling's, through the same anchor, ties its edges with the base and with the sibling
//! (`docs/decisions.md`, `tree_ties`).

use super::{count_in_range, in_range, plain_sse, tree_inputs, tree_stands};
use kinetree_core::{Draft, Edit, Proposal, Repair, RepairContext, RepairPhase, Result};
use serde::{Deserialize, Serialize};

/// Parameters of [`TreeTies`] (`[pipeline.repairs.tree_ties]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TreeTiesParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Edge-cost margin of a near tie (default 0.05, a fit ratio of 0.1).
    pub margin: f64,
    /// Most near-tied edges tried per model (default 3; each costs a whole-tree fit of every
    /// frame).
    pub max_alternatives: usize,
    /// Near ties are looked for only in models of at most this many bodies (default 12; on a
    /// 21-body tree the alternatives doubled the run time with no joint gained).
    pub max_bodies: usize,
    /// Least relative drop of the keypoints' RMS residual for an alternative tree (default
    /// 0.02), first in a plain whole-tree fit, then finished.
    pub gain: f64,
}

impl Default for TreeTiesParams {
    fn default() -> Self {
        Self {
            enabled: true,
            margin: 0.05,
            max_alternatives: 3,
            max_bodies: 12,
            gain: 0.02,
        }
    }
}

impl TreeTiesParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "tree_ties";
        in_range(NAME, "margin", self.margin, 0.0, 10.0)?;
        count_in_range(NAME, "max_alternatives", self.max_alternatives, 0, 100)?;
        count_in_range(NAME, "max_bodies", self.max_bodies, 0, 100_000)?;
        in_range(NAME, "gain", self.gain, 0.0, 0.99)
    }
}

/// Proposes the best alternative to a near-tied tree edge.
#[derive(Debug, Clone)]
pub struct TreeTies {
    params: TreeTiesParams,
}

impl TreeTies {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: TreeTiesParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for TreeTies {
    fn name(&self) -> &str {
        "tree_ties"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Tree
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let (models, first, poses, pairs) = tree_inputs(self.name(), ctx, draft)?;
        let nb = draft.segmentation.n_bodies();
        if nb > self.params.max_bodies {
            return Ok(None);
        }
        let Some(tree) = kinetree_structure::spanning_tree(nb, pairs, &ctx.tree) else {
            return Ok(None);
        };
        let ties =
            kinetree_structure::near_tied_edges(nb, pairs, &tree, self.params.margin, &ctx.tree);
        if ties.is_empty() {
            return Ok(None);
        }
        let own = plain_sse(&first.model, ctx.tracks)?;
        let mut best: Option<((usize, usize), f64)> = None;
        for edge in ties.into_iter().take(self.params.max_alternatives) {
            let alt = models.assemble(
                &draft.segmentation,
                poses,
                pairs,
                &[edge],
                &[],
                &first.history,
            )?;
            let sse = plain_sse(&alt.model, ctx.tracks)?;
            let bar = best.as_ref().map_or(own, |c| c.1);
            if sse < bar * (1.0 - self.params.gain).powi(2) {
                best = Some((edge, sse));
            }
        }
        Ok(best.map(|(edge, sse)| {
            Proposal::new(
                Edit::Tree {
                    excluded: vec![edge],
                    replaced: Vec::new(),
                },
                format!(
                    "tree without edge {edge:?} fits {:.3} of the squared residual",
                    sse / own.max(f64::MIN_POSITIVE)
                ),
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
            x < m * (1.0 - self.params.gain)
        }))
    }
}
