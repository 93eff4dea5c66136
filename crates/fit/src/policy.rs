//! The fit's policy on a model: joints the whole-tree fit cannot follow freed, the followed
//! ones bundle-adjusted ([`crate::bundle`]), freed joints refined alone ([`crate::refine`])
//! and readmitted when they fit again, multi-DoF joints typed by the fit; then the positions,
//! their precision, their smoothing and every joint's range written into the model.

use crate::bundle::BundleLimits;
use crate::solver::{FrameFit, Measure, Observer, rms_in_sigma};
use kinetree_core::model::{JointFit, JointType, RigidTransform};
use kinetree_core::nalgebra::{Isometry3, Matrix3, Point3, UnitQuaternion, Vector3};
use kinetree_core::{Model, Result, Tracks, Warning};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// A model's whole-tree fit between the steps of the fit's policy: the observer built from the
/// model (its freed joints included), its fit of every frame, and a fingerprint of the parts
/// of the model it was made from, so a step can tell whether it is still the model's fit.
#[derive(Debug, Clone)]
pub struct FitState {
    observer: Observer,
    fits: Vec<FrameFit>,
    made_from: String,
}

/// What the fit depends on: the noise level, the bodies' keypoints and shapes, each joint's
/// place, type,
/// parameters and fit status, and (for files of schema 1) the warnings that free joints.
/// Written with `Debug`, so that a NaN compares equal to itself; the joints' positions, which
/// the fit writes and never reads, are left out.
fn fingerprint(model: &Model) -> String {
    use std::fmt::Write as _;
    let mut s = format!("{} {:?};", model.n_points, model.noise.sigma_m);
    for b in &model.bodies {
        let _ = write!(s, "{:?}{:?}", b.points, b.shape);
    }
    for j in &model.joints {
        let _ = write!(
            s,
            "{} {} {:?} {:?} {:?} {:?} {} {:?};",
            j.parent,
            j.child,
            j.joint_type,
            j.axis_in_parent,
            j.point_in_parent,
            j.reference_pose,
            j.reference_frame,
            j.fit
        );
    }
    if model.schema_version < 2 {
        let _ = write!(s, "{:?}", model.warnings);
    }
    s
}

impl FitState {
    /// The whole-tree fit of `model` on `tracks`.
    ///
    /// # Errors
    /// As [`Observer::new`] and [`Observer::fit_sequence`].
    pub fn new(model: &Model, tracks: &Tracks) -> Result<Self> {
        let observer = Observer::new(model)?;
        let fits = observer.fit_sequence(tracks)?;
        Ok(Self::of(model, observer, fits))
    }

    pub(crate) fn of(model: &Model, observer: Observer, fits: Vec<FrameFit>) -> Self {
        Self {
            observer,
            fits,
            made_from: fingerprint(model),
        }
    }

    /// The fit after a step that changed `model` (a new fingerprint) or left it as it was (the
    /// old one, `made_from`, which still holds).
    fn kept(
        model: &Model,
        observer: Observer,
        fits: Vec<FrameFit>,
        made_from: String,
        changed: bool,
    ) -> Self {
        if changed {
            Self::of(model, observer, fits)
        } else {
            Self {
                observer,
                fits,
                made_from,
            }
        }
    }

    /// Whether this is the fit of `model` as it is now.
    pub fn is_of(&self, model: &Model) -> bool {
        self.made_from == fingerprint(model)
    }

    /// The fit of every frame.
    pub fn fits(&self) -> &[FrameFit] {
        &self.fits
    }

    /// The observer that fitted them.
    pub(crate) fn observer(&self) -> &Observer {
        &self.observer
    }
}

/// Replaces the joint positions of `model` (discovered on `tracks`) with the kinematic fit of
/// every frame ([`Observer::fit_sequence`]) after the fit's policy at its default limits:
/// [`free_unfollowed_joints`], [`bundle_adjust`], [`readmit_freed_joints`] and
/// [`type_joints_by_fit`], then [`write_positions`]. Returns the fit's RMS residual in units of
/// the model's noise level (`None` with no usable frame). The pipeline runs the same steps as
/// the repairs `free_joints`, `bundle_adjust`, `readmit_joints` and `type_by_fit`, each of
/// which can be turned off.
///
/// # Errors
/// As [`Observer::new`] and [`Observer::fit_sequence`].
pub fn fit_model_positions(model: &mut Model, tracks: &Tracks) -> Result<Option<f64>> {
    let state = FitState::new(model, tracks)?;
    let (state, _) = free_unfollowed_joints(model, tracks, state, &FreeLimits::default())?;
    let (state, _) = bundle_adjust(model, tracks, state, &BundleLimits::default())?;
    let (state, _) = readmit_freed_joints(model, tracks, state, READMIT_EXCESS, MAX_JOINT_EXCESS)?;
    let (state, _) = type_joints_by_fit(model, tracks, state, &TypeByFitLimits::default())?;
    write_positions(model, &state)
}

/// The limits of [`free_unfollowed_joints`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FreeLimits {
    /// A joint whose [`Observer::joint_excess`] is above this is over the limit (default
    /// [`MAX_JOINT_EXCESS`]).
    pub max_excess: f64,
    /// With more candidates than `screen_keep`, each is first ranked on every
    /// `screen_stride`-th frame only, each such frame's fit started from the current fit's
    /// (default 4; 1 fits every candidate on every frame).
    pub screen_stride: usize,
    /// ... and the `screen_keep` candidates with the least residual there are fitted on every
    /// frame, the least full residual chosen among them (default 2; `docs/decisions.md`,
    /// `free_joints.screen_stride`).
    pub screen_keep: usize,
}

impl Default for FreeLimits {
    fn default() -> Self {
        Self {
            max_excess: MAX_JOINT_EXCESS,
            screen_stride: 4,
            screen_keep: 2,
        }
    }
}

/// Frees, one at a time, the joints of `model` whose [`Observer::joint_excess`] is over
/// `limits.max_excess` (a `joint_not_followed` warning each), refitting the sequence after
/// each. A wrong joint also spoils the joints above it, which bend to absorb its miss (their
/// excess can be the larger), so each round tries every joint over the limit and every joint
/// below one, and frees the one whose freeing leaves the smallest residual. Where there are
/// many such candidates, a fit of every few frames ranks them and only the best few are fitted
/// on every frame ([`FreeLimits`]): a round then costs about a quarter of a full fit per
/// candidate and two full fits. Returns the new fit and the joints freed, in order.
///
/// # Errors
/// As [`Observer::fit_sequence`].
pub fn free_unfollowed_joints(
    model: &mut Model,
    tracks: &Tracks,
    state: FitState,
    limits: &FreeLimits,
) -> Result<(FitState, Vec<usize>)> {
    let FitState {
        mut observer,
        mut fits,
        ..
    } = state;
    let max_excess = limits.max_excess;
    let screen: Vec<usize> = (0..tracks.n_frames())
        .step_by(limits.screen_stride.max(1))
        .collect();
    let mut freed_now = Vec::new();
    loop {
        let excess = observer.joint_excess(tracks, &fits)?;
        let over: Vec<usize> = (0..observer.joints.len())
            .filter(|&k| excess[k].is_some_and(|e| e > max_excess))
            .collect();
        if over.is_empty() {
            break;
        }
        let candidates: Vec<usize> = (0..observer.joints.len())
            .filter(|&k| {
                observer.joint_col[k].is_some()
                    && over.iter().any(|&o| {
                        o == k
                            || observer.joint_col[o].is_some_and(|c| {
                                observer.cols[observer.joints[k].child].contains(&c)
                            })
                    })
            })
            .collect();
        let candidates = if limits.screen_stride > 1 && candidates.len() > limits.screen_keep {
            screened(
                &observer,
                tracks,
                &fits,
                &candidates,
                &screen,
                limits.screen_keep,
            )?
        } else {
            candidates
        };
        // Each candidate is freed and the sequence refitted independently, in parallel; the
        // best is then chosen in joint order, as a sequential loop would.
        let trials = candidates
            .par_iter()
            .map(|&k| {
                let mut trial = observer.clone();
                trial.free_joint(k);
                let trial_fits = trial.fit_sequence(tracks)?;
                let miss: f64 = trial_fits.iter().map(|f| f.sum_sq_m2).sum();
                Ok((k, miss, trial, trial_fits))
            })
            .collect::<Result<Vec<_>>>()?;
        let mut best: Option<(usize, f64, Observer, Vec<FrameFit>)> = None;
        for trial in trials {
            if best.as_ref().is_none_or(|b| trial.1 < b.1) {
                best = Some(trial);
            }
        }
        let Some((k, _, freed, freed_fits)) = best else {
            break;
        };
        (observer, fits) = (freed, freed_fits);
        model.joints[k].fit = JointFit::Freed;
        let j = &model.joints[k];
        model.warnings.push(Warning::JointNotFollowed {
            parent: j.parent,
            child: j.child,
            excess_in_sigma2: excess[k].unwrap_or(f64::NAN),
        });
        freed_now.push(k);
    }
    Ok((FitState::of(model, observer, fits), freed_now))
}

