//! The runner: owns the loop over the repairs (their order, limits, restarts and reverts),
//! redoes what each edit invalidates, and records every change in a trace.
//!
//! Phases, in order (see [`RepairPhase`]): grouping (after each clustering), bodies (after
//! each pose estimate), then models made over passes: each model's tree repairs, the fit
//! repairs on every model finished (the first and any alternative), then its points repairs
//! (at most `model_passes` passes, each redoing the bodies and the model, and reverted unless
//! its edits stand), then its model repairs when no point moved.

use crate::Pipeline;
use kinetree_core::memo::{Fingerprint, Memo, MemoUsage};
use kinetree_core::model::NoiseSource;
use kinetree_core::{
    BodyPoses, BodyTrack, ClusteringInput, DissimilarityInput, DissimilarityMatrix, DofInput,
    DofTester, Draft, Edit, Error, ModelDraft, ModelMaker, PairDof, PairStats, PoseInput, Proposal,
    Repair, RepairContext, RepairLimit, RepairPhase, Result, Segmentation, StageSlots, TraceEntry,
    Tracks, Warning,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Mutex;

/// The runner's own limits (`[pipeline.runner]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunnerParams {
    /// Whether each clustering is followed by the point-by-point check on observed pairs
    /// ([`kinetree_clustering::reassign_points`]; default on).
    pub point_check: bool,
    /// Passes in which the points repairs may move points and the bodies and model are redone
    /// (default 2).
    pub model_passes: usize,
    /// Observed pairs a point needs with a body to be judged against it by the point-by-point
    /// check (default 2).
    pub reassign_min_pairs: usize,
    /// Whether a points edit that does not stand on the next pass's model is undone alone, the
    /// model made again with the pass's other edits (default true); otherwise the whole pass
    /// is undone (`docs/decisions.md`, `runner.redo_passes`).
    pub redo_passes: bool,
    /// Mebibytes of pair tests and hinge fits the discovery keeps, each under a fingerprint
    /// of its inputs, to look up when a later pass asks for it again (default 256; 0 keeps
    /// none). The output is the same at any value; `docs/decisions.md`, `runner.memo_mib`.
    pub memo_mib: usize,
}

impl Default for RunnerParams {
    fn default() -> Self {
        Self {
            point_check: true,
            model_passes: 2,
            reassign_min_pairs: 2,
            redo_passes: true,
            memo_mib: 256,
        }
    }
}

impl RunnerParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming `pipeline.runner.<parameter>`.
    pub fn validate(&self) -> Result<()> {
        use crate::repairs::count_within;
        count_within("pipeline.runner.model_passes", self.model_passes, 0, 100)?;
        count_within(
            "pipeline.runner.reassign_min_pairs",
            self.reassign_min_pairs,
            0,
            1_000_000,
        )?;
        count_within("pipeline.runner.memo_mib", self.memo_mib, 0, 1 << 20)
    }
}

/// The error for a repair that proposes an edit its phase does not take.
fn wrong_edit(repair: &dyn Repair, edit: &Edit) -> Error {
    Error::Config(format!(
        "repair `{}` proposed a `{}` edit in the {:?} phase, which does not take it",
        repair.name(),
        edit.kind(),
        repair.phase()
    ))
}

/// How poorly a body is posed, and how far it travels: the median over its registered frames
/// of its rotation's standard deviation per unit noise (infinite when never registered), and
/// the path length of its origin over its registered frames. Both depend on the body's
/// keypoints, their visibility and motion, not on how the bodies or points are numbered, where
/// the camera is, or which way time runs.
pub(crate) fn pose_spread(track: &BodyTrack) -> (f64, f64) {
    let Some(spread) = track.median_quality(|q| q.rot_std_per_sigma) else {
        return (f64::INFINITY, 0.0);
    };
    let origins: Vec<_> = track
        .cam_from_body
        .iter()
        .flatten()
        .map(|p| p.translation.vector)
        .collect();
    let travel = origins.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    (spread, travel)
}

/// The pair of bodies `i`, `j` as `(frame, moving)`: `j` is the frame when it is better
/// posed, or equally well posed (within rounding) and travels less; else `i`. Exact ties keep
/// `i` (identical bodies moving identically).
pub(crate) fn frame_and_moving(spread: &[(f64, f64)], i: usize, j: usize) -> (usize, usize) {
    let differs = |a: f64, b: f64| (a - b).abs() > 1e-9 * a.abs().max(b.abs());
    let ((si, ti), (sj, tj)) = (spread[i], spread[j]);
    let j_first = if differs(si, sj) {
        sj < si
    } else if differs(ti, tj) {
        tj < ti
    } else {
        false
    };
    if j_first { (j, i) } else { (i, j) }
}

