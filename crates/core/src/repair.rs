//! Repairs: the steps after the stages that look at a draft of the result and propose an edit.
//!
//! A [`Repair`] is object-safe, `Send + Sync`, and returns [`Result`], like the stage traits in
//! [`crate::stage`]. The runner (`kinetree-pipeline`'s `runner`) owns the loop: it asks each
//! enabled repair of a phase, in order, for a [`Proposal`], applies the edit, redoes what the
//! edit invalidates (poses, pair tests, the model), records the change in the model's
//! [`trace`](crate::Model::trace), and asks the repair whether its edit stands once the
//! redone draft exists ([`Repair::stands`]).

use crate::{
    BodyPoses, Clustering, Dissimilarity, DissimilarityMatrix, DofTester, Model, PairDof,
    PairStats, PoseEstimator, PoseQuality, Result, Segmentation, Tracks, Warning,
};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

/// When the runner asks a repair, and which edits it may return.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RepairPhase {
    /// After each clustering (the draft has a segmentation only): [`Edit::NoiseLevel`], after
    /// which the dissimilarity and the clustering are redone.
    Grouping,
    /// After each pose estimate: [`Edit::Segmentation`] (the poses are redone and the phase
    /// restarts) or [`Edit::Poses`] (the poses are replaced and the next repair asked).
    Bodies,
    /// After the first model of a segmentation is assembled, before its whole-tree fit:
    /// [`Edit::Tree`]. The alternative is finished like the model and replaces it when
    /// [`Repair::stands`] says so.
    Tree,
    /// While each model is finished, after its assembly and first whole-tree fit:
    /// [`Edit::Fit`], which replaces the model's joints (same bodies, poses and tree).
    Fit,
    /// After each finished model, for at most the runner's `model_passes` passes:
    /// [`Edit::Points`]; the bodies and the model are then redone, and the pass is reverted
    /// unless every edit of it stands.
    Points,
    /// After a finished model that no `Points` repair edited: [`Edit::Model`], which replaces
    /// the model.
    Model,
}

/// How often the runner asks a repair within one run of its phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RepairLimit {
    /// Every time the phase comes round.
    Always,
    /// Once per run of the phase, whether it proposes an edit or not (asked again after a
    /// repair named in [`Repair::reopened_by`] edits).
    Once,
    /// Until it has made this many edits in the run of its phase.
    Edits(usize),
}

/// The stages a repair may use, as configured: a repair that clusters, poses or tests does it
/// through these, so swapping a stage swaps it inside the repairs too.
#[derive(Debug, Clone, Copy)]
pub struct StageSlots<'a> {
    /// The dissimilarity measure.
    pub dissimilarity: &'a dyn Dissimilarity,
    /// The clustering of all points into bodies.
    pub clustering: &'a dyn Clustering,
    /// The clusterer that cuts a group of points in two (the `halves` slot): used by the
    /// repairs that split bodies or groups.
    pub halves: &'a dyn Clustering,
    /// The pose estimator.
    pub pose: &'a dyn PoseEstimator,
    /// The DoF tester.
    pub dof: &'a dyn DofTester,
}

/// What a repair may read besides the draft: the data and the configured stages.
#[derive(Debug, Clone, Copy)]
pub struct RepairContext<'a> {
    /// The tracks.
    pub tracks: &'a Tracks,
    /// Pair statistics of the tracks.
    pub stats: &'a PairStats,
    /// The dissimilarity matrix at the current noise level.
    pub dissimilarity: &'a DissimilarityMatrix,
    /// Per-coordinate noise std-dev in metres.
    pub noise_sigma_m: f64,
    /// The noise estimator's first estimate, when the level was estimated by a method whose
    /// estimate may be refined; `None` when it was given.
    pub estimated_noise_sigma_m: Option<f64>,
    /// The configured stages.
    pub stages: StageSlots<'a>,
    /// Makes models as the runner does, for repairs that compare or rebuild models; `None` in
    /// the grouping phase.
    pub models: Option<&'a dyn ModelMaker>,
    /// Seed for any random choice.
    pub seed: u64,
    /// The spanning tree's preferences, for repairs that build trees.
    pub tree: crate::TreeCosts,
    /// Results of pure computations kept for the rest of the discovery (the pair tests, the
    /// hinges' fits); `None` computes everything each time.
    pub memo: Option<&'a crate::memo::Memo>,
}