/// The `keep` of `candidates` whose freeing leaves the least residual over the `frames`, in
/// joint order (ties to the earlier joint). Each frame's fit starts from `known`, the fit
/// before the freeing: a few steps a frame, where a fit from the listed frame before took two
/// to three times as long.
fn screened(
    observer: &Observer,
    tracks: &Tracks,
    known: &[FrameFit],
    candidates: &[usize],
    frames: &[usize],
    keep: usize,
) -> Result<Vec<usize>> {
    let misses = candidates
        .par_iter()
        .map(|&k| {
            let mut trial = observer.clone();
            trial.free_joint(k);
            trial.settled_miss(tracks, known, frames)
        })
        .collect::<Result<Vec<f64>>>()?;
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    order.sort_by(|&a, &b| misses[a].total_cmp(&misses[b]).then(a.cmp(&b)));
    let mut kept: Vec<usize> = order.iter().take(keep).map(|&i| candidates[i]).collect();
    kept.sort_unstable();
    Ok(kept)
}

/// Bundle-adjusts the single-DoF joints the fit follows with every frame's configuration (see
/// `crate::bundle`), after the freeing so a wrong joint does not bend the others. Returns the
/// new fit and whether the joints changed.
///
/// Measured: it replaced rounds of one-joint refinements against the whole-tree fit's poses;
/// on a draw of 640 random mechanisms at 1 mm, axes under 1 deg went from 2764 to 2830 of 2837
/// joints and positions within their limit from 2642 to 2764 (`docs/decisions.md`).
///
/// # Errors
/// As [`Observer::fit_sequence`].
pub fn bundle_adjust(
    model: &mut Model,
    tracks: &Tracks,
    state: FitState,
    limits: &BundleLimits,
) -> Result<(FitState, bool)> {
    match adjust_model(model, &state.observer, tracks, &state.fits, limits, None)? {
        Some((observer, fits)) => Ok((FitState::of(model, observer, fits), true)),
        None => Ok((state, false)),
    }
}

/// Puts freed joints back into the fit where they only had poor parameters (a small parent's
/// noisy poses misled the tester): each is refined with its parent posed by the fit, in which
/// its child moves freely, put back, and kept there when its excess is then within
/// `max_excess` and every other joint's within `others_max_excess`. Returns the new fit and
/// the joints put back.
///
/// # Errors
/// As [`Observer::new`] and [`Observer::fit_sequence`].
pub fn readmit_freed_joints(
    model: &mut Model,
    tracks: &Tracks,
    state: FitState,
    max_excess: f64,
    others_max_excess: f64,
) -> Result<(FitState, Vec<usize>)> {
    let FitState {
        mut observer,
        mut fits,
        made_from,
    } = state;
    let mut readmitted = Vec::new();
    accept_in_order(
        model,
        (&mut observer, &mut fits),
        &mut readmitted,
        |_, k, observer, _| observer.freed[k],
        |trial_model, k, observer, fits| {
            readmitted_trial(
                trial_model,
                k,
                tracks,
                (observer, fits),
                (max_excess, others_max_excess),
            )
        },
    )?;
    let state = FitState::kept(model, observer, fits, made_from, !readmitted.is_empty());
    Ok((state, readmitted))
}

/// A new observer and its fit, or `None`: what a joint's trial returns.
type Trial = Option<(Observer, Vec<FrameFit>)>;

/// Joints tried in order, each on the fit the accepted trials before it left, those already
/// `accepted` skipped; each accepted joint is appended. A trial that accepts nothing leaves
/// the model as it was, so the trials from one state run in parallel (each on a clone of the
/// model), as many at a time as there are threads, and the first that accepts its joint is
/// taken, as a loop in joint order would take it; the joints after it are then tried again on
/// the new fit. Trying every joint at once would make the trials after the accepted one only
/// to make them again on the new fit (`docs/decisions.md`, "Parallel trials of
/// readmit_joints and hinges").
fn accept_in_order(
    model: &mut Model,
    (observer, fits): (&mut Observer, &mut Vec<FrameFit>),
    accepted: &mut Vec<usize>,
    tried: impl Fn(&Model, usize, &Observer, &[FrameFit]) -> bool,
    trial: impl Fn(&mut Model, usize, &Observer, &[FrameFit]) -> Result<Trial> + Sync,
) -> Result<()> {
    let mut from = 0;
    loop {
        let tries: Vec<usize> = (from..observer.joints.len())
            .filter(|&k| !accepted.contains(&k) && tried(model, k, observer, fits))
            .collect();
        // The group size changes only which trials are made, never which is taken.
        let group = rayon::current_num_threads().max(1);
        let mut found = None;
        'groups: for ks in tries.chunks(group) {
            let results: Vec<Result<Option<_>>> = ks
                .par_iter()
                .map(|&k| {
                    let mut trial_model = model.clone();
                    let found = trial(&mut trial_model, k, observer, fits)?;
                    Ok(found.map(|f| (k, trial_model, f)))
                })
                .collect();
            // In joint order: an error counts only where a loop would have met it.
            for result in results {
                if let Some(t) = result? {
                    found = Some(t);
                    break 'groups;
                }
            }
        }
        let Some((k, accepted_model, (trial_observer, trial_fits))) = found else {
            return Ok(());
        };
        *model = accepted_model;
        (*observer, *fits) = (trial_observer, trial_fits);
        accepted.push(k);
        from = k + 1;
    }
}

/// Freed joint `k` refined against its child's keypoints and put back into `model`'s fit,
/// with the new observer and fit, when the fit then follows it within the first bound and
/// every other joint within the second; `None` (and `model` left in an unspecified state)
/// otherwise.
fn readmitted_trial(
    model: &mut Model,
    k: usize,
    tracks: &Tracks,
    (observer, fits): (&Observer, &[FrameFit]),
    (max_excess, others_max_excess): (f64, f64),
) -> Result<Trial> {
    if !refine_joint(model, k, observer, tracks, fits) {
        return Ok(None);
    }
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    model.joints[k].fit = JointFit::Followed;
    model.warnings.retain(|w| {
        !matches!(w, Warning::JointNotFollowed { parent: p, child: c, .. } if *p == parent && *c == child)
    });
    let trial = Observer::new(model)?;
    let trial_fits = trial.fit_sequence(tracks)?;
    let excess = trial.joint_excess(tracks, &trial_fits)?;
    let followed = excess[k].is_some_and(|e| e <= max_excess)
        && excess
            .iter()
            .all(|e| e.is_none_or(|e| e <= others_max_excess));
    Ok(followed.then_some((trial, trial_fits)))
}

