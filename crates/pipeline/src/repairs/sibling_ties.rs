//! Bodies that turn or slide with their parent about one axis hung on the grandparent when a
//! whole-tree fit tells the two trees apart by no more than noise.
//!
//! Two gripper fingers on one pin or one rail each move relative to the hand and to each
//! other by a joint of the same type, so a chain through one finger fits the data as well as
//! both fingers on the hand. [`kinetree_structure::spanning_tree`] hoists such a body when its
//! pair tests say so within a fit margin; the pair tests' fit ratios scatter too much for that
//! margin to catch every tie (`docs/decisions.md`, `sibling_ties`). The same holds for fingers
//! whose knuckles flex about one line: a finger's hinge on its neighbour can test clearer than
//! its hinge on the palm. The candidates are the bodies [`kinetree_structure::fit_margin_ties`] leaves and
//! those [`kinetree_structure::collinear_hinge_ties`] finds (which may carry other bodies).
//! For each, this repair fits the tree with the body on its grandparent whole, and keeps the
//! hoist when the keypoints' squared residual grows by at most `max_cost_per_frame` noise
//! variances per frame the body is seen with the grandparent: a joint a few degrees off the
//! parent's axis costs more. With `universal_candidates`, a body whose pair with the
//! grandparent is a universal joint (a knuckle that also swings its finger sideways) is a
//! candidate too; it has one more coordinate there, so the fit must instead gain at least
//! `universal_min_gain_per_frame`. The hoists kept are proposed
//! together; the proposal stands when the finished model has no more doubtful joints (or,
//! with a body on a universal joint, which counts as doubtful, no more joints the fit cannot
//! follow) and re-predicts the keypoints within `rms_tolerance` of the model.

use super::{count_in_range, in_range, not_followed, plain_sse, tree_inputs, tree_stands};
use kinetree_core::{Draft, Edit, JointKind, Proposal, Repair, RepairContext, RepairPhase, Result};
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
    /// Largest angle, degrees, between a body's hinge on its parent and the parent's hinge on
    /// the grandparent for the two to turn about one line
    /// ([`kinetree_structure::collinear_hinge_ties`]; default 20).
    pub collinear_max_angle_deg: f64,
    /// Largest distance between those two hinge lines, over the distance between the body's
    /// and its parent's origins, for them to be one line (default 0.4).
    pub collinear_max_offset: f64,
    /// Largest distance of the body's hinge on its grandparent from the grandparent's nearest
    /// keypoint, over the RMS distance of the grandparent's keypoints from its origin: the
    /// hinge must pass by the grandparent (default 1).
    pub collinear_max_reach: f64,
    /// Whether a body whose pair with its grandparent is a universal joint is a candidate too
    /// (default false: on the hands sweep it hangs more fingers on the palm, whose knuckles
    /// the fit then types as balls; `docs/decisions.md`, `sibling_ties.universal_candidates`).
    pub universal_candidates: bool,
    /// Such a body is moved onto its grandparent only when the fit gains at least this many
    /// noise variances per frame the two are seen together (default 5, as
    /// `type_by_fit.min_universal_gain_per_frame`): the second axis is one more coordinate,
    /// which gains about one per frame by chance.
    pub universal_min_gain_per_frame: f64,
}