/// Every pair's DoF test: each body against the camera frame, and each pair of bodies with the
/// better-posed one as the frame (`frame_and_moving`). The test of `b` in `a`'s frame is not
/// that of `a` in `b`'s (the frame's rotation noise acts at the lever arm of the other's
/// origin), so the direction must not follow the body numbering, which follows the order of
/// the points. Pairs never registered together are left out.
///
/// # Errors
/// The DoF stage's errors other than [`Error::Degenerate`].
pub fn all_pairs(
    dof: &dyn DofTester,
    poses: &BodyPoses,
    sigma: f64,
    memo: Option<&Memo>,
) -> Result<Vec<PairDof>> {
    let input = DofInput {
        poses,
        noise_sigma_m: sigma,
    };
    let n = poses.bodies.len();
    let spread: Vec<(f64, f64)> = poses.bodies.iter().map(pose_spread).collect();
    let mut pairs: Vec<(Option<usize>, usize)> = (0..n).map(|b| (None, b)).collect();
    for i in 0..n {
        for j in i + 1..n {
            let (frame, moving) = frame_and_moving(&spread, i, j);
            pairs.push((Some(frame), moving));
        }
    }
    // The tests are independent: run in parallel, kept in this order.
    let tested: Vec<Result<Option<PairDof>>> = pairs
        .par_iter()
        .map(|&(a, b)| match test_pair(dof, &input, a, b, memo) {
            Ok(p) => Ok(Some(p)),
            Err(Error::Degenerate(_)) => Ok(None),
            Err(e) => Err(e),
        })
        .collect();
    let mut out = Vec::new();
    for t in tested {
        out.extend(t?);
    }
    Ok(out)
}

/// `dof`'s test of body `b` in frame `a`, looked up in `memo` when the same tester has tested
/// the same two tracks at the same noise level before (a test depends on nothing else,
/// [`DofTester::test_pair`]). Degenerate pairs are kept too; other errors are not.
///
/// # Errors
/// The DoF stage's.
pub(crate) fn test_pair(
    dof: &dyn DofTester,
    input: &DofInput<'_>,
    a: Option<usize>,
    b: usize,
    memo: Option<&Memo>,
) -> Result<PairDof> {
    let bodies = &input.poses.bodies;
    let (Some(memo), Some(track)) = (memo, bodies.get(b)) else {
        return dof.test_pair(input, a, b);
    };
    let mut key = Fingerprint::new("pair test");
    // The tester's address tells apart two testers of one name with other parameters.
    key.usize(std::ptr::from_ref(dof).cast::<()>() as usize)
        .option_usize(a)
        .usize(b)
        .usize(input.poses.n_frames)
        .f64(input.noise_sigma_m)
        .track(track);
    if let Some(frame) = a.and_then(|a| bodies.get(a)) {
        key.track(frame);
    }
    let key = key.finish();
    let kept = memo.get_or_compute(
        key,
        || match dof.test_pair(input, a, b) {
            Err(Error::Degenerate(why)) => Some(Err(why)),
            Ok(p) => Some(Ok(p)),
            Err(_) => None,
        },
        |_| std::mem::size_of::<PairDof>(),
    );
    match kept {
        Some(Ok(p)) => Ok(p),
        Some(Err(why)) => Err(Error::Degenerate(why)),
        None => dof.test_pair(input, a, b),
    }
}

/// The configured stages as repair slots.
fn slots(p: &Pipeline) -> StageSlots<'_> {
    StageSlots {
        dissimilarity: p.dissimilarity.as_ref(),
        clustering: p.clustering.as_ref(),
        halves: p.halves.as_ref(),
        pose: p.pose.as_ref(),
        dof: p.dof.as_ref(),
    }
}

/// The dissimilarity at `sigma` and the clustering, with the point-by-point check.
pub(crate) fn segment(
    p: &Pipeline,
    tracks: &Tracks,
    stats: &PairStats,
    sigma: f64,
) -> Result<(DissimilarityMatrix, Segmentation)> {
    let d = p.dissimilarity.compute(&DissimilarityInput {
        tracks,
        stats,
        noise_sigma_m: sigma,
    })?;
    let s = p.clustering.cluster(&ClusteringInput {
        dissimilarity: &d,
        seed: p.seed,
        pair_frames: Some(&stats.count),
    })?;
    if !p.runner.point_check {
        return Ok((d, s));
    }
    let s =
        kinetree_clustering::reassign_points(&d, &s, d.suggested_cut, p.runner.reassign_min_pairs);
    Ok((d, s))
}

/// A trace entry for `proposal` of `repair`.
fn entry(repair: &dyn Repair, pass: usize, outcome: &str, proposal: &Proposal) -> TraceEntry {
    TraceEntry {
        repair: repair.name().to_owned(),
        phase: repair.phase(),
        pass,
        outcome: outcome.to_owned(),
        edit: proposal.edit.kind().to_owned(),
        summary: proposal.summary.clone(),
        points: proposal.points.clone(),
    }
}

/// Whether a repair may be asked again, given how often it was asked and how many edits it
/// made in this run of its phase.
fn may_ask(repair: &dyn Repair, asked: usize, edits: usize) -> bool {
    match repair.limit() {
        RepairLimit::Always => true,
        RepairLimit::Once => asked == 0,
        RepairLimit::Edits(n) => edits < n,
    }
}

/// Runs `call` (a `propose` or `stands` of `repair`) and tells `observer` its time.
fn timed<T>(observer: &dyn DiscoveryObserver, repair: &dyn Repair, call: impl FnOnce() -> T) -> T {
    let start = std::time::Instant::now();
    let out = call();
    observer.repair_time(repair.name(), start.elapsed().as_secs_f64());
    out
}