/// The limits of [`type_joints_by_fit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TypeByFitLimits {
    /// A typed joint's excess must be within this (default 3.0; `docs/decisions.md`,
    /// `type_by_fit.max_excess`).
    pub max_excess: f64,
    /// ... and every other joint's within this (default 30, the freeing bound).
    pub others_max_excess: f64,
    /// Only joints whose pair test found at most this many rotation directions are tried
    /// (default 1): tried on every multi-DoF joint, the human joints of a tennis serve
    /// (rotation rank 2-3) were typed, one as a slide, and the re-prediction rose from 2.3 to
    /// 3.4 sigma.
    pub max_rotation_rank: usize,
    /// ... and at most this many translation directions (default 2).
    pub max_translation_rank: usize,
    /// A spherical joint is tried as a hinge only when its fitted rotations stray from their
    /// principal axis by at most this many of their standard deviations, RMS (default 20;
    /// two hinges typed spherical at 10 mm of noise strayed by 6-18, the ball joints of a
    /// simulated skeleton by 20-180, and each trial costs a refinement and a bundle
    /// adjustment); a universal joint when one of its two angles spreads by at most as
    /// many.
    pub max_ball_off_axis_in_std: f64,
    /// A universal joint the fit follows is typed spherical when the ball lowers the fit's
    /// squared residual, in noise variances, by more than the `K` frames with angles plus
    /// this many standard deviations `sqrt(2 K)` of what the extra coordinate gains on a
    /// true universal joint (default 5: at 300 frames, true universal joints of simulated
    /// skeletons gained 0.83-1.23 per frame, balls typed universal 1.5 and more, the bound
    /// is 1.41; see [`type_joints_by_fit`]).
    pub min_ball_gain_in_std: f64,
    /// Whether every hinge the fit follows is tried as a universal joint (default off: each
    /// trial costs two fits of every frame and a bundle adjustment; see
    /// [`type_joints_by_fit`]).
    pub hinges_as_universal: bool,
    /// Such a hinge is typed universal when the second axis lowers the fit's squared
    /// residual, in noise variances, over the `K` frames where both joints have positions,
    /// by more than `K` plus this many `sqrt(2 K)` (default 5, as `min_ball_gain_in_std`).
    pub min_universal_gain_in_std: f64,
    /// ... and by at least this many noise variances per frame (default 5;
    /// `docs/decisions.md`, `type_by_fit.min_universal_gain_per_frame`): a true hinge below a
    /// small or noisy parent gains a few per frame from any second axis, more than the
    /// chi-square bound allows over hundreds of frames, where a knuckle's abduction gains
    /// tens.
    pub min_universal_gain_per_frame: f64,
    /// A hinge is tried as a universal joint only when a ball about its pivot places the
    /// child's keypoints better than the hinge by at least this many noise variances per
    /// frame, each frame fitted on the parent's fitted pose in closed form (default 2.5;
    /// a true hinge gains a chi-square of two degrees of freedom; `docs/decisions.md`,
    /// `type_by_fit.universal_screen_per_frame`).
    pub universal_screen_per_frame: f64,
    /// A candidate whose excess, refined but before the bundle adjustment, is above this is
    /// not adjusted and not kept (default 1000): over every sweep the adjustment cut a
    /// candidate's excess at most 178-fold, so such a candidate cannot reach `max_excess`,
    /// and its adjustment is most of a typing trial's cost (`docs/decisions.md`).
    pub max_excess_to_adjust: f64,
    /// Whether a candidate is first bundle-adjusted with only the joints that share a body
    /// with it, and dropped when its excess is then above `max_local_excess` (default on).
    pub screen_locally: bool,
    /// That bound (default 9, three times `max_excess`; `docs/decisions.md`,
    /// `type_by_fit.max_local_excess`).
    pub max_local_excess: f64,
    /// The bundle adjustment of each candidate type.
    pub bundle: BundleLimits,
}

impl Default for TypeByFitLimits {
    fn default() -> Self {
        Self {
            max_excess: TYPE_EXCESS,
            others_max_excess: MAX_JOINT_EXCESS,
            max_rotation_rank: 1,
            max_translation_rank: 2,
            max_ball_off_axis_in_std: BALL_OFF_AXIS,
            min_ball_gain_in_std: BALL_GAIN_IN_STD,
            hinges_as_universal: false,
            min_universal_gain_in_std: BALL_GAIN_IN_STD,
            min_universal_gain_per_frame: UNIVERSAL_GAIN_PER_FRAME,
            universal_screen_per_frame: UNIVERSAL_SCREEN_PER_FRAME,
            max_excess_to_adjust: TYPE_EXCESS_TO_ADJUST,
            screen_locally: true,
            max_local_excess: LOCAL_EXCESS,
            bundle: BundleLimits::default(),
        }
    }
}

/// Types by the fit a multi-DoF joint whose child still moves as a hinge or a slide in it (a
/// small body's noisy poses can fake a second degree of freedom in the pair test): a slide,
/// then a hinge, is fitted from the two bodies' fitted poses, refined like a freed joint, and
/// the first the fit then follows closely is kept (see `type_by_fit`). A freed single-DoF
/// joint gets the other single-DoF type tried the same way: a link turning a little on the
/// base can show no rotation in its pair test and a straight path. A freed slide is first
/// fitted again as a slide, from the fitted poses: its axis, from a child posed in a few
/// frames, can miss, and a hinge about a pivot metres away then fits the child as closely
/// with two more parameters. A universal joint is tried as a ball and then as a hinge (see
/// `universal_by_fit`). With `hinges_as_universal`, every hinge the fit follows is first tried
/// as a universal joint (see `universal_from_hinge`). Returns the new fit and the joints typed.
///
/// # Errors
/// As [`Observer::new`] and [`Observer::fit_sequence`].
pub fn type_joints_by_fit(
    model: &mut Model,
    tracks: &Tracks,
    state: FitState,
    limits: &TypeByFitLimits,
) -> Result<(FitState, Vec<usize>)> {
    let FitState {
        mut observer,
        mut fits,
        made_from,
    } = state;
    let mut typed = Vec::new();
    if limits.hinges_as_universal {
        let (o, f, t) = universals_from_hinges(model, tracks, observer, fits, limits)?;
        (observer, fits) = (o, f);
        typed = t;
    }
    accept_in_order(
        model,
        (&mut observer, &mut fits),
        &mut typed,
        |model, k, observer, fits| typing_tried(model, k, observer, fits, limits),
        |trial_model, k, observer, fits| {
            if trial_model.joints[k].joint_type == JointType::Universal {
                universal_by_fit(trial_model, k, tracks, observer, fits, limits)
            } else {
                let types = typing_candidates(trial_model, k, observer);
                type_by_fit(trial_model, k, tracks, fits, types, limits)
            }
        },
    )?;
    let state = FitState::kept(model, observer, fits, made_from, !typed.is_empty());
    Ok((state, typed))
}

/// Whether [`type_joints_by_fit`] tries joint `k`: every universal joint; a spherical joint
/// whose rotations keep near one axis; a multi-DoF joint of low ranks; a freed single-DoF
/// joint.
fn typing_tried(
    model: &Model,
    k: usize,
    observer: &Observer,
    fits: &[FrameFit],
    limits: &TypeByFitLimits,
) -> bool {
    let joint = &model.joints[k];
    if joint.joint_type == JointType::Universal {
        return true;
    }
    let ranks = &joint.ranks;
    // A spherical joint is tried as a hinge whatever its ranks: a hinge has a fixed centre
    // too, and the rank test can take a noisy hinge's rotations for more than one.
    let ball = joint.joint_type == JointType::Spherical;
    if !ball
        && (ranks.rotation > limits.max_rotation_rank
            || ranks.translation > limits.max_translation_rank)
    {
        return false;
    }
    if ball && off_axis_in_std(fits, k).is_none_or(|r| r > limits.max_ball_off_axis_in_std) {
        return false;
    }
    !typing_candidates(model, k, observer).is_empty()
}

/// The types joint `k` is tried as, in order (`true` revolute, `false` prismatic): a freed
/// slide as a slide again before a hinge (see [`type_joints_by_fit`]).
fn typing_candidates(model: &Model, k: usize, observer: &Observer) -> &'static [bool] {
    match model.joints[k].joint_type {
        JointType::Spherical => &[true],
        JointType::MultiDof => &[false, true],
        JointType::Prismatic if observer.freed[k] => &[false, true],
        JointType::Revolute if observer.freed[k] => &[false],
        _ => &[],
    }
}