/// Decisions the repairs have made that later steps must respect. They are typed here, not
/// carried by warnings (warnings only report).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Constraints {
    /// Pairs of points that must not end in one body (one point of each part of a split).
    /// Cleared at the start of each bodies phase.
    pub cannot_link: Vec<(usize, usize)>,
    /// Point sets of bodies a split undid: no attachment may remake one. Cleared at the start
    /// of each bodies phase.
    pub undone_bodies: Vec<Vec<usize>>,
    /// Points taken off a hinged body: not attached again by poses, not taken off twice.
    /// Cleared at the start of each bodies phase.
    pub off_hinge: Vec<usize>,
    /// Points a model's fit found belonging to no body's motion: never attached by poses.
    /// Kept for the whole run.
    pub kept_off: Vec<usize>,
    /// Point sets of every body a split undid in the run: points of the bodies born of them
    /// may leave for a body whose fitted motion explains them. Kept for the whole run.
    pub split_origins: Vec<Vec<usize>>,
}

impl Constraints {
    /// Appends `other`'s decisions.
    pub fn extend(&mut self, other: &Self) {
        self.cannot_link.extend_from_slice(&other.cannot_link);
        self.undone_bodies
            .extend(other.undone_bodies.iter().cloned());
        self.off_hinge.extend_from_slice(&other.off_hinge);
        self.kept_off.extend_from_slice(&other.kept_off);
        self.split_origins
            .extend(other.split_origins.iter().cloned());
    }

    /// Forgets the decisions that hold for one bodies phase only.
    pub fn start_bodies_phase(&mut self) {
        self.cannot_link.clear();
        self.undone_bodies.clear();
        self.off_hinge.clear();
    }
}

/// Every body's pose in every frame from a model's whole-tree fit, with its precision; in the
/// model's body numbering.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FittedPoses {
    /// `[body][frame]`, `None` where the fit leaves the body's pose undetermined.
    pub body_poses: Vec<Vec<Option<Isometry3<f64>>>>,
    /// `[body][frame]`, the precision of each fitted pose.
    pub body_qualities: Vec<Vec<Option<PoseQuality>>>,
}

/// Makes models from bodies, poses and pair tests, as the runner does.
pub trait ModelMaker: Send + Sync + std::fmt::Debug {
    /// The model of `segmentation`'s bodies with `poses` and `pairs` (in its numbering), its
    /// spanning tree chosen without the edges `excluded` (`(parent, child)`), `history` as its
    /// first warnings; not yet fitted (no positions' precision, no re-prediction). Each edge's
    /// joint is the DoF stage's test of the child against the parent, or the pair in
    /// `replaced` from that parent to that child. Its bodies come in tree order;
    /// `body_order` maps them to `segmentation`'s.
    ///
    /// # Errors
    /// [`crate::Error::Degenerate`] when there is no body; a stage's error.
    fn assemble(
        &self,
        segmentation: &Segmentation,
        poses: &BodyPoses,
        pairs: &[PairDof],
        excluded: &[(usize, usize)],
        replaced: &[PairDof],
        history: &[Warning],
    ) -> Result<ModelDraft>;
    /// The finished model: assembled, the tree repairs applied, fitted whole to every frame;
    /// `body_order` maps its bodies to `segmentation`'s.
    ///
    /// # Errors
    /// As [`ModelMaker::assemble`], and the whole-tree fit's.
    fn make(
        &self,
        segmentation: &Segmentation,
        poses: &BodyPoses,
        pairs: &[PairDof],
        history: &[Warning],
    ) -> Result<ModelDraft> {
        self.make_without(segmentation, poses, pairs, &[], history)
    }
    /// [`ModelMaker::make`] with the tree's edges between the body pairs in `excluded`
    /// (`(parent, child)` in `segmentation`'s numbering, either order) left out, the tree
    /// repairs' alternatives included.
    ///
    /// # Errors
    /// As [`ModelMaker::make`].
    fn make_without(
        &self,
        segmentation: &Segmentation,
        poses: &BodyPoses,
        pairs: &[PairDof],
        excluded: &[(usize, usize)],
        history: &[Warning],
    ) -> Result<ModelDraft>;
}

/// A model with what it was made from.
#[derive(Clone)]
pub struct ModelDraft {
    /// The model (bodies in tree order).
    pub model: Model,
    /// `model body id -> body id` in the segmentation the model was made from; the identity
    /// once a draft has adopted the model ([`Draft::adopt`]).
    pub body_order: Vec<usize>,
    /// The model's whole-tree fit, when the runner has made it (the `Points` and `Model`
    /// phases have it).
    pub fitted: Option<FittedPoses>,
    /// The warnings of the steps before the model (its own come on top in `model.warnings`).
    pub history: Vec<Warning>,
    /// An opaque cache of the model's whole-tree fit, shared by the fit repairs (the
    /// pipeline's store a `kinetree_fit::FitState`); check that it belongs to the model
    /// before use, and drop it when the model changes.
    pub cache: Option<std::sync::Arc<dyn std::any::Any + Send + Sync>>,
}