/// The grouping phase: the clustering at `sigma`, then the grouping repairs, which may change
/// the noise level (the clustering is then redone). Returns the final level, matrix,
/// segmentation and trace; `observer` is told each repair's time.
pub(crate) fn grouping(
    p: &Pipeline,
    tracks: &Tracks,
    stats: &PairStats,
    mut sigma: f64,
    first_guess: Option<f64>,
    observer: &dyn DiscoveryObserver,
) -> Result<(f64, DissimilarityMatrix, Segmentation, Vec<TraceEntry>)> {
    let (mut dmat, mut seg) = segment(p, tracks, stats, sigma)?;
    let mut trace = Vec::new();
    let phase: Vec<&dyn Repair> = p
        .repairs
        .iter()
        .map(AsRef::as_ref)
        .filter(|r| r.phase() == RepairPhase::Grouping)
        .collect();
    let (mut asked, mut edits) = (vec![0usize; phase.len()], vec![0usize; phase.len()]);
    'phase: loop {
        for (k, &r) in phase.iter().enumerate() {
            if !may_ask(r, asked[k], edits[k]) {
                continue;
            }
            asked[k] += 1;
            let ctx = RepairContext {
                tracks,
                stats,
                dissimilarity: &dmat,
                noise_sigma_m: sigma,
                estimated_noise_sigma_m: first_guess,
                stages: slots(p),
                models: None,
                seed: p.seed,
                tree: p.tree,
                memo: None,
            };
            let Some(proposal) = timed(observer, r, || r.propose(&ctx, &Draft::new(seg.clone())))?
            else {
                continue;
            };
            edits[k] += 1;
            trace.push(entry(r, 0, "applied", &proposal));
            let Edit::NoiseLevel {
                sigma_m,
                redo_clustering,
            } = proposal.edit
            else {
                return Err(wrong_edit(r, &proposal.edit));
            };
            if !(sigma_m.is_finite() && sigma_m > 0.0) {
                return Err(Error::Numerical(format!(
                    "repair `{}` proposed the noise level {sigma_m}",
                    r.name()
                )));
            }
            sigma = sigma_m;
            if !redo_clustering {
                break 'phase;
            }
            (dmat, seg) = segment(p, tracks, stats, sigma)?;
            continue 'phase;
        }
        break;
    }
    Ok((sigma, dmat, seg, trace))
}

/// For each body of `seg`, the body of `other` (the same partition in another numbering)
/// that holds its points.
///
/// # Errors
/// [`Error::Shape`] when the two are not one partition.
fn bodies_in(seg: &Segmentation, other: &Segmentation) -> Result<Vec<usize>> {
    // Each body's first point of its own (a shared point's first body is another).
    let order: Vec<usize> = (0..seg.n_bodies())
        .filter_map(|b| {
            let p = seg.labels().iter().position(|l| *l == Some(b))?;
            other.body_of(p)
        })
        .collect();
    let same = order.len() == seg.n_bodies()
        && seg.n_points() == other.n_points()
        && seg
            .labels()
            .iter()
            .zip(other.labels())
            .all(|(a, b)| a.map(|a| order[a]) == *b);
    if !same {
        return Err(Error::Shape {
            expected: "one partition of the points in two body numberings".into(),
            found: format!(
                "{} and {} bodies that hold other points",
                seg.n_bodies(),
                other.n_bodies()
            ),
        });
    }
    Ok(order)
}

/// The edits of one points pass, with the repairs that proposed them.
type PassEdits<'r> = Vec<(&'r dyn Repair, Proposal)>;

/// A pass's edits with the draft they were made on (its constraints those from before them) and
/// the history from before them, so that the next draft can be made again without one of them.
struct Applied<'r> {
    before: Draft,
    edits: PassEdits<'r>,
    history: Vec<Warning>,
}

/// The draft `edits` make of `before`: their point moves in order on its segmentation, its
/// constraints with theirs.
fn edited(before: &Draft, edits: &PassEdits<'_>) -> Draft {
    let mut labels = before.segmentation.labels().to_vec();
    let mut all = before.constraints.clone();
    for (_, p) in edits {
        if let Edit::Points(moves) = &p.edit {
            for &(point, body) in moves {
                if let Some(l) = labels.get_mut(point) {
                    *l = body;
                }
            }
        }
        all.extend(&p.constraints);
    }
    let mut seg = Segmentation::from_raw(&labels, 1).with_shared_of(&before.segmentation, &labels);
    seg.discarded_groups = before.segmentation.discarded_groups.clone();
    let mut next = Draft::new(seg);
    next.constraints = all;
    next
}

/// What the runner calls with every trace entry as it is made: progress, for a caller who
/// wants to show it (the runner itself never prints).
pub type Progress<'a> = &'a (dyn Fn(&TraceEntry) + Sync);

/// What a discovery tells its caller as it goes ([`crate::Pipeline::run_observed`]; nothing
/// in the pipeline prints): each stage as it starts, and every trace entry as it is made.
pub trait DiscoveryObserver: Sync {
    /// A stage starts: `pair statistics`, `noise level`, `clustering`, then per model pass
    /// `bodies`, `tree`, `whole-tree fit`, `points` and `model checks`; in a sampled
    /// discovery ([`crate::sampling`]) all of them once per discovery, each followed by
    /// `assigning the other points`.
    fn stage(&self, _name: &str) {}
    /// A repair made a change (the entry the model's `trace` will hold).
    fn trace(&self, _entry: &TraceEntry) {}
    /// A repair's `propose` or `stands` returned after `seconds` of wall-clock time: the
    /// time includes the models it had built and the repairs those ran.
    fn repair_time(&self, _repair: &str, _seconds: f64) {}
    /// The model phases are over: what their memo of pair tests and hinge fits kept and how
    /// often it answered (once per discovery, so twice in a sampled one).
    fn memo(&self, _usage: MemoUsage) {}
}