/// Universal joint `k` typed by the fit, as a ball or a hinge, when that explains the
/// keypoints better: a pair test on per-body poses of a small or often hidden body can take a
/// ball whose third rotation is small for two axes, or a noisy hinge (which fits two
/// intersecting axes too) for a universal joint.
///
/// The joint is first fitted as a ball. With the joint followed, the ball is kept when it
/// lowers the fit's squared residual, in noise variances, by more than `K` plus
/// `min_ball_gain_in_std` times `sqrt(2 K)`, with `K` the frames where the joint has angles:
/// on a true universal joint, whose axes the bundle adjustment has fitted, the ball's extra
/// coordinate gains a chi-square of `K` degrees of freedom. With the joint freed (the fit
/// could not follow it), the ball is kept when the fit follows it and every other joint
/// within `others_max_excess`, the freeing bound.
/// Otherwise, when one of its angles spreads by at most `max_ball_off_axis_in_std` of its
/// standard deviations, a hinge is tried as for a ball joint, from the ball's fit (whose
/// child poses the universal joint's axes do not bend). Returns the new observer and fit
/// when the joint is typed.
fn universal_by_fit(
    model: &mut Model,
    k: usize,
    tracks: &Tracks,
    observer: &Observer,
    fits: &[FrameFit],
    limits: &TypeByFitLimits,
) -> Result<Option<(Observer, Vec<FrameFit>)>> {
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    let this = |p: &usize, c: &usize| *p == parent && *c == child;
    let freed = observer.freed[k];
    let original = (model.joints.clone(), model.warnings.clone());
    make_ball(&mut model.joints[k]);
    model.warnings.retain(
        |w| !matches!(w, Warning::JointNotFollowed { parent: p, child: c, .. } if this(p, c)),
    );
    let trial = Observer::new(model)?;
    let trial_fits = trial.fit_sequence(tracks)?;
    let excess = trial.joint_excess(tracks, &trial_fits)?;
    let keep = if freed {
        !any_above(&excess, limits.others_max_excess)
    } else {
        let frames = fits.iter().filter(|f| f.angles[k].is_some()).count() as f64;
        let sum = |f: &[FrameFit]| f.iter().map(|f| f.sum_sq_m2).sum::<f64>();
        let gain = (sum(fits) - sum(&trial_fits)) / model.noise.sigma_m.powi(2);
        // The extra coordinate of a ball gains a chi-square of `frames` degrees of freedom
        // on a true universal joint: mean `frames`, standard deviation `sqrt(2 frames)`.
        frames > 0.0 && gain > frames + limits.min_ball_gain_in_std * (2.0 * frames).sqrt()
    };
    if keep {
        record_typed_by_fit(model, k, excess[k].unwrap_or(0.0));
        return Ok(Some((trial, trial_fits)));
    }
    if least_angle_spread_in_std(fits, k).is_some_and(|r| r <= limits.max_ball_off_axis_in_std)
        && let Some(found) = type_by_fit(model, k, tracks, &trial_fits, &[true], limits)?
    {
        return Ok(Some(found));
    }
    (model.joints, model.warnings) = original;
    Ok(None)
}

/// Revolute joint `k` typed universal by the fit when a second axis explains the keypoints
/// better: a knuckle's abduction, a fraction of its flexion on a link of 1-2.5 cm, hides in
/// the pair test's rotation vectors, whose universal-joint columns leave a plane as the
/// angles grow. The hinge is fitted as a ball about the point of its axis nearest the
/// child's keypoints; the second axis, fixed in the child and perpendicular to the hinge's
/// at the reference pose, is the direction the ball's relative rotations keep perpendicular
/// to the hinge axis. The universal joint, bundle-adjusted, is kept when it lowers the fit's
/// squared residual, in noise variances, over the `K` frames where both joints have
/// positions, by more than `K` plus `min_universal_gain_in_std` times `sqrt(2 K)`: the hinge
/// is the universal joint with its second angle held at zero, so on a true hinge the extra
/// coordinate gains a chi-square of `K` degrees of freedom; and by at least
/// `min_universal_gain_per_frame` times `K`.
fn universal_from_hinge(
    model: &mut Model,
    k: usize,
    tracks: &Tracks,
    observer: &Observer,
    fits: &[FrameFit],
    limits: &TypeByFitLimits,
) -> Result<Option<(Observer, Vec<FrameFit>)>> {
    let j = &observer.joints[k];
    let Measure::Revolute(axis, pivot) = j.measure else {
        return Ok(None);
    };
    let (parent, child, reference) = (j.parent, j.child, j.reference);
    let shape = &observer.bodies[child].shape;
    if shape.is_empty() {
        return Ok(None);
    }
    let Some(cam_parent) = fits
        .get(model.joints[k].reference_frame)
        .and_then(|f| f.poses.get(parent).copied().flatten())
    else {
        return Ok(None);
    };
    let centroid = shape.iter().map(|(_, p)| p.coords).sum::<Vector3<f64>>() / shape.len() as f64;
    let seen = reference * Point3::from(centroid);
    let centre = pivot + axis * axis.dot(&(seen - pivot));
    let original = (model.joints.clone(), model.warnings.clone());
    let arr = |v: Vector3<f64>| [v.x, v.y, v.z];
    // Field by field, not through `store_centred_joint`: its reference pose, carried through
    // an isometry, would change in the last bits, and the fits downstream with it.
    make_ball(&mut model.joints[k]);
    model.joints[k].point_in_parent = Some(arr(centre.coords));
    model.joints[k].point = Some(arr((cam_parent * centre).coords));
    let ball = Observer::new(model)?;
    let ball_fits = ball.fit_sequence(tracks)?;
    // Perpendicular to the hinge axis at the reference pose, the second axis stays so as the
    // child turns: `axis . turn b = 0` in every frame.
    let mut scatter = axis * axis.transpose();
    for f in &ball_fits {
        let (Some(p), Some(c)) = (
            f.poses.get(parent).copied().flatten(),
            f.poses.get(child).copied().flatten(),
        ) else {
            continue;
        };
        let turn = ((p.inverse() * c).rotation * reference.rotation.inverse()).to_rotation_matrix();
        let row = turn.matrix().transpose() * axis;
        scatter += row * row.transpose();
    }
    let e = scatter.symmetric_eigen();
    let second = e.eigenvectors.column(e.eigenvalues.imin()).into_owned();
    {
        let joint = &mut model.joints[k];
        joint.joint_type = JointType::Universal;
        joint.dof = 2;
        joint.axis_in_parent = Some(arr(axis));
        joint.axis = Some(arr(cam_parent.rotation * axis));
        joint.second_axis_in_parent = Some(arr(second));
        joint.second_axis = Some(arr(cam_parent.rotation * second));
    }
    let mut trial = Observer::new(model)?;
    let mut trial_fits = trial.fit_sequence(tracks)?;
    if let Some(adjusted) = adjust_model(model, &trial, tracks, &trial_fits, &limits.bundle, None)?
    {
        (trial, trial_fits) = adjusted;
    }
    // Over the frames where both joints have positions: where the universal joint's angles
    // are undetermined, the fit leaves its child's points looser than the hinge did.
    let (mut frames, mut gain) = (0.0, 0.0);
    for (u, h) in trial_fits.iter().zip(fits) {
        if u.angles[k].is_some() && h.positions[k].is_some() {
            frames += 1.0;
            gain += h.sum_sq_m2 - u.sum_sq_m2;
        }
    }
    let gain = gain / model.noise.sigma_m.powi(2);
    let excess = trial.joint_excess(tracks, &trial_fits)?;
    let z = (gain - frames) / (2.0 * frames).sqrt();
    if frames > 0.0
        && z > limits.min_universal_gain_in_std
        && gain >= limits.min_universal_gain_per_frame * frames
        && !any_above(&excess, limits.others_max_excess)
    {
        record_typed_by_fit(model, k, excess[k].unwrap_or(0.0));
        return Ok(Some((trial, trial_fits)));
    }
    (model.joints, model.warnings) = original;
    Ok(None)
}

/// How much better a ball about hinge `k`'s pivot places the child's keypoints than the
/// hinge does, in noise variances per frame, each frame on the parent's pose in `fits`: the
/// best hinge angle in closed form, the best rotation about the pivot by Kabsch on the
/// keypoints about the pivot (no centring). A true hinge
/// gains a chi-square of two degrees of freedom a frame, a universal joint its second angle
/// too. `None` when no frame shows three of the child's keypoints with the parent posed.
fn local_ball_gain_per_frame(
    observer: &Observer,
    k: usize,
    tracks: &Tracks,
    fits: &[FrameFit],
) -> Option<f64> {
    let j = &observer.joints[k];
    let Measure::Revolute(axis, pivot) = j.measure else {
        return None;
    };
    // The child's keypoints about the pivot at joint position zero, in the parent's frame.
    let at_rest: Vec<(usize, Vector3<f64>)> = observer.bodies[j.child]
        .shape
        .iter()
        .map(|(i, s)| (*i, (j.reference * s) - pivot))
        .collect();
    let (mut frames, mut gain) = (0.0_f64, 0.0_f64);
    for (t, f) in fits.iter().enumerate() {
        let Some(parent) = f.poses.get(j.parent).copied().flatten() else {
            continue;
        };
        let to_parent = parent.inverse();
        let mut cross = Matrix3::zeros();
        // `sum b . turn(theta) a = along + across cos(theta) + turned sin(theta)`.
        let (mut along, mut across, mut turned, mut seen) = (0.0, 0.0, 0.0, 0);
        for (i, a) in &at_rest {
            let Some(z) = tracks.get(t, *i) else {
                continue;
            };
            let b = (to_parent * z) - pivot;
            cross += a * b.transpose();
            let on_axis = axis.dot(a) * axis.dot(&b);
            along += on_axis;
            across += a.dot(&b) - on_axis;
            turned += axis.cross(a).dot(&b);
            seen += 1;
        }
        if seen < 3 {
            continue;
        }
        let hinge = along + across.hypot(turned);
        let Some(turn) = kinetree_core::geom::kabsch_rotation_by_svd(&cross, 0.0) else {
            continue;
        };
        let ball = (turn * cross).trace();
        frames += 1.0;
        gain += 2.0 * (ball - hinge).max(0.0);
    }
    (frames > 0.0).then(|| gain / observer.sigma.powi(2) / frames)
}