impl std::fmt::Debug for ModelDraft {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ModelDraft")
            .field("model", &self.model)
            .field("body_order", &self.body_order)
            .field("fitted", &self.fitted.is_some())
            .field("history", &self.history)
            .field("cache", &self.cache.is_some())
            .finish()
    }
}

/// The current state of a run, as a repair sees it.
///
/// One body numbering holds throughout a draft: the segmentation's, which is the model's once
/// the draft has one ([`Draft::adopt`] renumbers the segmentation, poses, pair tests and
/// pending edits into the model's tree order). Body `k` of `segmentation`, of `poses`, of
/// `pairs` and of `model` is one body.
#[derive(Debug, Clone)]
pub struct Draft {
    /// Which point belongs to which body.
    pub segmentation: Segmentation,
    /// Poses per body of the segmentation; absent in the grouping phase.
    pub poses: Option<BodyPoses>,
    /// Every pair's DoF test on `poses`, when made.
    pub pairs: Option<Vec<PairDof>>,
    /// The model, in the tree, points and model phases.
    pub model: Option<ModelDraft>,
    /// Decisions made so far.
    pub constraints: Constraints,
    /// The point edits proposed so far in this pass of the points phase, in order:
    /// `(point, new body)` (`None`: on no body).
    pub pending: Vec<(usize, Option<usize>)>,
}

impl Draft {
    /// A draft with a segmentation only.
    pub fn new(segmentation: Segmentation) -> Self {
        Self {
            segmentation,
            poses: None,
            pairs: None,
            model: None,
            constraints: Constraints::default(),
            pending: Vec::new(),
        }
    }

    /// Takes `model`, made from this draft's segmentation, poses and pair tests, and
    /// renumbers those (and the pending point edits) into the model's body numbering; the
    /// model's `body_order` becomes the identity.
    ///
    /// # Errors
    /// [`crate::Error::Shape`] when `model.body_order` is not a permutation of the
    /// segmentation's bodies, or the poses or pair tests name other bodies.
    pub fn adopt(&mut self, mut model: ModelDraft) -> Result<()> {
        let n = self.segmentation.n_bodies();
        let order = &model.body_order;
        let shape = |what: &str| crate::Error::Shape {
            expected: format!("a model made from this draft's {n} bodies"),
            found: format!("{what} (body_order {order:?})"),
        };
        let new_id = crate::segmentation::inverse_permutation(order, n)
            .ok_or_else(|| shape("its body_order is no permutation of the bodies"))?;
        if self.poses.as_ref().is_some_and(|p| p.bodies.len() != n) {
            return Err(shape("the poses have another number of bodies"));
        }
        let known = |b: usize| b < n;
        if let Some(pairs) = &self.pairs
            && pairs
                .iter()
                .any(|p| !known(p.b) || p.a.is_some_and(|a| !known(a)))
        {
            return Err(shape("a pair test names a body beyond the segmentation's"));
        }
        if self
            .pending
            .iter()
            .any(|&(_, b)| b.is_some_and(|b| !known(b)))
        {
            return Err(shape(
                "a pending point edit names a body beyond the segmentation's",
            ));
        }
        if order.iter().enumerate().any(|(k, &b)| k != b) {
            self.segmentation = self.segmentation.relabeled(&new_id);
            if let Some(poses) = &mut self.poses {
                let mut old: Vec<Option<crate::BodyTrack>> = std::mem::take(&mut poses.bodies)
                    .into_iter()
                    .map(Some)
                    .collect();
                poses.bodies = order.iter().filter_map(|&b| old[b].take()).collect();
            }
            for p in self.pairs.iter_mut().flatten() {
                p.a = p.a.map(|a| new_id[a]);
                p.b = new_id[p.b];
            }
            for (_, b) in &mut self.pending {
                *b = b.map(|b| new_id[b]);
            }
            model.body_order = (0..n).collect();
        }
        self.model = Some(model);
        Ok(())
    }
}

/// The change a repair proposes.
#[derive(Debug, Clone)]
pub enum Edit {
    /// A new per-coordinate noise level.
    NoiseLevel {
        /// The level, metres.
        sigma_m: f64,
        /// Whether the dissimilarity and the clustering are redone at it (else the grouping
        /// phase ends with it).
        redo_clustering: bool,
    },
    /// A new segmentation.
    Segmentation(Segmentation),
    /// New poses for the same segmentation.
    Poses(BodyPoses),
    /// The tree without the edges `excluded` (`(parent, child)`, either order), assembled
    /// from the draft's pair tests with those between the same bodies as a pair in
    /// `replaced` replaced by it.
    Tree {
        /// Body pairs the tree may not join.
        excluded: Vec<(usize, usize)>,
        /// Pair tests to assemble from in place of the draft's, in the draft's numbering (a
        /// joint the test could not see, typed from the bodies around it); the model records
        /// each that becomes one of its joints with a `joint_typed_by_sibling` warning.
        replaced: Vec<PairDof>,
    },
    /// Points moved: `(point, new body)` (`None`: on no body).
    Points(Vec<(usize, Option<usize>)>),
    /// The model with its joints refitted (same bodies, poses and tree).
    Fit(Box<ModelDraft>),
    /// A replacement model, with the poses and segmentation it was made from.
    Model {
        /// The model.
        model: Box<ModelDraft>,
        /// Its poses, in the draft's numbering (the runner adopts the model with them).
        poses: BodyPoses,
    },
}