/// The observer that is told nothing.
impl DiscoveryObserver for () {}

/// Wall-clock time of one stage ([`StageTimes::totals`]).
#[derive(Debug, Clone, PartialEq)]
pub struct StageTime {
    /// The stage's name as [`DiscoveryObserver::stage`] gave it (`bodies`, `tree (pass 2)`).
    pub stage: String,
    /// Seconds from each start of the stage to the next stage's start (or to the call of
    /// [`StageTimes::totals`]), summed over its starts.
    pub seconds: f64,
    /// How many times the stage started.
    pub starts: usize,
}

/// Wall-clock time of one repair's calls ([`StageTimes::repair_totals`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RepairTime {
    /// The repair's name ([`Repair::name`]).
    pub repair: String,
    /// Seconds in its `propose` and `stands` calls, summed; a call's time includes the
    /// models it had built and the repairs those ran, so the repairs' times can add up to
    /// more than the discovery's.
    pub seconds: f64,
    /// How many calls.
    pub calls: usize,
}

/// An observer that times each stage and each repair and passes every call on to another
/// observer: where the time of a discovery goes, on the caller's own data (`kinetree
/// discover --timings`).
pub struct StageTimes<'a> {
    inner: &'a dyn DiscoveryObserver,
    started: std::time::Instant,
    starts: std::sync::Mutex<Vec<(String, std::time::Instant)>>,
    repairs: std::sync::Mutex<Vec<RepairTime>>,
    memo: std::sync::Mutex<MemoUsage>,
}

impl<'a> StageTimes<'a> {
    /// Times the stages from now on, telling `inner` everything as well.
    pub fn new(inner: &'a dyn DiscoveryObserver) -> Self {
        Self {
            inner,
            started: std::time::Instant::now(),
            starts: std::sync::Mutex::new(Vec::new()),
            repairs: std::sync::Mutex::new(Vec::new()),
            memo: std::sync::Mutex::new(MemoUsage::default()),
        }
    }

    /// The memo's usage, summed over the discoveries so far.
    pub fn memo_usage(&self) -> MemoUsage {
        self.memo.lock().map(|m| *m).unwrap_or_default()
    }

    /// Each repair's time so far, the longest first (then by name).
    pub fn repair_totals(&self) -> Vec<RepairTime> {
        let mut out = self.repairs.lock().map(|r| r.clone()).unwrap_or_default();
        out.sort_by(|a, b| {
            b.seconds
                .total_cmp(&a.seconds)
                .then_with(|| a.repair.cmp(&b.repair))
        });
        out
    }

    /// Each stage's time so far, in the order the stages first started; the time before the
    /// first stage is `setup` (checking and cleaning the tracks, choosing a sample).
    pub fn totals(&self) -> Vec<StageTime> {
        let now = std::time::Instant::now();
        let starts = self.starts.lock().map(|s| s.clone()).unwrap_or_default();
        let first = starts.first().map_or(now, |(_, t)| *t);
        let mut out = vec![StageTime {
            stage: "setup".into(),
            seconds: first.duration_since(self.started).as_secs_f64(),
            starts: 1,
        }];
        for (k, (name, at)) in starts.iter().enumerate() {
            let end = starts.get(k + 1).map_or(now, |(_, t)| *t);
            let seconds = end.duration_since(*at).as_secs_f64();
            tally(
                &mut out,
                |s| s.stage == *name,
                |s| (s.seconds, s.starts) = (s.seconds + seconds, s.starts + 1),
                || StageTime {
                    stage: name.clone(),
                    seconds,
                    starts: 1,
                },
            );
        }
        out
    }
}

/// Updates the first row of `rows` that `matches` with `add`, or appends `new()` when none
/// does: a stage's or a repair's running total.
fn tally<T>(
    rows: &mut Vec<T>,
    matches: impl Fn(&T) -> bool,
    add: impl FnOnce(&mut T),
    new: impl FnOnce() -> T,
) {
    match rows.iter_mut().find(|r| matches(r)) {
        Some(r) => add(r),
        None => rows.push(new()),
    }
}

impl std::fmt::Debug for StageTimes<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StageTimes")
            .field("totals", &self.totals())
            .finish_non_exhaustive()
    }
}

impl DiscoveryObserver for StageTimes<'_> {
    fn stage(&self, name: &str) {
        if let Ok(mut s) = self.starts.lock() {
            s.push((name.to_string(), std::time::Instant::now()));
        }
        self.inner.stage(name);
    }

    fn trace(&self, entry: &TraceEntry) {
        self.inner.trace(entry);
    }

    fn repair_time(&self, repair: &str, seconds: f64) {
        if let Ok(mut r) = self.repairs.lock() {
            tally(
                &mut r,
                |t| t.repair == repair,
                |t| (t.seconds, t.calls) = (t.seconds + seconds, t.calls + 1),
                || RepairTime {
                    repair: repair.to_string(),
                    seconds,
                    calls: 1,
                },
            );
        }
        self.inner.repair_time(repair, seconds);
    }

    fn memo(&self, usage: MemoUsage) {
        if let Ok(mut m) = self.memo.lock() {
            *m = m.plus(usage);
        }
        self.inner.memo(usage);
    }
}