/// The hinges of `model` typed universal by [`universal_from_hinge`], parents first (the
/// joints are in tree order), each on the fit the typings before it left: a parent's missed
/// second axis shows in its children's fit too.
///
/// A hinge whose ball places its child no better than `universal_screen_per_frame` noise
/// variances per frame ([`local_ball_gain_per_frame`]) is not tried: a trial costs two fits
/// of every frame and a bundle adjustment.
fn universals_from_hinges(
    model: &mut Model,
    tracks: &Tracks,
    mut observer: Observer,
    mut fits: Vec<FrameFit>,
    limits: &TypeByFitLimits,
) -> Result<(Observer, Vec<FrameFit>, Vec<usize>)> {
    let mut typed = Vec::new();
    for k in 0..observer.joints.len() {
        if model.joints[k].joint_type != JointType::Revolute
            || observer.freed[k]
            || !matches!(observer.joints[k].measure, Measure::Revolute(..))
        {
            continue;
        }
        if local_ball_gain_per_frame(&observer, k, tracks, &fits)
            .is_none_or(|g| g < limits.universal_screen_per_frame)
        {
            continue;
        }
        let mut trial_model = model.clone();
        if let Some((o, f)) =
            universal_from_hinge(&mut trial_model, k, tracks, &observer, &fits, limits)?
        {
            *model = trial_model;
            (observer, fits) = (o, f);
            typed.push(k);
        }
    }
    Ok((observer, fits, typed))
}

/// Makes `joint` a ball to be fitted: no axes, no coordinates, typed by the fit (its centre
/// stays where it is).
fn make_ball(joint: &mut kinetree_core::model::Joint) {
    joint.joint_type = JointType::Spherical;
    joint.dof = 3;
    joint.fit = JointFit::TypedByFit;
    (joint.axis, joint.axis_in_parent) = (None, None);
    clear_coordinates(joint);
}

/// Records in `model`'s warnings that the fit typed joint `k` as it now stands, with its
/// excess in noise variances.
fn record_typed_by_fit(model: &mut Model, k: usize, excess_in_sigma2: f64) {
    let j = &model.joints[k];
    let warning = Warning::JointTypedByFit {
        parent: j.parent,
        child: j.child,
        joint_type: j.joint_type,
        excess_in_sigma2,
    };
    model.warnings.push(warning);
}

/// Whether any joint's excess is above `bound` (a joint the fit no longer follows).
pub(crate) fn any_above(excess: &[Option<f64>], bound: f64) -> bool {
    excess.iter().any(|e| e.is_some_and(|e| e > bound))
}

/// Drops what a joint typed anew no longer has: a universal joint's second axis and every
/// coordinate of more than one (the fit writes the new type's).
pub(crate) fn clear_coordinates(joint: &mut kinetree_core::model::Joint) {
    (joint.second_axis, joint.second_axis_in_parent) = (None, None);
    for coordinates in [
        &mut joint.coordinates,
        &mut joint.coordinate_std,
        &mut joint.smoothed_coordinates,
        &mut joint.smoothed_coordinate_std,
    ] {
        coordinates.clear();
    }
}

/// How far spherical joint `k`'s fitted rotation vectors (`fits`) stray from the line through
/// zero that fits them best (a hinge's lie on it): the RMS over frames of the distance from
/// it in units of each frame's rotation standard deviation (the mean of its three axes').
/// `None` with fewer than three frames.
fn off_axis_in_std(fits: &[FrameFit], k: usize) -> Option<f64> {
    let seen: Vec<(Vector3<f64>, f64)> = fits
        .iter()
        .filter_map(|f| {
            let v = Vector3::from(f.rotations.get(k).copied().flatten()?);
            let s = f.rotation_std.get(k).copied().flatten()?;
            let var = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) / 3.0;
            (var > 0.0 && var.is_finite()).then_some((v, var))
        })
        .collect();
    if seen.len() < 3 {
        return None;
    }
    let scatter: Matrix3<f64> = seen.iter().map(|(v, w)| v * v.transpose() / *w).sum();
    let e = scatter.symmetric_eigen();
    let axis = e.eigenvectors.column(e.eigenvalues.imax()).into_owned();
    let off: f64 = seen
        .iter()
        .map(|(v, w)| (v - axis * axis.dot(v)).norm_squared() / w)
        .sum();
    Some((off / seen.len() as f64).sqrt())
}

/// How little universal joint `k` turns about one of its axes: the smaller over its two angles
/// of their RMS spread about their mean over the frames (`fits`), in units of each frame's
/// standard deviation of that angle (a hinge's other angle stays within noise). `None` with
/// fewer than three frames.
fn least_angle_spread_in_std(fits: &[FrameFit], k: usize) -> Option<f64> {
    let seen: Vec<([f64; 2], [f64; 2])> = fits
        .iter()
        .filter_map(|f| {
            Some((
                f.angles.get(k).copied().flatten()?,
                f.angle_std.get(k).copied().flatten()?,
            ))
        })
        .filter(|(_, s)| s.iter().all(|&v| v > 0.0 && v.is_finite()))
        .collect();
    if seen.len() < 3 {
        return None;
    }
    (0..2)
        .map(|i| {
            let mean = seen.iter().map(|(a, _)| a[i]).sum::<f64>() / seen.len() as f64;
            let z2: f64 = seen
                .iter()
                .map(|(a, s)| ((a[i] - mean) / s[i]).powi(2))
                .sum();
            (z2 / seen.len() as f64).sqrt()
        })
        .reduce(f64::min)
}

/// Writes the fit into `model`: every followed or freed joint's positions (multi-DoF ones keep
/// theirs) with its reference pose turned (or slid) to its position at the joint's reference
/// frame, so the positions stay zero there; the positions' precision and their smoothing;
/// every joint's observed range. Returns the fit's RMS residual in units of the model's noise
/// level (`None` with no usable frame).
///
/// # Errors
/// [`kinetree_core::Error::Shape`] when `state` is not the fit of `model`; the smoothing's
/// errors.
pub fn write_positions(model: &mut Model, state: &FitState) -> Result<Option<f64>> {
    if !state.is_of(model) {
        return Err(kinetree_core::Error::Shape {
            expected: "the whole-tree fit of this model".into(),
            found: "the fit of another model".into(),
        });
    }
    let (observer, fits) = (&state.observer, &state.fits);
    for (k, joint) in model.joints.iter_mut().enumerate() {
        let j = &observer.joints[k];
        if let Measure::Spherical(centre) = j.measure {
            write_rotations(joint, k, &centre, j.reference, fits, &model.position_limits)?;
            continue;
        }
        if let Measure::Universal(..) = j.measure {
            write_angles(joint, k, j, fits, &model.position_limits)?;
            continue;
        }
        // Joints in the fit and freed ones (from the fitted poses); multi-DoF ones keep the
        // positions they came with.
        if !matches!(j.measure, Measure::None) {
            let mut column: Vec<Option<f64>> = fits.iter().map(|f| f.positions[k]).collect();
            if let Some(zero) = column.get(joint.reference_frame).copied().flatten() {
                let turned = Observer::joint_transform(j, zero);
                joint.reference_pose = Some(RigidTransform::from_isometry(&turned));
                for v in column.iter_mut().flatten() {
                    *v -= zero;
                }
            }
            joint.positions = column;
        }
        joint.position_std = fits
            .iter()
            .zip(&joint.positions)
            .map(|(f, q)| q.and(f.std[k]))
            .collect();
        (joint.smoothed_positions, joint.smoothed_std) = crate::smooth::smooth_fitted_positions(
            &joint.positions,
            &joint.position_std,
            joint.joint_type != JointType::Prismatic,
            &model.position_limits,
        )?;
        joint.range = span(joint.positions.iter().flatten().copied());
    }
    Ok(rms_in_sigma(fits, model.noise.sigma_m))
}