impl Default for SiblingTiesParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_cost_per_frame: 1.0,
            rms_tolerance: 0.01,
            max_alternatives: 3,
            collinear_max_angle_deg: 20.0,
            collinear_max_offset: 0.4,
            collinear_max_reach: 1.0,
            universal_candidates: false,
            universal_min_gain_per_frame: 5.0,
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
        in_range(
            NAME,
            "collinear_max_angle_deg",
            self.collinear_max_angle_deg,
            0.0,
            90.0,
        )?;
        in_range(
            NAME,
            "collinear_max_offset",
            self.collinear_max_offset,
            0.0,
            1e3,
        )?;
        in_range(
            NAME,
            "collinear_max_reach",
            self.collinear_max_reach,
            0.0,
            1e3,
        )?;
        in_range(
            NAME,
            "universal_min_gain_per_frame",
            self.universal_min_gain_per_frame,
            0.0,
            1e6,
        )?;
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
        let variance = first.model.noise.sigma_m.powi(2).max(f64::MIN_POSITIVE);
        let mut own = None;
        let mut cost_of =
            |excluded: &[(usize, usize)], w: usize, v: usize| -> Result<Option<f64>> {
                let frames = find_pair(pairs, Some(w), v).map_or(0, |p| p.translation.n_columns);
                if frames == 0 {
                    return Ok(None);
                }
                let own = match own {
                    Some(x) => x,
                    None => *own.insert(plain_sse(&first.model, ctx.tracks)?),
                };
                let alt =
                    models.assemble(&draft.segmentation, poses, pairs, excluded, &first.history)?;
                Ok(Some(
                    (plain_sse(&alt.model, ctx.tracks)? - own) / variance / frames as f64,
                ))
            };
        let mut tried = 0;
        // The ties the fit margin left: the tree without the body's edge, when it hangs the
        // body on its grandparent; the one that costs least.
        let mut best: Option<((usize, usize), f64)> = None;
        for (w, u, v) in kinetree_structure::fit_margin_ties(pairs, &tree) {
            if tried == self.params.max_alternatives {
                break;
            }
            tried += 1;
            let edge = (u, v);
            let hoisted = kinetree_structure::spanning_tree_without(nb, pairs, &[edge], &ctx.tree);
            if hoisted.is_none_or(|t| t.parent[v] != Some(w)) {
                continue;
            }
            if let Some(cost) = cost_of(&[edge], w, v)?
                && cost <= self.params.max_cost_per_frame
                && best.is_none_or(|b| cost < b.1)
            {
                best = Some((edge, cost));
            }
        }
        if let Some((edge, cost)) = best {
            return Ok(Some(Proposal::new(
                Edit::Tree(vec![edge]),
                format!("tree without edge {edge:?} costs {cost:.3} noise variances per frame"),
            )));
        }
        // Bodies on a parent's hinge line: the tree with just the body moved, and every such
        // move that costs little at once.
        let mut hoisted = tree.parent.clone();
        let mut costs = Vec::new();
        for (w, u, v) in kinetree_structure::collinear_hinge_ties(
            pairs,
            poses,
            &tree,
            self.params.collinear_max_angle_deg.to_radians(),
            self.params.collinear_max_offset,
            self.params.collinear_max_reach,
        ) {
            let universal = find_pair(pairs, Some(w), v)
                .is_some_and(|p| matches!(p.joint, JointKind::Universal { .. }));
            if universal && !self.params.universal_candidates {
                continue;
            }
            if tried == self.params.max_alternatives {
                break;
            }
            tried += 1;
            let mut parent = tree.parent.clone();
            parent[v] = Some(w);
            let bound = if universal {
                -self.params.universal_min_gain_per_frame
            } else {
                self.params.max_cost_per_frame
            };
            if let Some(cost) = cost_of(&off_the_tree(pairs, &parent), w, v)?
                && cost <= bound
            {
                hoisted[v] = Some(w);
                costs.push(format!("{v} from {u} onto {w}: {cost:.3}"));
            }
        }
        if costs.is_empty() {
            return Ok(None);
        }
        Ok(Some(Proposal::new(
            Edit::Tree(off_the_tree(pairs, &hoisted)),
            format!(
                "bodies moved onto their grandparents' hinge lines cost, in noise variances \
                 per frame each is seen with its grandparent, {}",
                costs.join(", ")
            ),
        )))
    }

    fn stands(
        &self,
        ctx: &RepairContext<'_>,
        edit: &Edit,
        before: &Draft,
        after: &Draft,
    ) -> Result<bool> {
        let within = |x: f64, m: f64| x <= m * (1.0 + self.params.rms_tolerance);
        if tree_stands(before, after, within) {
            return Ok(true);
        }
        // A body moved onto its grandparent by a universal joint passed
        // `universal_min_gain_per_frame` in `propose`, so here the universal joint (or the
        // ball the fit may type it) does not count as doubtful, as it otherwise does (a
        // hinge noise can fake one): the move stands when the fit frees no more joints and
        // the model re-predicts the keypoints as well.
        let (Edit::Tree(excluded), Some(b), Some(a), Some(pairs)) = (
            edit,
            before.model.as_ref(),
            after.model.as_ref(),
            before.pairs.as_ref(),
        ) else {
            return Ok(false);
        };
        let (model, alt) = (&b.model, &a.model);
        let Some(tree) = kinetree_structure::spanning_tree_without(
            before.segmentation.n_bodies(),
            pairs,
            excluded,
            &ctx.tree,
        ) else {
            return Ok(false);
        };
        let moved_onto_universal = (0..tree.parent.len()).any(|v| {
            tree.parent[v].is_some_and(|w| {
                !model.joints.iter().any(|j| (j.parent, j.child) == (w, v))
                    && find_pair(pairs, Some(w), v)
                        .is_some_and(|p| matches!(p.joint, JointKind::Universal { .. }))
            })
        });
        Ok(moved_onto_universal
            && not_followed(alt).len() <= not_followed(model).len()
            && matches!(
                (alt.reprediction_rms_in_sigma, model.reprediction_rms_in_sigma),
                (Some(x), Some(m)) if within(x, m)
            ))
    }
}

/// Every tested pair between two bodies that is not an edge of the tree `parent`: left out,
/// they leave the spanning tree no other choice.
fn off_the_tree(pairs: &[kinetree_core::PairDof], parent: &[Option<usize>]) -> Vec<(usize, usize)> {
    pairs
        .iter()
        .filter_map(|p| {
            let (a, b) = (p.a?, p.b);
            let edge = parent.get(b) == Some(&Some(a)) || parent.get(a) == Some(&Some(b));
            (!edge).then_some((a, b))
        })
        .collect()
}