/// A [`Progress`] callback as an observer of the trace alone.
pub(crate) struct TraceOnly<'a>(pub(crate) Progress<'a>);

impl DiscoveryObserver for TraceOnly<'_> {
    fn trace(&self, entry: &TraceEntry) {
        (self.0)(entry);
    }
}

/// Writes what the whole-tree fit `state` of `model` on `tracks` gives into the model: the
/// joints' precision, their positions and the re-prediction, and the identifiability
/// warnings in place of the model's.
///
/// # Errors
/// As [`kinetree_fit::write_joint_precision`] and [`kinetree_fit::write_positions`].
pub(crate) fn write_fit(
    pipeline: &Pipeline,
    model: &mut kinetree_core::Model,
    state: &kinetree_fit::FitState,
    tracks: &Tracks,
) -> Result<()> {
    kinetree_fit::write_joint_precision(model, state, tracks)?;
    model.reprediction_rms_in_sigma = kinetree_fit::write_positions(model, state)?;
    model
        .warnings
        .retain(|w| !matches!(w, Warning::JointNotIdentifiable { .. }));
    let verdicts = kinetree_fit::identifiability_warnings(
        model,
        tracks,
        &model.position_limits,
        pipeline.dof.model_error_rad(),
    );
    model.warnings.extend(verdicts);
    Ok(())
}

/// One discovery's state shared by the phases after the grouping.
pub(crate) struct Runner<'a> {
    pipeline: &'a Pipeline,
    tracks: &'a Tracks,
    stats: &'a PairStats,
    dmat: &'a DissimilarityMatrix,
    sigma: f64,
    source: NoiseSource,
    first_guess: Option<f64>,
    /// The trace so far and the current pass.
    trace: Mutex<(Vec<TraceEntry>, usize)>,
    observer: &'a dyn DiscoveryObserver,
    memo: Memo,
}

impl std::fmt::Debug for Runner<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Runner")
            .field("sigma", &self.sigma)
            .field("source", &self.source)
            .field("trace", &self.trace)
            .finish_non_exhaustive()
    }
}