/// Writes every joint's precision into `model` ([`Joint::axis_std_deg`],
/// [`Joint::pivot_std_m`], [`Joint::centre_std_m`], [`Joint::second_axis_std_deg`]): the
/// Cramér-Rao bound of the followed joints from the whole-tree fit `state` of `tracks`
/// (`crate::bundle::joint_precision`); null for the others.
///
/// [`Joint::axis_std_deg`]: kinetree_core::model::Joint::axis_std_deg
/// [`Joint::pivot_std_m`]: kinetree_core::model::Joint::pivot_std_m
/// [`Joint::centre_std_m`]: kinetree_core::model::Joint::centre_std_m
/// [`Joint::second_axis_std_deg`]: kinetree_core::model::Joint::second_axis_std_deg
///
/// # Errors
/// [`kinetree_core::Error::Shape`] when `state` is not the fit of `model` or the tracks do not
/// match it.
pub fn write_joint_precision(model: &mut Model, state: &FitState, tracks: &Tracks) -> Result<()> {
    if !state.is_of(model) {
        return Err(kinetree_core::Error::Shape {
            expected: "the whole-tree fit of this model".into(),
            found: "the fit of another model".into(),
        });
    }
    let precision = crate::bundle::joint_precision(&state.observer, tracks, &state.fits)?;
    for (joint, p) in model.joints.iter_mut().zip(precision) {
        let p = p.unwrap_or_default();
        joint.axis_std_deg = p.axis_std_rad.map(f64::to_degrees);
        joint.pivot_std_m = p.pivot_std_m;
        joint.centre_std_m = p.centre_std_m;
        joint.second_axis_std_deg = p.second_axis_std_rad.map(f64::to_degrees);
    }
    Ok(())
}

/// [`write_positions`] for spherical joint `k`: its rotation vectors, re-zeroed at the
/// joint's reference frame (the reference pose turned about the centre by that frame's
/// rotation), their standard deviations, each coordinate smoothed on its own, and the range
/// of the rotation angle.
fn write_rotations(
    joint: &mut kinetree_core::model::Joint,
    k: usize,
    centre: &Point3<f64>,
    reference: Isometry3<f64>,
    fits: &[FrameFit],
    limits: &kinetree_core::model::PositionLimits,
) -> Result<()> {
    let turn = |v: [f64; 3]| UnitQuaternion::from_scaled_axis(Vector3::from(v));
    let mut rotations: Vec<Option<UnitQuaternion<f64>>> =
        fits.iter().map(|f| f.rotations[k].map(turn)).collect();
    if let Some(zero) = rotations.get(joint.reference_frame).copied().flatten() {
        let about = kinetree_core::nalgebra::Translation3::from(centre.coords);
        let turned = about * zero * about.inverse() * reference;
        joint.reference_pose = Some(RigidTransform::from_isometry(&turned));
        for r in rotations.iter_mut().flatten() {
            *r *= zero.inverse();
        }
    }
    joint.coordinates = rotations
        .iter()
        .map(|r| {
            r.map(|r| {
                let v = r.scaled_axis();
                vec![v.x, v.y, v.z]
            })
        })
        .collect();
    joint.coordinate_std = fits
        .iter()
        .zip(&joint.coordinates)
        .map(|(f, c)| c.as_ref().and(f.rotation_std[k]).map(|s| s.to_vec()))
        .collect();
    smooth_coordinates(joint, 3, limits)?;
    joint.range = span(rotations.iter().flatten().map(|r| r.angle()));
    Ok(())
}

/// [`write_positions`] for universal joint `k` (`j` in the observer): its two angles,
/// re-zeroed at the joint's reference frame (the reference pose turned by that frame's
/// angles, and the second axis with it), their standard deviations, each smoothed on its own,
/// and the range of the rotation angle.
fn write_angles(
    joint: &mut kinetree_core::model::Joint,
    k: usize,
    j: &crate::solver::ObservedJoint,
    fits: &[FrameFit],
    limits: &kinetree_core::model::PositionLimits,
) -> Result<()> {
    let Measure::Universal(first, second, _) = j.measure else {
        return Ok(());
    };
    let turn = |axis: Vector3<f64>, q: f64| {
        UnitQuaternion::from_axis_angle(&kinetree_core::nalgebra::Unit::new_normalize(axis), q)
    };
    // The second axis where the (re-zeroed) reference pose holds it.
    let mut second_now = second;
    let mut angles: Vec<Option<[f64; 2]>> = fits.iter().map(|f| f.angles[k]).collect();
    if let Some([q1, q2]) = angles.get(joint.reference_frame).copied().flatten() {
        let turned = Observer::universal_transform(j, q1, q2);
        joint.reference_pose = Some(RigidTransform::from_isometry(&turned));
        // The second axis, fixed in the child, turns with the first angle; in the camera
        // frame about the first axis there.
        second_now = turn(first, q1) * second;
        joint.second_axis_in_parent = Some([second_now.x, second_now.y, second_now.z]);
        if let (Some(a), Some(b)) = (joint.axis, joint.second_axis) {
            let moved = turn(Vector3::from(a), q1) * Vector3::from(b);
            joint.second_axis = Some([moved.x, moved.y, moved.z]);
        }
        for v in angles.iter_mut().flatten() {
            *v = [v[0] - q1, v[1] - q2];
        }
    }
    joint.coordinates = angles.iter().map(|a| a.map(|a| a.to_vec())).collect();
    joint.coordinate_std = fits
        .iter()
        .zip(&joint.coordinates)
        .map(|(f, c)| c.as_ref().and(f.angle_std[k]).map(|s| s.to_vec()))
        .collect();
    smooth_coordinates(joint, 2, limits)?;
    // The angle of the whole rotation from the reference pose, as for a ball joint.
    joint.range = span(
        angles
            .iter()
            .flatten()
            .map(|&[q1, q2]| (turn(first, q1) * turn(second_now, q2)).angle()),
    );
    Ok(())
}

/// Each of the first `width` coordinates of `joint` smoothed on its own (as the positions of
/// a revolute joint, all of them angles), into its smoothed coordinates; its scalar
/// positions emptied.
fn smooth_coordinates(
    joint: &mut kinetree_core::model::Joint,
    width: usize,
    limits: &kinetree_core::model::PositionLimits,
) -> Result<()> {
    let n = joint.coordinates.len();
    let mut smoothed = vec![Some(Vec::new()); n];
    let mut smoothed_std = vec![Some(Vec::new()); n];
    for i in 0..width {
        let column: Vec<Option<f64>> = joint
            .coordinates
            .iter()
            .map(|c| c.as_ref().map(|c| c[i]))
            .collect();
        let std: Vec<Option<f64>> = joint
            .coordinate_std
            .iter()
            .map(|c| c.as_ref().map(|c| c[i]))
            .collect();
        let (values, deviations) =
            crate::smooth::smooth_fitted_positions(&column, &std, true, limits)?;
        for (t, (v, d)) in values.iter().zip(&deviations).enumerate() {
            for (out, x) in [(&mut smoothed[t], v), (&mut smoothed_std[t], d)] {
                *out = match (out.take(), x) {
                    (Some(mut o), Some(x)) => {
                        o.push(*x);
                        Some(o)
                    }
                    _ => None,
                };
            }
        }
    }
    joint.smoothed_coordinates = smoothed;
    joint.smoothed_coordinate_std = smoothed_std;
    joint.positions = vec![None; n];
    joint.position_std = vec![None; n];
    joint.smoothed_positions = vec![None; n];
    joint.smoothed_std = vec![None; n];
    Ok(())
}

/// `[min, max]` of `values`, `None` when there are none.
fn span(values: impl Iterator<Item = f64>) -> Option<[f64; 2]> {
    values.fold(None, |acc, v| match acc {
        None => Some([v, v]),
        Some([lo, hi]) => Some([lo.min(v), hi.max(v)]),
    })
}