impl Edit {
    /// The edit's kind, as named in the trace.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::NoiseLevel { .. } => "noise_level",
            Self::Segmentation(_) => "segmentation",
            Self::Poses(_) => "poses",
            Self::Tree { .. } => "tree",
            Self::Fit(_) => "fit",
            Self::Points(_) => "points",
            Self::Model { .. } => "model",
        }
    }
}

/// What a repair returns when it has something to change.
#[derive(Debug, Clone)]
pub struct Proposal {
    /// The edit.
    pub edit: Edit,
    /// Decisions that come with it.
    pub constraints: Constraints,
    /// Warnings that report it (report-only). With an [`Edit::Poses`] they describe those
    /// poses and are dropped when the poses are redone.
    pub warnings: Vec<Warning>,
    /// One line on what the edit does, for the trace.
    pub summary: String,
    /// The points it concerns, for the trace (ascending).
    pub points: Vec<usize>,
}

impl Proposal {
    /// A proposal with no constraints, warnings or points.
    pub fn new(edit: Edit, summary: impl Into<String>) -> Self {
        Self {
            edit,
            constraints: Constraints::default(),
            warnings: Vec::new(),
            summary: summary.into(),
            points: Vec::new(),
        }
    }
}

/// One change in a run, for the model's trace.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TraceEntry {
    /// The repair that made it.
    pub repair: String,
    /// Its phase.
    pub phase: RepairPhase,
    /// The runner's model pass (0 for the first model and everything before it).
    pub pass: usize,
    /// `applied`, `kept` (a tree or model edit that stood), `discarded` (one that did not)
    /// or `reverted` (a points pass undone because this repair's edit did not stand).
    pub outcome: String,
    /// The edit's kind ([`Edit::kind`]).
    pub edit: String,
    /// What it did.
    pub summary: String,
    /// The points it concerned.
    #[serde(default)]
    pub points: Vec<usize>,
}

/// A step after the stages that proposes an edit to the draft, or nothing.
///
/// ```
/// use kinetree_core::{Draft, Proposal, Repair, RepairContext, RepairPhase, Result};
///
/// /// Proposes nothing; asked after every pose estimate.
/// #[derive(Debug)]
/// struct Idle;
///
/// impl Repair for Idle {
///     fn name(&self) -> &str {
///         "idle"
///     }
///     fn phase(&self) -> RepairPhase {
///         RepairPhase::Bodies
///     }
///     fn propose(&self, _: &RepairContext<'_>, _: &Draft) -> Result<Option<Proposal>> {
///         Ok(None)
///     }
/// }
/// let boxed: Box<dyn Repair> = Box::new(Idle);
/// assert_eq!(boxed.name(), "idle");
/// ```
pub trait Repair: Send + Sync + std::fmt::Debug {
    /// Short name used in configs and the trace.
    fn name(&self) -> &str;
    /// When the runner asks it.
    fn phase(&self) -> RepairPhase;
    /// How often the runner asks it within one run of its phase.
    fn limit(&self) -> RepairLimit {
        RepairLimit::Always
    }
    /// Repairs whose edits make a [`RepairLimit::Once`] repair be asked again.
    fn reopened_by(&self) -> &[&str] {
        &[]
    }
    /// Whether the runner tests every pair on the current poses (the draft's `pairs`) before
    /// asking it.
    fn needs_pair_tests(&self) -> bool {
        false
    }
    /// Whether a `Points` repair is asked again when a `Model` repair replaced the model in
    /// the same pass.
    fn asked_on_replaced_model(&self) -> bool {
        false
    }
    /// The edit this repair proposes for `draft`, or `None`.
    ///
    /// # Errors
    /// A stage's error; never for a draft that merely gives it nothing to do.
    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>>;
    /// Whether `edit`, which this repair proposed on `before`, stands on `after`, the draft
    /// the runner redid with it. The default keeps every edit.
    ///
    /// # Errors
    /// A stage's error.
    fn stands(
        &self,
        ctx: &RepairContext<'_>,
        edit: &Edit,
        before: &Draft,
        after: &Draft,
    ) -> Result<bool> {
        let _ = (ctx, edit, before, after);
        Ok(true)
    }
}