impl<'a> Runner<'a> {
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        pipeline: &'a Pipeline,
        tracks: &'a Tracks,
        stats: &'a PairStats,
        dmat: &'a DissimilarityMatrix,
        sigma: f64,
        source: NoiseSource,
        first_guess: Option<f64>,
        trace: Vec<TraceEntry>,
        observer: &'a dyn DiscoveryObserver,
    ) -> Self {
        Self {
            pipeline,
            tracks,
            stats,
            dmat,
            sigma,
            source,
            first_guess,
            trace: Mutex::new((trace, 0)),
            observer,
            memo: Memo::new(pipeline.runner.memo_mib.saturating_mul(1 << 20)),
        }
    }

    pub(crate) fn context(&self) -> RepairContext<'_> {
        RepairContext {
            tracks: self.tracks,
            stats: self.stats,
            dissimilarity: self.dmat,
            noise_sigma_m: self.sigma,
            estimated_noise_sigma_m: self.first_guess,
            stages: slots(self.pipeline),
            models: Some(self),
            seed: self.pipeline.seed,
            tree: self.pipeline.tree,
            memo: Some(&self.memo),
        }
    }

    fn record(&self, repair: &dyn Repair, outcome: &str, proposal: &Proposal) {
        let made = self.trace.lock().ok().map(|mut t| {
            let e = entry(repair, t.1, outcome, proposal);
            t.0.push(e.clone());
            e
        });
        if let Some(e) = made {
            self.observer.trace(&e);
        }
    }

    /// Runs `call` (a `propose` or `stands` of `repair`) and tells the observer its time.
    fn timed<T>(&self, repair: &dyn Repair, call: impl FnOnce() -> T) -> T {
        timed(self.observer, repair, call)
    }

    fn set_pass(&self, pass: usize) {
        if let Ok(mut t) = self.trace.lock() {
            t.1 = pass;
        }
    }

    fn phase(&self, phase: RepairPhase) -> Vec<&'a dyn Repair> {
        self.pipeline
            .repairs
            .iter()
            .map(AsRef::as_ref)
            .filter(|r| r.phase() == phase)
            .collect()
    }

    /// Refuses the run when the bodies and model phases on the draft's bodies are estimated to
    /// take longer than [`Pipeline::max_minutes`] ([`kinetree_core::limits::model_seconds`]).
    fn check_model_work(&self, draft: &Draft) -> Result<()> {
        let (t, b) = (self.tracks.n_frames(), draft.segmentation.n_bodies());
        let advice = if self.source == NoiseSource::Estimated {
            format!(
                "the noise level was estimated ({:.3} mm), and an underestimate splits bodies: \
                 give it with --noise-sigma (`noise_sigma_m`) if it is known",
                self.sigma * 1e3
            )
        } else {
            String::new()
        };
        kinetree_core::limits::check_work(
            &format!("the bodies and model phases on {b} bodies over {t} frames"),
            kinetree_core::limits::model_seconds(t as u64, b as u64),
            self.pipeline.max_minutes,
            &advice,
        )
    }

    /// Tests every pair on the draft's poses.
    fn test_pairs(&self, draft: &mut Draft) -> Result<()> {
        if draft.segmentation.n_bodies() == 0 {
            return Err(Error::Degenerate(
                "no rigid body of three or more points could be found and registered".into(),
            ));
        }
        let poses = crate::repairs::poses_of("runner", draft.poses.as_ref())?;
        draft.pairs = Some(all_pairs(
            self.pipeline.dof.as_ref(),
            poses,
            self.sigma,
            Some(&self.memo),
        )?);
        Ok(())
    }

    /// The bodies phase on `draft`: poses, then the bodies repairs in order, the poses redone
    /// after every segmentation edit; ends with the draft's poses and pair tests. Segmentation
    /// edits' warnings go to `history`; the warnings of the final poses' edits are returned.
    fn bodies(&self, draft: &mut Draft, history: &mut Vec<Warning>) -> Result<Vec<Warning>> {
        draft.constraints.start_bodies_phase();
        let phase = self.phase(RepairPhase::Bodies);
        let (mut asked, mut edits) = (vec![0usize; phase.len()], vec![0usize; phase.len()]);
        let ctx = self.context();
        let mut pose_warnings = Vec::new();
        'poses: loop {
            draft.poses = Some(self.pipeline.pose.estimate(&PoseInput {
                tracks: self.tracks,
                segmentation: &draft.segmentation,
                noise_sigma_m: self.sigma,
            })?);
            draft.pairs = None;
            pose_warnings.clear();
            for (k, &r) in phase.iter().enumerate() {
                if !may_ask(r, asked[k], edits[k]) {
                    continue;
                }
                if r.needs_pair_tests() && draft.pairs.is_none() {
                    self.test_pairs(draft)?;
                }
                asked[k] += 1;
                let Some(proposal) = self.timed(r, || r.propose(&ctx, draft))? else {
                    continue;
                };
                edits[k] += 1;
                self.record(r, "applied", &proposal);
                draft.constraints.extend(&proposal.constraints);
                match proposal.edit {
                    Edit::Poses(poses) => {
                        draft.poses = Some(poses);
                        draft.pairs = None;
                        pose_warnings.extend(proposal.warnings);
                    }
                    Edit::Segmentation(seg) => {
                        history.extend(proposal.warnings);
                        draft.segmentation = seg;
                        for (j, other) in phase.iter().enumerate() {
                            if other.reopened_by().contains(&r.name()) {
                                asked[j] = 0;
                            }
                        }
                        continue 'poses;
                    }
                    edit => return Err(wrong_edit(r, &edit)),
                }
            }
            break;
        }
        if draft.pairs.is_none() {
            self.test_pairs(draft)?;
        }
        Ok(pose_warnings)
    }

    /// The model's whole-tree fit, into `model.fitted`.
    fn fit(&self, model: &mut ModelDraft) -> Result<()> {
        if model.fitted.is_none() {
            let motions = kinetree_fit::FittedMotions::new(&model.model, self.tracks)?;
            model.fitted = Some(motions.into_fitted());
        }
        Ok(())
    }

    /// Asks the points repairs (those `only` admits) on `draft`, each seeing the edits of the
    /// ones before it.
    fn ask_points(
        &self,
        draft: &mut Draft,
        only: impl Fn(&dyn Repair) -> bool,
    ) -> Result<Vec<(&'a dyn Repair, Proposal)>> {
        let ctx = self.context();
        let mut out = Vec::new();
        draft.pending.clear();
        for r in self.phase(RepairPhase::Points) {
            if !only(r) {
                continue;
            }
            if let Some(p) = self.timed(r, || r.propose(&ctx, draft))? {
                let Edit::Points(moves) = &p.edit else {
                    return Err(wrong_edit(r, &p.edit));
                };
                draft.pending.extend(moves.iter().copied());
                out.push((r, p));
            }
        }
        draft.pending.clear();
        Ok(out)
    }

    /// The whole run after the grouping: bodies, model, and passes of point edits.
    pub(crate) fn run(
        &self,
        seg: Segmentation,
        mut history: Vec<Warning>,
    ) -> Result<(Draft, Vec<TraceEntry>)> {
        let ctx = self.context();
        let passes = self.pipeline.runner.model_passes;
        let mut draft = Draft::new(seg);
        let mut previous: Option<Applied<'_>> = None;
        let mut pass = 0;
        let last = loop {
            self.set_pass(pass);
            let stage = |name: &str| {
                if pass == 0 {
                    self.observer.stage(name);
                } else {
                    self.observer.stage(&format!("{name} (pass {})", pass + 1));
                }
            };
            // The clustering's bodies bound the work before the bodies phase (its splits and
            // pair tests grow with them too), and the phase's bodies before the model phases.
            if pass == 0 {
                self.check_model_work(&draft)?;
            }
            stage("bodies");
            let pose_warnings = self.bodies(&mut draft, &mut history)?;
            if pass == 0 {
                self.check_model_work(&draft)?;
            }
            let hist: Vec<Warning> = history.iter().cloned().chain(pose_warnings).collect();
            let (Some(poses), Some(pairs)) = (&draft.poses, &draft.pairs) else {
                return Err(Error::Degenerate("the bodies phase left no poses".into()));
            };
            stage("tree");
            let mut model = self.make(&draft.segmentation, poses, pairs, &hist)?;
            self.adopt(&mut model);
            stage("whole-tree fit");
            self.fit(&mut model)?;
            draft.adopt(model)?;
            // The previous pass's edits must stand on this model. One that does not is undone
            // and the model made again with the others; with none left, the pass is undone.
            if let Some(applied) = previous.take() {
                let mut undone = None;
                for (k, (r, p)) in applied.edits.iter().enumerate() {
                    if !self.timed(*r, || r.stands(&ctx, &p.edit, &applied.before, &draft))? {
                        undone = Some(k);
                        break;
                    }
                }
                if let Some(k) = undone {
                    let Applied {
                        before,
                        mut edits,
                        history: kept,
                    } = applied;
                    let (r, p) = edits.remove(k);
                    let mut points: Vec<usize> = match &p.edit {
                        Edit::Points(moves) => moves.iter().map(|&(p, _)| p).collect(),
                        _ => Vec::new(),
                    };
                    points.sort_unstable();
                    let others = !edits.is_empty() && self.pipeline.runner.redo_passes;
                    let mut note = Proposal::new(
                        p.edit,
                        if others {
                            "undone: this edit did not stand on its model, which is made again with the pass's other edits"
                        } else {
                            "the previous pass undone: this edit did not stand on its model"
                        },
                    );
                    note.points = points;
                    self.record(r, "reverted", &note);
                    if !others {
                        break before;
                    }
                    history.clone_from(&kept);
                    for (_, p) in &edits {
                        history.extend(p.warnings.iter().cloned());
                    }
                    draft = edited(&before, &edits);
                    previous = Some(Applied {
                        before,
                        edits,
                        history: kept,
                    });
                    continue;
                }
            }
            let mut proposals = if pass < passes {
                stage("points");
                self.ask_points(&mut draft, |_| true)?
            } else {
                Vec::new()
            };
            if proposals.is_empty() {
                stage("model checks");
                for r in self.phase(RepairPhase::Model) {
                    let Some(p) = self.timed(r, || r.propose(&ctx, &draft))? else {
                        continue;
                    };
                    self.record(r, "applied", &p);
                    let Edit::Model { mut model, poses } = p.edit else {
                        return Err(wrong_edit(r, &p.edit));
                    };
                    self.adopt(&mut model);
                    draft.poses = Some(poses);
                    draft.pairs = None;
                    draft.adopt(*model)?;
                    if pass < passes {
                        if let Some(m) = draft.model.as_mut() {
                            self.fit(m)?;
                        }
                        proposals = self.ask_points(&mut draft, |r| r.asked_on_replaced_model())?;
                    }
                    if !proposals.is_empty() {
                        break;
                    }
                }
            }
            if proposals.is_empty() {
                break draft;
            }
            let kept = history.clone();
            let mut edits = Vec::new();
            for (r, p) in proposals {
                if !matches!(p.edit, Edit::Points(_)) {
                    return Err(wrong_edit(r, &p.edit));
                }
                self.record(r, "applied", &p);
                history.extend(p.warnings.iter().cloned());
                edits.push((r, p));
            }
            let next = edited(&draft, &edits);
            previous = Some(Applied {
                before: std::mem::replace(&mut draft, next),
                edits,
                history: kept,
            });
            pass += 1;
        };
        let trace = self
            .trace
            .lock()
            .map(|mut t| std::mem::take(&mut t.0))
            .unwrap_or_default();
        self.observer.memo(self.memo.usage());
        Ok((last, trace))
    }

    /// Finishes a model assembled from `seg`: point confidence, bodies' internal
    /// dissimilarity, the whole-tree fit, the fit repairs in order (on a draft that adopted
    /// the model), and the positions, their precision and the re-prediction written from the
    /// final fit. The fit repairs' trace entries are left in the model's `trace`, for the
    /// caller to keep if it adopts the model.
    fn finish(&self, seg: &Segmentation, mut m: ModelDraft) -> Result<ModelDraft> {
        let diag = kinetree_clustering::diagnostics(self.dmat, seg);
        m.model.point_confidence = diag.point_margin.clone();
        for body in &mut m.model.bodies {
            body.internal_dissimilarity = diag.body_spread[m.body_order[body.id]];
        }
        let state = kinetree_fit::FitState::new(&m.model, self.tracks)?;
        m.cache = Some(std::sync::Arc::new(state));
        let ctx = self.context();
        let pass = self.trace.lock().map_or(0, |t| t.1);
        let mut entries = Vec::new();
        let order = m.body_order.clone();
        let mut draft = Draft::new(seg.clone());
        draft.adopt(m)?;
        for r in self.phase(RepairPhase::Fit) {
            let Some(p) = self.timed(r, || r.propose(&ctx, &draft))? else {
                continue;
            };
            entries.push(entry(r, pass, "applied", &p));
            let Edit::Fit(refit) = p.edit else {
                return Err(wrong_edit(r, &p.edit));
            };
            draft.model = Some(*refit);
        }
        let Some(mut m) = draft.model else {
            return Err(Error::Degenerate("no model to finish".into()));
        };
        let state = crate::repairs::fit_state(&ctx, &m)?;
        m.cache = None;
        m.body_order = order;
        write_fit(self.pipeline, &mut m.model, &state, ctx.tracks)?;
        m.model.trace = entries;
        Ok(m)
    }

    /// Keeps the fit repairs' trace entries of an adopted model.
    fn adopt(&self, m: &mut ModelDraft) {
        let entries = std::mem::take(&mut m.model.trace);
        for e in &entries {
            self.observer.trace(e);
        }
        if let Ok(mut t) = self.trace.lock() {
            t.0.extend(entries);
        }
    }
}