/// Bundle-adjusts the joints `observer` (built from `model`; `known` is its fit of `tracks`)
/// follows ([`crate::bundle`]; with `only`, those of them in it) and writes them into
/// `model`; returns the observer rebuilt from the model and its fit, or `None` (the model
/// unchanged) when the adjustment changed nothing.
pub(crate) fn adjust_model(
    model: &mut Model,
    observer: &Observer,
    tracks: &Tracks,
    known: &[FrameFit],
    limits: &BundleLimits,
    only: Option<&[usize]>,
) -> Result<Option<(Observer, Vec<FrameFit>)>> {
    let Some(adjusted) = crate::bundle::adjust(observer, tracks, known, limits, only)? else {
        return Ok(None);
    };
    // The joints are stored against their parents' poses at their reference frames, so only
    // those frames are fitted here, each from its known fit; the whole sequence is fitted once,
    // with the stored joints, below.
    let mut at_reference: BTreeMap<usize, FrameFit> = BTreeMap::new();
    for (k, j) in model.joints.iter().enumerate() {
        let r = j.reference_frame;
        if adjusted.joint_col[k].is_none()
            || r >= tracks.n_frames()
            || at_reference.contains_key(&r)
        {
            continue;
        }
        at_reference.insert(r, adjusted.fit(&tracks.frame_points(r), known.get(r))?);
    }
    for (k, j) in adjusted.joints.iter().enumerate() {
        if adjusted.joint_col[k].is_none() {
            continue;
        }
        let Some(cam_parent) = at_reference
            .get(&model.joints[k].reference_frame)
            .and_then(|f| f.poses.get(j.parent).copied().flatten())
        else {
            continue;
        };
        if let Some(params) = crate::refine::JointParams::of(j) {
            store_joint(&mut model.joints[k], &params, &cam_parent);
        } else {
            store_centred_joint(&mut model.joints[k], j, &cam_parent);
        }
    }
    let observer = Observer::new(model)?;
    let fits = observer.fit_sequence(tracks)?;
    Ok(Some((observer, fits)))
}

/// Types joint `k` of `model` (multi-DoF, or single-DoF and not followed) by the whole-tree
/// fit `fits`: a candidate of each type of `revolute` in turn ([`candidate_joint`] on the
/// fitted relative poses) is refined as a freed joint is ([`refine_joint`]) and every joint
/// bundle-adjusted with it (after [`near_enough`]'s screen, from its adjustment of the joints
/// next to the candidate); the first the fit follows closely (its excess within
/// `limits`, every other joint's within its bound) is kept, with a
/// `joint_typed_by_fit` warning in place of the `multi_dof_joint` or `joint_not_followed`
/// one. Returns the new observer and fits, or `None` (the model unchanged) when none is
/// followed. For a multi-DoF joint the slide comes first: a hinge about a distant pivot
/// approximates a slide with two more parameters, and fitted a true slide better (a 3.1 cm,
/// 4-point slider at 1.5 mm of noise: excess 4.6 as a slide against 7.3 as a hinge;
/// `docs/decisions.md`, `type_by_fit.max_excess`).
fn type_by_fit(
    model: &mut Model,
    k: usize,
    tracks: &Tracks,
    fits: &[FrameFit],
    revolute: &[bool],
    limits: &TypeByFitLimits,
) -> Result<Option<(Observer, Vec<FrameFit>)>> {
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    let this = |p: &usize, c: &usize| *p == parent && *c == child;
    let relative: Vec<Option<Isometry3<f64>>> = fits
        .iter()
        .map(|f| {
            let p = f.poses.get(parent).copied().flatten()?;
            let c = f.poses.get(child).copied().flatten()?;
            Some(p.inverse() * c)
        })
        .collect();
    let reference = model.joints[k].reference_frame;
    let original = (model.joints.clone(), model.warnings.clone());
    let Some(cam_parent) = fits
        .get(reference)
        .and_then(|f| f.poses.get(parent).copied().flatten())
    else {
        return Ok(None);
    };
    for &revolute in revolute {
        let Some(start) = candidate_joint(&relative, reference, revolute) else {
            continue;
        };
        (model.joints, model.warnings) = original.clone();
        // Put back into the fit; its warning no longer holds.
        model.joints[k].fit = JointFit::TypedByFit;
        model.warnings.retain(
            |w| !matches!(w, Warning::JointNotFollowed { parent: p, child: c, .. } if this(p, c)),
        );
        model.joints[k].joint_type = if revolute {
            JointType::Revolute
        } else {
            JointType::Prismatic
        };
        model.joints[k].dof = 1;
        clear_coordinates(&mut model.joints[k]);
        store_joint(&mut model.joints[k], &start, &cam_parent);
        let mut freed = Observer::new(model)?;
        freed.free_joint(k);
        if !refine_joint(model, k, &freed, tracks, fits) {
            continue;
        }
        let mut trial = Observer::new(model)?;
        let mut trial_fits = trial.fit_sequence(tracks)?;
        let unadjusted = trial.joint_excess(tracks, &trial_fits)?;
        // A candidate without an excess (its child never shows three points where the fit
        // poses it) gets none from an adjustment either, so it cannot be kept.
        if unadjusted[k].is_none_or(|e| e > limits.max_excess_to_adjust) {
            continue;
        }
        // The adjustment of every joint continues from the screen's: the joints near the
        // candidate, which the screen has adjusted, have most of the gain.
        let mut current = unadjusted;
        if limits.screen_locally {
            match near_enough(model, k, tracks, &trial, &trial_fits, limits)? {
                Screen::Dropped => continue,
                Screen::Passed(None) => {}
                Screen::Passed(Some(screened)) => {
                    model.joints = screened.joints;
                    (trial, trial_fits, current) =
                        (screened.observer, screened.fits, screened.excess);
                }
            }
        }
        let excess = match adjust_model(model, &trial, tracks, &trial_fits, &limits.bundle, None)? {
            Some(adjusted) => {
                (trial, trial_fits) = adjusted;
                trial.joint_excess(tracks, &trial_fits)?
            }
            None => current,
        };
        let Some(own) = excess[k].filter(|&e| e <= limits.max_excess) else {
            continue;
        };
        if any_above(&excess, limits.others_max_excess) {
            continue;
        }
        model.warnings.retain(
            |w| !matches!(w, Warning::MultiDofJoint { parent: p, child: c, .. } if this(p, c)),
        );
        record_typed_by_fit(model, k, own);
        return Ok(Some((trial, trial_fits)));
    }
    (model.joints, model.warnings) = original;
    Ok(None)
}

/// The outcome of [`near_enough`]'s screen of a typing candidate.
enum Screen {
    /// The candidate's excess after the local adjustment is above `max_local_excess`.
    Dropped,
    /// The candidate passes, with the local adjustment (`None` when it changed nothing).
    Passed(Option<Box<Screened>>),
}

/// A typing candidate after [`near_enough`]'s local adjustment.
struct Screened {
    /// The model's joints, those near the candidate adjusted.
    joints: Vec<kinetree_core::model::Joint>,
    /// The observer built from them.
    observer: Observer,
    /// Its fit of the tracks.
    fits: Vec<FrameFit>,
    /// Every joint's excess in that fit.
    excess: Vec<Option<f64>>,
}

/// The screen of [`type_by_fit`] on candidate joint `k` of `model` (fitted by `trial` as
/// `fits`): the candidate passes when its excess after a bundle adjustment of only the joints
/// that share a body with it is within `max_local_excess`, or when that adjustment changes
/// nothing. Such an adjustment costs a fraction of one of every joint, and over every sweep it
/// put a candidate's excess at 0.29-6.2 times (median 1.005) where the adjustment of every
/// joint put it, every kept candidate's at most 4.1 (`docs/decisions.md`,
/// `type_by_fit.max_local_excess`).
fn near_enough(
    model: &Model,
    k: usize,
    tracks: &Tracks,
    trial: &Observer,
    fits: &[FrameFit],
    limits: &TypeByFitLimits,
) -> Result<Screen> {
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    let near: Vec<usize> = (0..model.joints.len())
        .filter(|&x| {
            let j = &model.joints[x];
            [j.parent, j.child]
                .iter()
                .any(|&b| b == parent || b == child)
        })
        .collect();
    let mut screened = model.clone();
    let Some((observer, screened_fits)) = adjust_model(
        &mut screened,
        trial,
        tracks,
        fits,
        &limits.bundle,
        Some(&near),
    )?
    else {
        return Ok(Screen::Passed(None));
    };
    let excess = observer.joint_excess(tracks, &screened_fits)?;
    Ok(if excess[k].is_none_or(|e| e <= limits.max_local_excess) {
        Screen::Passed(Some(Box::new(Screened {
            joints: screened.joints,
            observer,
            fits: screened_fits,
            excess,
        })))
    } else {
        Screen::Dropped
    })
}

