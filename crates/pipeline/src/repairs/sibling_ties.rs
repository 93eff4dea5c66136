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
//!
//! With `quiet_siblings`, when neither finds a hoist: two bodies that move against each other
//! by a hinge or a slide while a pair with a third tests rigid within its bounds (a gripper's
//! finger sliding a few noise levels, whose motion the pair test's slack for model error
//! hides) are hung on the third by the joint their pairs share ([`Edit::Tree`] with the pairs replaced), when the
//! fit costs at most `max_cost_per_frame` and each such body's position on its joint spreads
//! between `quiet_min_spread_in_std` and `quiet_max_spread_in_std` of its precision.

use super::{
    count_in_range, in_range, not_followed, plain_sse, rigid_within_bounds, tree_inputs,
    tree_stands,
};
use kinetree_core::nalgebra::{Point3, Vector3};
use kinetree_core::{
    BodyPoses, Draft, Edit, JointKind, PairDof, Proposal, Repair, RepairContext, RepairPhase,
    Result,
};
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
    /// Whether two bodies whose pair is a hinge or a slide are tried as siblings on a third
    /// body that one of them tests rigid with, by the joint their pairs share (default true):
    /// a gripper's finger that moves a few noise levels tests rigid with the hand
    /// (`docs/decisions.md`, `sibling_ties.quiet_siblings`).
    pub quiet_siblings: bool,
    /// Least spread of such a body's position on the joint in the plain whole-tree fit, RMS
    /// about its mean in the fit's per-frame standard deviations, for it to count as moving
    /// (default 1.5; `docs/decisions.md`, `sibling_ties.quiet_spread_in_std`): a body that
    /// does not move spreads about 1.
    pub quiet_min_spread_in_std: f64,
    /// Largest such spread (default 10): a body moving that much along one axis shows in its
    /// pair test, so a rigid verdict on it came from other frames or another fault. The fit
    /// may gain at most its square in noise variances per frame for each such body.
    pub quiet_max_spread_in_std: f64,
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
            quiet_siblings: true,
            quiet_min_spread_in_std: 1.5,
            quiet_max_spread_in_std: 10.0,
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
        in_range(
            NAME,
            "quiet_min_spread_in_std",
            self.quiet_min_spread_in_std,
            0.0,
            1e6,
        )?;
        in_range(
            NAME,
            "quiet_max_spread_in_std",
            self.quiet_max_spread_in_std,
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
        let own: std::cell::Cell<Option<f64>> = std::cell::Cell::new(None);
        // The plain whole-tree fit's squared residual of the first model, fitted once.
        let own_sse = || -> Result<f64> {
            if let Some(x) = own.get() {
                return Ok(x);
            }
            let x = plain_sse(&first.model, ctx.tracks)?;
            own.set(Some(x));
            Ok(x)
        };
        // The growth of the keypoints' squared residual, in noise variances per frame `v` is
        // seen with `w`, of the tree without the edges `excluded`.
        let cost_of = |excluded: &[(usize, usize)], w: usize, v: usize| -> Result<Option<f64>> {
            let frames = find_pair(pairs, Some(w), v).map_or(0, |p| p.translation.n_columns);
            if frames == 0 {
                return Ok(None);
            }
            let own = own_sse()?;
            let alt = models.assemble(
                &draft.segmentation,
                poses,
                pairs,
                excluded,
                &[],
                &first.history,
            )?;
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
                Edit::Tree {
                    excluded: vec![edge],
                    replaced: Vec::new(),
                },
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
            if !self.params.quiet_siblings || tried == self.params.max_alternatives {
                return Ok(None);
            }
            return self.quiet_hoist(
                ctx,
                draft,
                &tree,
                self.params.max_alternatives - tried,
                &own_sse,
            );
        }
        Ok(Some(Proposal::new(
            Edit::Tree {
                excluded: off_the_tree(pairs, &hoisted),
                replaced: Vec::new(),
            },
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
        let (Edit::Tree { excluded, .. }, Some(b), Some(a), Some(pairs)) = (
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

impl SiblingTies {
    /// The [`SiblingTiesParams::quiet_siblings`] proposal: of the first `budget` candidates
    /// ([`quiet_siblings`]), the tree with the two bodies on the third that costs least, if
    /// it costs at most `max_cost_per_frame` and every body whose pair test it overrides
    /// moves along its joint within the spread bounds. `own_sse` is the first model's plain
    /// whole-tree fit's squared residual.
    fn quiet_hoist(
        &self,
        ctx: &RepairContext<'_>,
        draft: &Draft,
        tree: &kinetree_structure::Tree,
        budget: usize,
        own_sse: &dyn Fn() -> Result<f64>,
    ) -> Result<Option<Proposal>> {
        let (models, first, poses, pairs) = tree_inputs(self.name(), ctx, draft)?;
        let variance = first.model.noise.sigma_m.powi(2).max(f64::MIN_POSITIVE);
        // Two bodies on one rail or pin whose joints with a third the pair tests missed: both
        // hung on the third by the joint their pairs share, when the fit costs no more.
        let mut best: Option<(Vec<PairDof>, f64, Candidate)> = None;
        let collinear = (
            self.params.collinear_max_angle_deg.to_radians(),
            self.params.collinear_max_offset,
        );
        for (w, u, v, source) in quiet_siblings(pairs, tree).into_iter().take(budget) {
            let Some(replaced) = sibling_joints(pairs, poses, w, u, v, source, collinear) else {
                continue;
            };
            let mut parent = tree.parent.clone();
            parent[u] = Some(w);
            parent[v] = Some(w);
            let excluded = off_the_tree(pairs, &parent);
            let alt_pairs = crate::runner::with_replaced(pairs, &replaced);
            let frames = find_pair(pairs, Some(w), v).map_or(0, |p| p.translation.n_columns);
            if frames == 0 {
                continue;
            }
            let alt = models.assemble(
                &draft.segmentation,
                poses,
                &alt_pairs,
                &excluded,
                &replaced,
                &first.history,
            )?;
            let fits = kinetree_fit::Observer::new(&alt.model)?.fit_sequence(ctx.tracks)?;
            let own = own_sse()?;
            let sse: f64 = fits.iter().map(|f| f.sum_sq_m2).sum();
            let cost = (sse - own) / variance / frames as f64;
            if cost > self.params.max_cost_per_frame || best.as_ref().is_some_and(|b| cost >= b.1) {
                continue;
            }
            // Each body whose pair test the joint overrides must move along it by more
            // than its fitted position's precision (two parts of one rigid body that the
            // clustering split test rigid too, and do not), and by too little for its pair
            // test to see (a rigid verdict over a few frames, or beside a wrong tree
            // elsewhere, hides no quiet joint).
            let overridden: Vec<usize> = [u, v]
                .into_iter()
                .zip(&replaced)
                .filter(|(x, r)| {
                    find_pair(pairs, Some(w), *x).map(|p| p.joint.joint_type())
                        != Some(r.joint.joint_type())
                })
                .map(|(x, _)| x)
                .collect();
            // Nor can hanging such bodies gain more than their motions explain, a squared
            // spread per frame each: a larger gain is a fault of the first tree elsewhere,
            // which this tree need not mend.
            if cost < -(overridden.len() as f64) * self.params.quiet_max_spread_in_std.powi(2) {
                continue;
            }
            let moves = overridden.iter().all(|&x| {
                let spread = alt
                    .model
                    .joints
                    .iter()
                    .position(|j| {
                        (alt.body_order.get(j.parent), alt.body_order.get(j.child))
                            == (Some(&w), Some(&x))
                    })
                    .and_then(|k| spread_in_std(&fits, k));
                spread.is_some_and(|s| {
                    (self.params.quiet_min_spread_in_std..=self.params.quiet_max_spread_in_std)
                        .contains(&s)
                })
            });
            if moves {
                best = Some((replaced, cost, (w, u, v, source)));
            }
        }
        let Some((replaced, cost, (w, u, v, source))) = best else {
            return Ok(None);
        };
        let mut parent = tree.parent.clone();
        parent[u] = Some(w);
        parent[v] = Some(w);
        Ok(Some(Proposal::new(
            Edit::Tree {
                excluded: off_the_tree(pairs, &parent),
                replaced,
            },
            format!(
                "bodies {u} and {v} on {w} by the joint of pair {source:?} cost {cost:.3} \
                 noise variances per frame"
            ),
        )))
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

/// A candidate of [`quiet_siblings`]: `(w, u, v, source)`.
type Candidate = (usize, usize, usize, (usize, usize));

/// The candidates for [`SiblingTiesParams::quiet_siblings`], as `(w, u, v, source)`: bodies
/// `u` and `v` that carry no body but each other in `tree`, are not both on `w` there, and
/// whose pair and pairs with `w` have at most one DoF, hung on `w` by the joint of the pair
/// `source` (bodies in either order). The source is the first of the pairs `u`-`v`, `w`-`u`
/// and `w`-`v` that is a hinge or a slide of whose type each pair with `w` is, unless it is
/// too quiet to contradict it (rigid within its tests' bounds, [`rigid_within_bounds`]: a
/// slide that stood out only against the measured noise level counts too), and which the
/// pair `u`-`v` matches, is rigid with or, for a hinge, passes for as a slide (the two
/// bodies' relative arc is small too). At least one pair with `w` must be of another type
/// than the source, or the exact-tie rule of [`kinetree_structure::spanning_tree`] would have
/// seen the tie. Neither `u` nor `v` is the tree's root or static. In the order of the pairs,
/// then of `w`.
fn quiet_siblings(pairs: &[PairDof], tree: &kinetree_structure::Tree) -> Vec<Candidate> {
    let nb = tree.parent.len();
    let carries_only = |x: usize, y: usize| (0..nb).all(|c| c == y || tree.parent[c] != Some(x));
    let fixed = |x: usize| {
        x == tree.root || find_pair(pairs, None, x).is_some_and(|p| p.joint == JointKind::Rigid)
    };
    // Whether the two bodies' own pair of kind `p` is consistent with a joint of kind `of`.
    let consistent = |p: &JointKind, of: &JointKind| {
        matches!(
            (p, of),
            (JointKind::Rigid, _)
                | (
                    JointKind::Prismatic { .. },
                    JointKind::Prismatic { .. } | JointKind::Revolute { .. }
                )
                | (JointKind::Revolute { .. }, JointKind::Revolute { .. })
        )
    };
    let same_type = |p: &JointKind, of: &JointKind| p.joint_type() == of.joint_type();
    let mut out = Vec::new();
    for q in pairs {
        let (Some(u), v) = (q.a, q.b) else {
            continue;
        };
        if !q.joint.is_single_dof()
            || fixed(u)
            || fixed(v)
            || !carries_only(u, v)
            || !carries_only(v, u)
        {
            continue;
        }
        for w in (0..nb).filter(|&w| w != u && w != v) {
            if tree.parent[u] == Some(w) && tree.parent[v] == Some(w) {
                continue;
            }
            let (Some(pu), Some(pv)) = (find_pair(pairs, Some(w), u), find_pair(pairs, Some(w), v))
            else {
                continue;
            };
            let three = [(q, (u, v)), (pu, (w, u)), (pv, (w, v))];
            let source = three.iter().find(|(s, _)| {
                s.joint.is_single_dof()
                    && three.iter().all(|(p, bodies)| {
                        if *bodies == (u, v) {
                            consistent(&p.joint, &s.joint)
                        } else {
                            rigid_within_bounds(p).is_some() || same_type(&p.joint, &s.joint)
                        }
                    })
                    && !(same_type(&pu.joint, &s.joint) && same_type(&pv.joint, &s.joint))
            });
            if let Some((_, bodies)) = source {
                out.push((w, u, v, *bodies));
            }
        }
    }
    out
}

/// The pairs from `w` to `u` and to `v` with the joint of the pair between the bodies
/// `source`, its axis (and pivot) carried into `w`'s frame by the bodies' mean relative pose
/// (the rank tests stay the pairs' own); `None` when a pair or a common frame is missing, or
/// when a hinge among the three pairs turns about another line than the source's: more than
/// `collinear.0` radians from it, or further from it than `collinear.1` times the distance
/// between `u` and `v`.
fn sibling_joints(
    pairs: &[PairDof],
    poses: &BodyPoses,
    w: usize,
    u: usize,
    v: usize,
    source: (usize, usize),
    collinear: (f64, f64),
) -> Option<Vec<PairDof>> {
    let q = find_pair(pairs, Some(source.0), source.1)?;
    let from = q.a?;
    let (axis, pivot) = match q.joint {
        JointKind::Prismatic { axis } => (axis, None),
        JointKind::Revolute { axis, pivot } => (axis, Some(pivot)),
        _ => return None,
    };
    let (axis, at) = line_in(poses, from, w, axis, pivot.unwrap_or_else(Point3::origin))?;
    // Hinges in series about parallel lines a link apart (a finger's knuckles) are no tie:
    // every hinge among the three pairs must turn about the source's line.
    if pivot.is_some() {
        let scale = find_pair(pairs, Some(u), v)?.distance_m?;
        for (a, b) in [(u, v), (w, u), (w, v)] {
            let p = find_pair(pairs, Some(a), b)?;
            if let JointKind::Revolute {
                axis: other,
                pivot: through,
            } = p.joint
            {
                let (other, through) = line_in(poses, p.a?, w, other, through)?;
                let angle = axis.dot(&other).abs().min(1.0).acos();
                if angle > collinear.0
                    || line_distance(at, axis, through, other) > collinear.1 * scale
                {
                    return None;
                }
            }
        }
    }
    let joint = match pivot {
        Some(_) => JointKind::Revolute { axis, pivot: at },
        None => JointKind::Prismatic { axis },
    };
    [u, v]
        .iter()
        .map(|&x| {
            let mut r = find_pair(pairs, Some(w), x)?.clone();
            (r.a, r.b) = (Some(w), x);
            r.joint = joint.clone();
            r.dof = 1;
            Some(r)
        })
        .collect()
}

/// The least distance between the line through `p` along `a` and the line through `q` along
/// `b` (unit axes).
fn line_distance(p: Point3<f64>, a: Vector3<f64>, q: Point3<f64>, b: Vector3<f64>) -> f64 {
    let d = q - p;
    let n = a.cross(&b);
    if n.norm() > 1e-9 {
        d.dot(&n).abs() / n.norm()
    } else {
        d.cross(&a).norm()
    }
}

/// A line (unit `axis` through `pivot`) fixed in body `from`, in body `to`'s frame: carried by
/// `to_from_from` averaged over the frames both are posed in. A line fixed in both bodies (a
/// rigid pair, or a hinge about that line) comes out the same from every frame; the mean
/// takes the noise out. `None` without a common frame.
fn line_in(
    poses: &BodyPoses,
    from: usize,
    to: usize,
    axis: Vector3<f64>,
    pivot: Point3<f64>,
) -> Option<(Vector3<f64>, Point3<f64>)> {
    if from == to {
        return Some((axis, pivot));
    }
    let (f, t) = (poses.bodies.get(from)?, poses.bodies.get(to)?);
    let (mut sum_axis, mut sum_pivot, mut n) = (Vector3::zeros(), Vector3::zeros(), 0usize);
    for (pf, pt) in f.cam_from_body.iter().zip(&t.cam_from_body) {
        let (Some(pf), Some(pt)) = (pf, pt) else {
            continue;
        };
        let x = pt.inverse() * pf;
        sum_axis += x.rotation * axis;
        sum_pivot += (x * pivot).coords;
        n += 1;
    }
    (n > 0 && sum_axis.norm() > 0.0)
        .then(|| (sum_axis.normalize(), Point3::from(sum_pivot / n as f64)))
}

/// The spread of joint `k`'s positions over the frames of `fits` that determine it: the RMS of
/// their deviations from their precision-weighted mean, each over its standard deviation;
/// `None` under two such frames.
fn spread_in_std(fits: &[kinetree_fit::FrameFit], k: usize) -> Option<f64> {
    let seen: Vec<(f64, f64)> = fits
        .iter()
        .filter_map(|f| {
            let (q, s) = (f.positions.get(k).copied()??, f.std.get(k).copied()??);
            (q.is_finite() && s.is_finite() && s > 0.0).then_some((q, s))
        })
        .collect();
    if seen.len() < 2 {
        return None;
    }
    let weight: f64 = seen.iter().map(|(_, s)| s.powi(-2)).sum();
    let mean = seen.iter().map(|(q, s)| q / (s * s)).sum::<f64>() / weight;
    let chi2: f64 = seen.iter().map(|(q, s)| ((q - mean) / s).powi(2)).sum();
    Some((chi2 / (seen.len() - 1) as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(q: Option<f64>, std: f64) -> kinetree_fit::FrameFit {
        kinetree_fit::FrameFit {
            positions: vec![Some(0.0), q],
            std: vec![Some(1.0), Some(std)],
            rotations: vec![None, None],
            rotation_std: vec![None, None],
            angles: vec![None, None],
            angle_std: vec![None, None],
            poses: Vec::new(),
            n_points: 0,
            sum_sq_m2: 0.0,
        }
    }

    /// The spread is the RMS deviation from the precision-weighted mean in per-frame standard
    /// deviations, over the frames that determine the joint.
    #[test]
    fn the_spread_counts_deviations_in_their_own_precision() {
        // +-2 mm about 1 mm with a 1 mm std: a spread of 2 * sqrt(4 / 3) over four frames.
        let fits: Vec<_> = [3.0, -1.0, 3.0, -1.0]
            .iter()
            .map(|&q| frame(Some(q * 1e-3), 1e-3))
            .chain([frame(None, 1e-3)])
            .collect();
        let s = spread_in_std(&fits, 1).expect("spread");
        assert!((s - 2.0 * (4.0f64 / 3.0).sqrt()).abs() < 1e-9, "{s}");
        // Twice the std halves it; the joint that does not move spreads 0.
        let wide: Vec<_> = [3.0, -1.0, 3.0, -1.0]
            .iter()
            .map(|&q| frame(Some(q * 1e-3), 2e-3))
            .collect();
        assert!((spread_in_std(&wide, 1).expect("spread") - s / 2.0).abs() < 1e-9);
        assert_eq!(spread_in_std(&fits, 0), Some(0.0));
        assert_eq!(spread_in_std(&fits[..1], 1), None);
        assert_eq!(spread_in_std(&fits, 2), None);
    }
}