/// `pairs` with each pair between the same two bodies as one in `replaced` (either order)
/// replaced by it.
pub(crate) fn with_replaced(pairs: &[PairDof], replaced: &[PairDof]) -> Vec<PairDof> {
    pairs
        .iter()
        .map(|p| {
            replaced
                .iter()
                .find(|q| same_bodies(p, q))
                .unwrap_or(p)
                .clone()
        })
        .collect()
}

/// Whether two pair tests are between the same two frames, in either order.
fn same_bodies(p: &PairDof, q: &PairDof) -> bool {
    (p.a, p.b) == (q.a, q.b) || (p.a == Some(q.b) && q.a == Some(p.b))
}

/// Adds a [`Warning::JointTypedBySibling`] for each joint of `alt` (bodies numbered as
/// `alt.body_order` says) assembled from a pair in `replaced` whose type differs from the one
/// the draft's own test in `tested` found.
fn warn_typed_by_sibling(alt: &mut ModelDraft, replaced: &[PairDof], tested: &[PairDof]) {
    let order = &alt.body_order;
    let mut found = Vec::new();
    for j in &alt.model.joints {
        let (Some(&p), Some(&c)) = (order.get(j.parent), order.get(j.child)) else {
            continue;
        };
        let Some(q) = replaced
            .iter()
            .find(|q| (q.a, q.b) == (Some(p), c) || (q.a, q.b) == (Some(c), p))
        else {
            continue;
        };
        let Some(own) = tested.iter().find(|t| same_bodies(t, q)) else {
            continue;
        };
        if own.joint.joint_type() != j.joint_type {
            found.push(Warning::JointTypedBySibling {
                parent: j.parent,
                child: j.child,
                tested: own.joint.joint_type(),
                joint_type: j.joint_type,
            });
        }
    }
    alt.model.warnings.extend(found);
}