/// A single-DoF joint's parameters (in the parent's frame) fitted to relative poses
/// `parent_from_child` by frame, zero at frame `reference`: revolute, the principal direction
/// of the rotation vectors from the reference pose and the pivot solving
/// `(I - R_t) p = t_t - R_t t_ref` in least squares (its component along the axis set to
/// zero); prismatic, the principal direction of the translations. `None` without the
/// reference pose or with fewer than three other frames.
fn candidate_joint(
    relative: &[Option<Isometry3<f64>>],
    reference: usize,
    revolute: bool,
) -> Option<crate::refine::JointParams> {
    let zero = relative.get(reference).copied().flatten()?;
    let others: Vec<&Isometry3<f64>> = relative.iter().flatten().collect();
    if others.len() < 4 {
        return None;
    }
    let principal = |v: &[Vector3<f64>]| {
        let mean = v.iter().sum::<Vector3<f64>>() / v.len() as f64;
        let scatter: Matrix3<f64> = v.iter().map(|x| (x - mean) * (x - mean).transpose()).sum();
        let e = scatter.symmetric_eigen();
        let axis = e.eigenvectors.column(e.eigenvalues.imax()).into_owned();
        (axis.norm() > 0.0).then(|| axis.normalize())
    };
    if !revolute {
        let t: Vec<Vector3<f64>> = others.iter().map(|x| x.translation.vector).collect();
        return Some(crate::refine::JointParams {
            axis: principal(&t)?,
            pivot: Point3::origin(),
            reference: zero,
            revolute: false,
        });
    }
    // Rotations relative to the reference, in the parent's frame: R_t = X_t.R * zero.R^-1.
    let turns: Vec<UnitQuaternion<f64>> = others
        .iter()
        .map(|x| x.rotation * zero.rotation.inverse())
        .collect();
    let vectors: Vec<Vector3<f64>> = turns.iter().map(|r| r.scaled_axis()).collect();
    let axis = principal(&vectors)?;
    let (mut a, mut b) = (Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
    for (x, r) in others.iter().zip(&turns) {
        let m = Matrix3::identity() - r.to_rotation_matrix().into_inner();
        let rhs = x.translation.vector - r * zero.translation.vector;
        a += m.transpose() * m;
        b += m.transpose() * rhs;
    }
    // The pivot is free along the axis: a small ridge picks the point nearest the origin.
    let ridge = 1e-9 * a.trace().max(f64::MIN_POSITIVE);
    let pivot = (a + Matrix3::identity() * ridge).try_inverse()? * b;
    Some(crate::refine::JointParams {
        axis,
        pivot: Point3::from(pivot),
        reference: zero,
        revolute: true,
    })
}

/// Default of [`TypeByFitLimits::max_excess`] (`docs/decisions.md`,
/// `type_by_fit.max_excess`).
const TYPE_EXCESS: f64 = 3.0;

/// Default of [`TypeByFitLimits::max_excess_to_adjust`] (`docs/decisions.md`,
/// `type_by_fit.max_excess_to_adjust`).
const TYPE_EXCESS_TO_ADJUST: f64 = 1000.0;

/// Default of [`TypeByFitLimits::max_local_excess`] (`docs/decisions.md`,
/// `type_by_fit.max_local_excess`).
const LOCAL_EXCESS: f64 = 9.0;

/// Default of [`TypeByFitLimits::max_ball_off_axis_in_std`] (`docs/decisions.md`,
/// `type_by_fit.max_ball_off_axis_in_std`).
const BALL_OFF_AXIS: f64 = 20.0;

/// Default of [`TypeByFitLimits::min_ball_gain_in_std`] (`docs/decisions.md`,
/// `type_by_fit.min_ball_gain_in_std`).
const BALL_GAIN_IN_STD: f64 = 5.0;

/// [`TypeByFitLimits::min_universal_gain_per_frame`]'s default.
const UNIVERSAL_GAIN_PER_FRAME: f64 = 5.0;

/// [`TypeByFitLimits::universal_screen_per_frame`]'s default.
const UNIVERSAL_SCREEN_PER_FRAME: f64 = 2.5;

/// Default bound of [`readmit_freed_joints`] (`docs/decisions.md`,
/// `readmit_joints.max_excess`).
const READMIT_EXCESS: f64 = 10.0;

/// Refines joint `k` of `model` against its child's keypoints over all frames, the parent
/// posed by `fits` (the whole-tree fit of `observer`, built from `model`): see
/// [`crate::refine`]. The joint's axis, pivot and reference pose are replaced when the fit
/// lowers the child's residual; its camera-frame axis and point follow from the parent's
/// fitted pose at the joint's reference frame (the joint is left alone where that pose is
/// unknown, or when it is not single-DoF). Returns whether the joint changed.
fn refine_joint(
    model: &mut Model,
    k: usize,
    observer: &Observer,
    tracks: &Tracks,
    fits: &[FrameFit],
) -> bool {
    let j = &observer.joints[k];
    let Some(start) = crate::refine::JointParams::of(j) else {
        return false;
    };
    let Some(cam_parent) = fits
        .get(model.joints[k].reference_frame)
        .and_then(|f| f.poses.get(j.parent).copied().flatten())
    else {
        return false;
    };
    let frames: Vec<crate::refine::FramePoints> = fits
        .iter()
        .enumerate()
        .map(|(t, f)| {
            let Some(parent) = f.poses.get(j.parent).copied().flatten() else {
                return Vec::new();
            };
            observer.bodies[j.child]
                .shape
                .iter()
                .filter_map(|&(i, s)| {
                    let o = tracks.get(t, i)?;
                    Some((s, parent.inverse_transform_point(&o)))
                })
                .collect()
        })
        .collect();
    let Some((refined, before, after)) = crate::refine::refine(&start, &frames) else {
        return false;
    };
    if after.partial_cmp(&before) != Some(std::cmp::Ordering::Less) {
        return false;
    }
    store_joint(&mut model.joints[k], &refined, &cam_parent);
    true
}

/// Writes refined parameters into a model joint: its axis, pivot and reference pose in the
/// parent's frame, and its camera-frame axis and point through `cam_parent` (the parent's
/// `camera_from_body` at the joint's reference frame).
pub(crate) fn store_joint(
    joint: &mut kinetree_core::model::Joint,
    refined: &crate::refine::JointParams,
    cam_parent: &Isometry3<f64>,
) {
    let arr = |v: Vector3<f64>| [v.x, v.y, v.z];
    joint.axis_in_parent = Some(arr(refined.axis));
    joint.axis = Some(arr(cam_parent.rotation * refined.axis));
    if refined.revolute {
        joint.point_in_parent = Some(arr(refined.pivot.coords));
        joint.point = Some(arr((cam_parent * refined.pivot).coords));
    }
    joint.reference_pose = Some(RigidTransform::from_isometry(&refined.reference));
}

/// Writes a ball or universal joint's parameters `j` (in the parent's frame) into `joint`,
/// and into the camera frame through `cam_parent`, the parent's pose at the joint's reference
/// frame; other joints are left alone.
fn store_centred_joint(
    joint: &mut kinetree_core::model::Joint,
    j: &crate::solver::ObservedJoint,
    cam_parent: &Isometry3<f64>,
) {
    let arr = |v: Vector3<f64>| [v.x, v.y, v.z];
    let centre = match j.measure {
        Measure::Spherical(centre) => centre,
        Measure::Universal(first, second, centre) => {
            joint.axis_in_parent = Some(arr(first));
            joint.axis = Some(arr(cam_parent.rotation * first));
            joint.second_axis_in_parent = Some(arr(second));
            joint.second_axis = Some(arr(cam_parent.rotation * second));
            centre
        }
        _ => return,
    };
    joint.point_in_parent = Some(arr(centre.coords));
    joint.point = Some(arr((cam_parent * centre).coords));
    joint.reference_pose = Some(RigidTransform::from_isometry(&j.reference));
}

/// A joint whose [`Observer::joint_excess`] is above this is freed by
/// [`fit_model_positions`]. On 200 random mechanisms the largest excess of a model was under
/// 4 in nine of ten and 10-30 where a joint's pivot was a few centimetres off; joints the
/// model gets wrong reach 50-200. Freeing at 9 instead also freed joints whose neighbour's
/// pivot was off, which then gave worse positions than the fit through the joint.
pub const MAX_JOINT_EXCESS: f64 = 30.0;