impl ModelMaker for Runner<'_> {
    fn assemble(
        &self,
        segmentation: &Segmentation,
        poses: &BodyPoses,
        pairs: &[PairDof],
        excluded: &[(usize, usize)],
        replaced: &[PairDof],
        history: &[Warning],
    ) -> Result<ModelDraft> {
        let mut m = crate::assemble::assemble(
            self.pipeline,
            self.tracks,
            segmentation,
            poses,
            pairs.to_vec(),
            self.sigma,
            self.source,
            history.to_vec(),
            excluded,
            replaced,
            Some(&self.memo),
        )?;
        m.history = history.to_vec();
        Ok(m)
    }

    fn make_without(
        &self,
        segmentation: &Segmentation,
        poses: &BodyPoses,
        pairs: &[PairDof],
        excluded: &[(usize, usize)],
        history: &[Warning],
    ) -> Result<ModelDraft> {
        let ctx = self.context();
        let first = self.assemble(segmentation, poses, pairs, excluded, &[], history)?;
        // The excluded edges in the first model's numbering, for the alternatives (a model
        // whose body order is no permutation is refused by `adopt` below).
        let renumbered: Vec<(usize, usize)> =
            kinetree_core::inverse_permutation(&first.body_order, segmentation.n_bodies())
                .map(|new_id| {
                    excluded
                        .iter()
                        .filter_map(|&(p, c)| Some((*new_id.get(p)?, *new_id.get(c)?)))
                        .collect()
                })
                .unwrap_or_default();
        let mut draft = Draft::new(segmentation.clone());
        draft.poses = Some(poses.clone());
        draft.pairs = Some(pairs.to_vec());
        draft.adopt(first)?;
        // From here on the draft is in the first model's numbering; the alternatives are
        // assembled from it, and each adopted in turn.
        let mut alternatives = Vec::new();
        for r in self.phase(RepairPhase::Tree) {
            if let Some(p) = self.timed(r, || r.propose(&ctx, &draft))? {
                let Edit::Tree { excluded, replaced } = &p.edit else {
                    return Err(wrong_edit(r, &p.edit));
                };
                let (Some(poses), Some(pairs)) = (&draft.poses, &draft.pairs) else {
                    return Err(Error::Degenerate("no poses to assemble from".into()));
                };
                let all: Vec<(usize, usize)> =
                    excluded.iter().chain(&renumbered).copied().collect();
                let pairs = with_replaced(pairs, replaced);
                let alt =
                    self.assemble(&draft.segmentation, poses, &pairs, &all, replaced, history)?;
                alternatives.push((r, p, alt, pairs));
            }
        }
        let Some(first) = draft.model.take() else {
            return Err(Error::Degenerate("no model to finish".into()));
        };
        draft.model = Some(self.finish(&draft.segmentation, first)?);
        for (r, p, alt, pairs) in alternatives {
            let mut after = draft.clone();
            after.pairs = Some(pairs);
            let mut alt = self.finish(&draft.segmentation, alt)?;
            if let Edit::Tree { replaced, .. } = &p.edit {
                warn_typed_by_sibling(&mut alt, replaced, draft.pairs.as_deref().unwrap_or(&[]));
            }
            after.adopt(alt)?;
            if self.timed(r, || r.stands(&ctx, &p.edit, &draft, &after))? {
                self.record(r, "kept", &p);
                draft = after;
            } else {
                self.record(r, "discarded", &p);
            }
        }
        let mut made = draft
            .model
            .ok_or_else(|| Error::Degenerate("no model was made".into()))?;
        made.body_order = bodies_in(&draft.segmentation, segmentation)?;
        Ok(made)
    }
}
