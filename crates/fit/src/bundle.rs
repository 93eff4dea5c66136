//! Bundle adjustment of a model's joints: every followed joint's axes, pivot or centre and
//! reference pose, with every frame's configuration (the root's pose, the joint coordinates
//! and the poses of freely posed bodies), fitted to all keypoints of all frames at once.
//!
//! [`crate::refine`] fits one joint at a time on its child's points with the rest of the tree
//! held where the last whole-tree fit put it. The frame's fit then moves the root and the
//! other joints to absorb what the joint no longer explains, and a round of such steps can
//! raise the tree's residual; on random mechanisms at 1 mm of noise the rounds stopped with
//! prismatic axes 0.4-1.5 deg off where the true parent poses give 0.02-0.1 deg. Here every
//! joint's parameters and every frame's are one least-squares problem: damped Gauss-Newton on
//! the joints' parameters with the frames' parameters eliminated (a Schur complement, as in
//! photogrammetric bundle adjustment), each frame then refitted exactly to the new joints
//! (variable projection), a step kept only when the total residual falls.
//!
//! A perturbation of any parameter of joint `k` moves the child's whole subtree rigidly, as
//! its position does, so its effect on the normal equations is a twist (camera-frame motion)
//! against the observer's per-subtree information matrices: a frame's contribution costs one
//! twist per joint parameter, not a pass over the points.

use crate::refine::JointParams;
use crate::solver::{Descent, Measure, ObservedJoint, Observer, Scratch, State, Visible};
use kinetree_core::geom::perpendicular_basis;
use kinetree_core::nalgebra::{
    DMatrix, DVector, Isometry3, Matrix6xX, Point3, Translation3, Unit, UnitQuaternion, Vector3,
    Vector6,
};
use kinetree_core::{Result, Tracks};
use rayon::prelude::*;
use std::borrow::Cow;

/// One adjusted joint.
#[derive(Debug, Clone, Copy)]
struct Block {
    joint: usize,
    params: Params,
    /// First of its parameters in the global vector.
    offset: usize,
}

/// The parameters of an adjusted joint, all in the parent's body frame.
#[derive(Debug, Clone, Copy)]
enum Params {
    /// A revolute or prismatic joint.
    Single(JointParams),
    /// A revolute or prismatic joint into a link put in (too little seen to pose): its axis
    /// and, for a hinge, its pivot only. The link's frame is a choice its keypoints, none or
    /// a few, need not fix, so its reference pose is held; adjusting it too would leave the
    /// normal equations singular where they do not fix it.
    Held(JointParams),
    /// A ball joint: its centre and the child's pose at rotation zero.
    Ball {
        centre: Point3<f64>,
        reference: Isometry3<f64>,
    },
    /// A universal joint: its first axis, its second where it is at angles zero, their
    /// intersection, and the child's pose at angles zero.
    Cardan {
        first: Vector3<f64>,
        second: Vector3<f64>,
        centre: Point3<f64>,
        reference: Isometry3<f64>,
    },
}

impl Params {
    /// From an observer's joint; `None` when it has no position (multi-DoF). `unseen_child`:
    /// whether the joint's child is a link put in between two hinges.
    fn of(j: &ObservedJoint, unseen_child: bool) -> Option<Self> {
        match j.measure {
            Measure::Revolute(..) | Measure::Prismatic(..) if unseen_child => {
                JointParams::of(j).map(Self::Held)
            }
            Measure::Spherical(centre) => Some(Self::Ball {
                centre,
                reference: j.reference,
            }),
            Measure::Universal(first, second, centre) => Some(Self::Cardan {
                first,
                second,
                centre,
                reference: j.reference,
            }),
            _ => JointParams::of(j).map(Self::Single),
        }
    }

    /// Free parameters in the adjustment: revolute 9 (axis tilt 2, pivot across the axis 2,
    /// reference pose turned about the two directions across the axis and shifted 3; held,
    /// the first 4), prismatic 7 (tilt 2, turn 3, shift across the axis 2; held, the first
    /// 2), ball 6 (centre 3, reference pose shifted 3), universal 11 (first axis tilted 2,
    /// second tilted towards or away from the first 1, centre 3, reference pose turned
    /// about the two directions across the second axis 2 and shifted 3). What a change of
    /// every frame's coordinates undoes is left out (a gauge freedom that would make the
    /// normal equations singular): the reference pose's turn about a revolute axis and
    /// shift along a prismatic one; every turn of a ball joint's reference pose; a
    /// universal joint's turn about its second axis (its second angle) and the second axis
    /// turned about the first together with the reference pose (its first angle).
    fn len(&self) -> usize {
        match self {
            Params::Single(p) if p.revolute => 9,
            Params::Single(_) => 7,
            Params::Held(p) if p.revolute => 4,
            Params::Held(_) => 2,
            Params::Ball { .. } => 6,
            Params::Cardan { .. } => 11,
        }
    }

    /// Moved by `d` ([`Params::len`] entries).
    fn moved(&self, d: &[f64]) -> Self {
        let shift = |d: &[f64]| Translation3::new(d[0], d[1], d[2]);
        match *self {
            Params::Single(p) => {
                let (e1, e2) = perpendicular_basis(&p.axis);
                let mut full = [0.0; 10];
                if p.revolute {
                    full[..4].copy_from_slice(&d[..4]);
                    let turn = e1 * d[4] + e2 * d[5];
                    full[4..7].copy_from_slice(turn.as_slice());
                    full[7..10].copy_from_slice(&d[6..9]);
                } else {
                    full[..5].copy_from_slice(&d[..5]);
                    let shift = e1 * d[5] + e2 * d[6];
                    full[5..8].copy_from_slice(shift.as_slice());
                }
                Params::Single(p.moved(&full[..p.len()]))
            }
            Params::Held(p) => {
                let mut full = [0.0; 10];
                let held = if p.revolute { 4 } else { 2 };
                full[..held].copy_from_slice(&d[..held]);
                Params::Held(p.moved(&full[..p.len()]))
            }
            Params::Ball { centre, reference } => Params::Ball {
                centre: centre + Vector3::new(d[0], d[1], d[2]),
                reference: shift(&d[3..6]) * reference,
            },
            Params::Cardan {
                first,
                second,
                centre,
                reference,
            } => {
                let (e1, e2) = perpendicular_basis(&first);
                let (f1, f2) = perpendicular_basis(&second);
                let turn = UnitQuaternion::from_scaled_axis(f1 * d[6] + f2 * d[7]);
                Params::Cardan {
                    first: (first + e1 * d[0] + e2 * d[1]).normalize(),
                    second: (second + cardan_tilt(&first, &second) * d[2]).normalize(),
                    centre: centre + Vector3::new(d[3], d[4], d[5]),
                    reference: shift(&d[8..11]) * turn * reference,
                }
            }
        }
    }

    /// `parent_from_child` of joint `k` at its coordinates in `state` (`None` while unknown).
    fn transform(&self, k: usize, state: &State) -> Option<Isometry3<f64>> {
        let about = |c: &Point3<f64>, turn: UnitQuaternion<f64>, reference: &Isometry3<f64>| {
            Translation3::from(c.coords) * turn * Translation3::from(-c.coords) * reference
        };
        match self {
            Params::Single(p) | Params::Held(p) => Some(p.transform(state.q[k]?)),
            Params::Ball { centre, reference } => Some(about(centre, state.turn[k]?, reference)),
            Params::Cardan {
                first,
                second,
                centre,
                reference,
            } => {
                let turn = |axis: &Vector3<f64>, q: f64| {
                    UnitQuaternion::from_axis_angle(&Unit::new_normalize(*axis), q)
                };
                let both = turn(first, state.q[k]?) * turn(second, state.q2[k]?);
                Some(about(centre, both, reference))
            }
        }
    }

    /// The same joint with a revolute pivot moved to its canonical place
    /// ([`JointParams::canonical`]).
    fn canonical(self) -> Self {
        match self {
            Params::Single(p) => Params::Single(p.canonical()),
            Params::Held(p) => Params::Held(p.canonical()),
            other => other,
        }
    }

    /// The measure an observer's joint takes from these parameters.
    fn measure(&self) -> Measure {
        match *self {
            Params::Single(p) | Params::Held(p) => p.measure(),
            Params::Ball { centre, .. } => Measure::Spherical(centre),
            Params::Cardan {
                first,
                second,
                centre,
                ..
            } => Measure::Universal(first, second, centre),
        }
    }

    /// `parent_from_child` at coordinates zero.
    fn reference(&self) -> Isometry3<f64> {
        match self {
            Params::Single(p) | Params::Held(p) => p.reference,
            Params::Ball { reference, .. } | Params::Cardan { reference, .. } => *reference,
        }
    }

    /// Writes the parameters into the observer's joint `j`.
    fn store(&self, j: &mut ObservedJoint) {
        j.measure = self.measure();
        j.reference = self.reference();
    }
}

/// The direction a universal joint's second axis `second` tilts in towards or away from its
/// first axis `first` (turning the angle between them); any direction across the second axis
/// when the two are parallel.
fn cardan_tilt(first: &Vector3<f64>, second: &Vector3<f64>) -> Vector3<f64> {
    let normal = first.cross(second);
    let about = if normal.norm() > 1e-9 {
        normal.normalize()
    } else {
        perpendicular_basis(second).0
    };
    about.cross(second)
}

/// Finite-difference step of the joint parameters' twists (metres or radians).
const DIFF_STEP: f64 = 1e-6;
/// When the bundle adjustment stops (`[pipeline.repairs.bundle_adjust]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BundleLimits {
    /// Most Gauss-Newton steps on the joints (default 20).
    pub max_steps: usize,
    /// The adjustment stops when a step lowers the total squared residual by less than this
    /// many noise variances (the parameters then move by well under their standard
    /// deviations), or when the next step's gain, predicted as `g_k^2 / g_(k-1)` from the
    /// last two, is; the prediction saves the last linearisation (default 0.1;
    /// `docs/decisions.md`, `kinetree_fit::MIN_GAIN_IN_VARIANCES`).
    pub min_gain_in_variances: f64,
    /// Most frames the adjustment works on: over more, it takes this many evenly spaced
    /// (default 20 000; their joints' parameters are then about `sqrt(T / max_frames)`
    /// times less precise than every frame would make them, far below the keypoint noise's
    /// effect on the positions; `docs/decisions.md`, `bundle_adjust.max_frames`).
    pub max_frames: usize,
    /// Most observations (frames times placed points, 48 bytes each) whose visible points
    /// the adjustment keeps between its steps; over more, each frame's are formed again from
    /// the tracks at each use, which gives the same result in more time (default 2 000 000,
    /// about 96 MB; `docs/decisions.md`, `bundle_adjust.max_kept_observations`).
    pub max_kept_observations: usize,
}

impl Default for BundleLimits {
    fn default() -> Self {
        Self {
            max_steps: 20,
            min_gain_in_variances: 0.1,
            max_frames: 20_000,
            max_kept_observations: 2_000_000,
        }
    }
}

/// One frame: its visible points (`None` when they are formed again at each use) and the
/// converged fit of its own parameters.
struct Frame {
    visible: Option<Visible>,
    descent: Descent,
}

/// The frames the adjustment works on, and where the visible points of those that do not keep
/// them come from: frame `t` of `frames` is frame `t` of `tracks`, seen by `observer`.
struct FrameSet<'a> {
    frames: Vec<Frame>,
    observer: &'a Observer,
    tracks: &'a Tracks,
}

impl FrameSet<'_> {
    /// Frame `t`'s visible points: its own, or formed again.
    fn visible(&self, t: usize) -> Cow<'_, Visible> {
        match &self.frames[t].visible {
            Some(v) => Cow::Borrowed(v),
            None => Cow::Owned(self.observer.visible_at(self.tracks, t)),
        }
    }
}

/// Bundle-adjusts the joints `observer` follows (freed joints and multi-DoF ones are left
/// alone; with `only`, also every joint not in it) against every frame of `tracks` (at most
/// [`BundleLimits::max_frames`] of them, evenly spaced), starting from `known`, the
/// observer's own fit of them ([`Observer::fit_sequence`]): the observer with the adjusted
/// joints, or `None` when there is no such joint or no step lowered the residual.
///
/// # Errors
/// [`kinetree_core::Error::Shape`] when the tracks do not match the observer's model.
pub(crate) fn adjust(
    observer: &Observer,
    tracks: &Tracks,
    known: &[crate::FrameFit],
    limits: &BundleLimits,
    only: Option<&[usize]>,
) -> Result<Option<Observer>> {
    let (mut blocks, n) = blocks_of(observer, only);
    if blocks.is_empty() {
        return Ok(None);
    }
    let t = tracks.n_frames();
    let m = limits.max_frames.max(1);
    let subset = if t > m && known.len() == t {
        let picked: Vec<usize> = (0..m).map(|j| j * t / m).collect();
        let known: Vec<crate::FrameFit> = picked.iter().map(|&f| known[f].clone()).collect();
        Some((tracks.select_frames(&picked)?, known))
    } else {
        None
    };
    let (source, known) = subset
        .as_ref()
        .map_or((tracks, known), |(s, k)| (s, k.as_slice()));
    let keep =
        source.n_frames().saturating_mul(observer.placed_points()) <= limits.max_kept_observations;
    let frame = |descent, visible| Frame {
        visible: keep.then_some(visible),
        descent,
    };
    let frames = if subset.is_some() {
        // Evenly spaced frames, each fitted again from its own known fit (the frames before
        // it in the subset are not its neighbours).
        observer.settle_sequence_with(source, known, frame)?
    } else {
        observer.replay_sequence_with(source, known, frame)?
    };
    let mut set = FrameSet {
        frames,
        observer,
        tracks: source,
    };
    let before: f64 = set.frames.iter().map(|f| f.descent.cost).sum();
    let mut current = observer.clone();
    let mut cost = before;
    let mut lambda = 1e-3;
    let mut previous_gain: Option<f64> = None;
    let variance = (observer.sigma * observer.sigma).max(f64::MIN_POSITIVE);
    for _ in 0..limits.max_steps {
        let Some((normal, rhs)) = reduced_system(&current, &blocks, n, &set) else {
            break;
        };
        let mut accepted = false;
        while lambda < 1e8 {
            let mut m = normal.clone();
            for i in 0..n {
                let d = m[(i, i)];
                m[(i, i)] = if d > 0.0 { d * (1.0 + lambda) } else { 1.0 };
            }
            let Some(chol) = m.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let step = chol.solve(&rhs);
            if !step.iter().all(|x| x.is_finite()) {
                lambda *= 10.0;
                continue;
            }
            let mut trial = current.clone();
            let trial_blocks: Vec<Block> = blocks
                .iter()
                .map(|b| {
                    let len = b.params.len();
                    let params = b.params.moved(&step.as_slice()[b.offset..b.offset + len]);
                    params.store(&mut trial.joints[b.joint]);
                    Block { params, ..*b }
                })
                .collect();
            // Frames are refitted independently, in parallel; collected in order, so the sum
            // below is the same as a sequential one.
            let refitted: Vec<Descent> = (0..set.frames.len())
                .into_par_iter()
                .map(|t| trial.descend(set.frames[t].descent.state.clone(), &set.visible(t)))
                .collect();
            let c: f64 = refitted.iter().map(|d| d.cost).sum();
            if c.is_finite() && c < cost {
                let gain = (cost - c) / variance;
                for (f, d) in set.frames.iter_mut().zip(refitted) {
                    f.descent = d;
                }
                (current, blocks, cost) = (trial, trial_blocks, c);
                lambda = (lambda * 0.1).max(1e-9);
                let predicted = previous_gain.map_or(f64::INFINITY, |p| gain * gain / p);
                let least = limits.min_gain_in_variances;
                accepted = gain >= least && predicted >= least;
                previous_gain = Some(gain);
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            break;
        }
    }
    if cost >= before {
        return Ok(None);
    }
    for b in &blocks {
        b.params.canonical().store(&mut current.joints[b.joint]);
    }
    Ok(Some(current))
}

/// The joints `observer` follows, each with its parameters' place in the global
/// vector, and the number of parameters.
fn blocks_of(observer: &Observer, only: Option<&[usize]>) -> (Vec<Block>, usize) {
    let mut blocks = Vec::new();
    let mut n = 0;
    for (k, j) in observer.joints.iter().enumerate() {
        if observer.joint_col[k].is_none() || only.is_some_and(|o| !o.contains(&k)) {
            continue;
        }
        let unseen_child = observer.bodies[j.child].unseen_link;
        if let Some(params) = Params::of(j, unseen_child) {
            blocks.push(Block {
                joint: k,
                params,
                offset: n,
            });
            n += params.len();
        }
    }
    (blocks, n)
}

/// Standard deviations of a joint's parameters from the whole-tree fit of every frame, at the
/// observer's noise level.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointPrecision {
    /// RMS angle between the estimated and the true axis direction (a universal joint's
    /// first axis), radians; `None` for a ball joint.
    pub axis_std_rad: Option<f64>,
    /// RMS distance across the axis between the estimated and the true axis line, metres
    /// (revolute joints; `None` for others).
    pub pivot_std_m: Option<f64>,
    /// RMS distance between the estimated and the true centre in the parent's frame, metres
    /// (ball and universal joints; `None` for others).
    pub centre_std_m: Option<f64>,
    /// RMS angle between the estimated and the true second axis of a universal joint in the
    /// child's frame, radians (`None` for others).
    pub second_axis_std_rad: Option<f64>,
}

/// The Cramér-Rao bound of every followed joint's axes and pivot or centre for Gaussian
/// keypoint noise at the observer's level, the reference shapes taken as exact: the inverse
/// of the normal matrix of the joints' parameters with every frame's configuration eliminated
/// (the matrix [`adjust`] steps with), linearised at the observer's own fit `known` of
/// `tracks`. The other joints' parameters and every frame's configuration are nuisance
/// parameters, so a joint seen in few frames or over a small arc gets a large bound. One
/// entry per joint, `None` for joints that are not followed or multi-DoF, and for every
/// joint when the normal matrix is singular.
///
/// # Errors
/// [`kinetree_core::Error::Shape`] when the tracks do not match the observer's model.
pub(crate) fn joint_precision(
    observer: &Observer,
    tracks: &Tracks,
    known: &[crate::FrameFit],
) -> Result<Vec<Option<JointPrecision>>> {
    let mut out = vec![None; observer.joints.len()];
    let (blocks, n) = blocks_of(observer, None);
    if blocks.is_empty() {
        return Ok(out);
    }
    let frame = |descent, visible| Frame {
        visible: Some(visible),
        descent,
    };
    let system = if known.len() == tracks.n_frames() {
        // The frames are settled a batch at a time and summed: their visible points together
        // would take 48 bytes per observation.
        let Some(mut sum) = ReducedSum::new(observer, &blocks, n) else {
            return Ok(out);
        };
        for start in (0..known.len()).step_by(FRAME_BATCH) {
            let range = start..(start + FRAME_BATCH).min(known.len());
            let set = FrameSet {
                frames: observer.settle_frames_with(tracks, known, range, frame)?,
                observer,
                tracks,
            };
            sum.add(&set, 0..set.frames.len());
        }
        sum.finish()
    } else {
        let set = FrameSet {
            frames: observer.settle_sequence_with(tracks, known, frame)?,
            observer,
            tracks,
        };
        reduced_system(observer, &blocks, n, &set)
    };
    let Some((normal, _)) = system else {
        return Ok(out);
    };
    let Some(chol) = normal.cholesky() else {
        return Ok(out);
    };
    let covariance = chol.inverse() * (observer.sigma * observer.sigma);
    // The RMS size of `sum_i directions[i] * d[indices[i]]` over the parameters' covariance:
    // the square root of the trace of the propagated covariance.
    let rms = |indices: &[usize], directions: &[Vector3<f64>]| {
        let mut v = 0.0;
        for (&i, a) in indices.iter().zip(directions) {
            for (&j, b) in indices.iter().zip(directions) {
                v += a.dot(b) * covariance[(i, j)];
            }
        }
        (v.is_finite() && v >= 0.0).then(|| v.sqrt())
    };
    let unit = [Vector3::x(), Vector3::y(), Vector3::z()];
    for b in &blocks {
        let o = b.offset;
        // Each reduced parameter vector ([`Params::len`]) starts with what moves the axis or
        // the centre along orthonormal directions.
        let precision = match b.params {
            Params::Single(p) | Params::Held(p) => JointPrecision {
                axis_std_rad: rms(&[o, o + 1], &unit[..2]),
                pivot_std_m: if p.revolute {
                    rms(&[o + 2, o + 3], &unit[..2])
                } else {
                    None
                },
                ..Default::default()
            },
            Params::Ball { .. } => JointPrecision {
                centre_std_m: rms(&[o, o + 1, o + 2], &unit),
                ..Default::default()
            },
            Params::Cardan { first, second, .. } => {
                // The second axis in the child's frame moves with its tilt and against the
                // reference pose's turn (parameters 2, then 6 and 7).
                let (f1, f2) = perpendicular_basis(&second);
                let in_child = [
                    cardan_tilt(&first, &second),
                    -f1.cross(&second),
                    -f2.cross(&second),
                ];
                JointPrecision {
                    axis_std_rad: rms(&[o, o + 1], &unit[..2]),
                    centre_std_m: rms(&[o + 3, o + 4, o + 5], &unit),
                    second_axis_std_rad: rms(&[o + 2, o + 6, o + 7], &in_child),
                    ..Default::default()
                }
            }
        };
        out[b.joint] = Some(precision);
    }
    Ok(out)
}

/// The normal equations of the joints' parameters with every frame's own parameters
/// eliminated: `sum_t (A_t - B_t D_t^-1 B_t^T)` and `sum_t (g_t - B_t D_t^-1 l_t)`, with
/// `D_t`, `l_t` the frame's own normal equations ([`Observer::linearise`]), `A_t`, `g_t` the
/// joints' and `B_t` between the two. `None` when no frame has a usable linearisation.
///
/// Two parameters share the points of the deeper one's subtree when one moves the other's
/// body, and none otherwise; a joint's parameters move its child's subtree, as its position
/// does. The blocks are products of 6 x k twist matrices with the subtrees' 6 x 6
/// information (a tenth of the time of entry-by-entry products on a 9-joint arm).
fn reduced_system(
    observer: &Observer,
    blocks: &[Block],
    n: usize,
    frames: &FrameSet,
) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let mut sum = ReducedSum::new(observer, blocks, n)?;
    let count = frames.frames.len();
    for start in (0..count).step_by(FRAME_BATCH) {
        sum.add(frames, start..(start + FRAME_BATCH).min(count));
    }
    sum.finish()
}

/// The sums of [`reduced_system`], taken a batch of frames at a time so that a caller can
/// form the frames batch by batch too (the visible points of every frame of a long recording
/// of many points would not fit in memory together).
struct ReducedSum<'a> {
    /// The observer whose joints are linearised.
    observer: &'a Observer,
    layout: Layout<'a>,
    normal: DMatrix<f64>,
    rhs: DVector<f64>,
    used: bool,
}

impl<'a> ReducedSum<'a> {
    /// Empty sums; `None` when a block's joint has no position column.
    fn new(observer: &'a Observer, blocks: &'a [Block], n: usize) -> Option<Self> {
        // The body each frame parameter moves with its subtree: a free pose's body, a
        // joint's child.
        let m = observer.n_params;
        let mut owner = vec![0; m];
        for (b, c) in observer.free_col.iter().enumerate() {
            if let Some(c) = *c {
                owner[c..c + 6].fill(b);
            }
        }
        for (k, c) in observer.joint_col.iter().enumerate() {
            if let Some(c) = *c {
                let j = &observer.joints[k];
                owner[c..c + j.measure.width()].fill(j.child);
            }
        }
        // Per block: its joint's position column and child.
        let place: Vec<(usize, usize)> = blocks
            .iter()
            .map(|b| Some((observer.joint_col[b.joint]?, observer.joints[b.joint].child)))
            .collect::<Option<_>>()?;
        Some(Self {
            observer,
            layout: Layout {
                blocks,
                n,
                owner,
                place,
            },
            normal: DMatrix::<f64>::zeros(n, n),
            rhs: DVector::<f64>::zeros(n),
            used: false,
        })
    }

    /// Adds the terms of the frames of `frames` in `batch`, the next in order. The terms are
    /// formed in parallel and added in frame order, so the sums do not depend on the number of
    /// threads; keep batches to about [`FRAME_BATCH`] frames (a term is n x n).
    fn add(&mut self, frames: &FrameSet, batch: std::ops::Range<usize>) {
        let (observer, layout) = (self.observer, &self.layout);
        let terms: Vec<FrameTerm> = batch
            .into_par_iter()
            .map_init(Scratch::default, |scratch, t| {
                let descent = &frames.frames[t].descent;
                frame_term(observer, layout, descent, &frames.visible(t), scratch)
            })
            .collect();
        for term in terms {
            match term {
                FrameTerm::Unused => {}
                FrameTerm::Unfactored => self.used = true,
                FrameTerm::Term(n_f, g_f) => {
                    self.used = true;
                    self.normal += n_f;
                    self.rhs += g_f;
                }
            }
        }
    }

    /// The normal matrix and right-hand side; `None` when no frame had a usable
    /// linearisation.
    fn finish(mut self) -> Option<(DMatrix<f64>, DVector<f64>)> {
        // The lower triangle is copied from the upper, so the matrix is symmetric to the
        // bit whatever order the Gram products summed each triangle in.
        self.normal.fill_lower_triangle_with_upper_triangle();
        self.used.then_some((self.normal, self.rhs))
    }
}

/// What [`reduced_system`] needs of the model besides the frames.
struct Layout<'a> {
    blocks: &'a [Block],
    /// Number of joint parameters.
    n: usize,
    /// The body each frame parameter moves with its subtree.
    owner: Vec<usize>,
    /// Per block: its joint's position column and child.
    place: Vec<(usize, usize)>,
}

/// Frames whose terms of the reduced system are formed at once.
const FRAME_BATCH: usize = 16;

/// One frame's part of [`reduced_system`].
enum FrameTerm {
    /// No usable linearisation (no point seen).
    Unused,
    /// Linearised, but the frame's own normal matrix could not be factored: it adds nothing.
    Unfactored,
    /// `A_t - B_t D_t^-1 B_t^T` (its upper triangle is what counts) and `g_t - B_t D_t^-1 l_t`.
    Term(DMatrix<f64>, DVector<f64>),
}

/// One frame's term of [`reduced_system`].
fn frame_term(
    observer: &Observer,
    layout: &Layout,
    descent: &Descent,
    visible: &Visible,
    scratch: &mut Scratch,
) -> FrameTerm {
    let Layout {
        blocks,
        n,
        owner,
        place,
    } = layout;
    let (n, m) = (*n, observer.n_params);
    let moves = |column: usize, body: usize| observer.cols[body].contains(&column);
    let Some(lin) = observer.linearise(&descent.poses, visible, scratch) else {
        return FrameTerm::Unused;
    };
    let twists: Vec<Option<Matrix6xX<f64>>> = blocks
        .iter()
        .map(|b| block_twists(observer, b, descent, &lin.origin))
        .collect();
    // The frame's own block, unseen parameters pinned, a tiny ridge for near-dependent
    // ones (a joint whose child's points are all near its axis in this frame).
    let Some(chol) = lin.damped_factor(1e-10, &observer.pattern) else {
        return FrameTerm::Unfactored;
    };
    let mut normal = DMatrix::<f64>::zeros(n, n);
    let mut rhs = DVector::<f64>::zeros(n);
    // Each local parameter's twist against its own subtree's information.
    let local: Vec<Vector6<f64>> = (0..m)
        .map(|c| scratch.info[owner[c]] * scratch.twist[c])
        .collect();
    // Each joint's twists against the information of the subtree they move.
    let informed: Vec<Option<Matrix6xX<f64>>> = twists
        .iter()
        .zip(place)
        .map(|(t, &(_, below))| t.as_ref().map(|t| scratch.info[below] * t))
        .collect();
    let mut cross = DMatrix::<f64>::zeros(m, n);
    for (u, bu) in blocks.iter().enumerate() {
        let Some(tu) = &twists[u] else { continue };
        let (cu, child) = place[u];
        let len = tu.ncols();
        let mut g = rhs.rows_mut(bu.offset, len);
        g += tu.transpose() * scratch.grad[child];
        // Against the joints at or below this one (the deeper one's subtree is shared).
        for (v, bv) in blocks.iter().enumerate() {
            let Some(wv) = &informed[v] else { continue };
            let (_, below) = place[v];
            if !moves(cu, below) {
                continue;
            }
            let mut upper = normal.view_mut((bu.offset, bv.offset), (len, wv.ncols()));
            upper.gemm_tr(1.0, tu, wv, 1.0);
            if u != v {
                let mut lower = normal.view_mut((bv.offset, bu.offset), (wv.ncols(), len));
                lower.gemm_tr(1.0, wv, tu, 1.0);
            }
        }
        // Against the frame's parameters: above or at the child, the child's subtree;
        // below it, the parameter's own.
        let Some(wu) = &informed[u] else { continue };
        for c in 0..m {
            if !lin.seen[c] {
                continue;
            }
            let (side, motion) = if moves(c, child) {
                (wu, &scratch.twist[c])
            } else if moves(cu, owner[c]) {
                (tu, &local[c])
            } else {
                continue;
            };
            for i in 0..len {
                cross[(c, bu.offset + i)] = side.column(i).dot(motion);
            }
        }
    }
    // cross^T D^-1 cross = Y^T Y and cross^T D^-1 l = Y^T z with Y = L^-T cross and
    // z = L^-T l (D = L^T L): one triangular sweep per column instead of two.
    chol.half_solve_columns_mut(&mut cross);
    let mut z = lin.rhs.clone();
    chol.half_solve_mut(z.as_mut_slice());
    subtract_gram(&mut normal, &cross);
    rhs.gemv_tr(-1.0, &cross, &z, 1.0);
    FrameTerm::Term(normal, rhs)
}

/// `normal -= y^T y`, through nalgebra's `gemm` (matrixmultiply's blocked kernel): on a
/// frame's `y` of the 21-body scenes (25 x 114) a dot product per entry of the upper triangle
/// was a third of the bundle adjustment. Only the upper triangle is read (`ReducedSum::finish`).
fn subtract_gram(normal: &mut DMatrix<f64>, y: &DMatrix<f64>) {
    if y.nrows() == 0 {
        return;
    }
    let yt = y.transpose();
    normal.gemm(-1.0, &yt, y, 1.0);
}

/// The twists (camera-frame motions about `origin`, see [`Observer::linearise`]) of one
/// joint's parameters in the frame of `descent`, by central differences; `None` where the
/// joint's parent has no pose or its position is unknown.
fn block_twists(
    observer: &Observer,
    b: &Block,
    descent: &Descent,
    origin: &kinetree_core::nalgebra::Vector3<f64>,
) -> Option<Matrix6xX<f64>> {
    let j = &observer.joints[b.joint];
    let parent = descent.poses[j.parent]?;
    let state = &descent.state;
    let origin = Point3::from(*origin);
    let inverse = (parent * b.params.transform(b.joint, state)?).inverse();
    let motion = |d: &[f64]| -> Option<Isometry3<f64>> {
        Some(parent * b.params.moved(d).transform(b.joint, state)? * inverse)
    };
    let len = b.params.len();
    let mut out = Matrix6xX::<f64>::zeros(len);
    let mut d = vec![0.0; len];
    for i in 0..len {
        d[i] = DIFF_STEP;
        let plus = motion(&d)?;
        d[i] = -DIFF_STEP;
        let minus = motion(&d)?;
        d[i] = 0.0;
        let v = (plus * origin - minus * origin) / (2.0 * DIFF_STEP);
        let w = (plus.rotation.scaled_axis() - minus.rotation.scaled_axis()) / (2.0 * DIFF_STEP);
        out.set_column(i, &Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z));
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gram_product_is_subtracted() {
        // A small product and one of a frame's size on the 21-body scenes, checked entry by
        // entry against dot products of the columns.
        for (rows, n) in [(7, 5), (25, 114)] {
            let y = DMatrix::from_fn(rows, n, |i, j| ((i * n + j) as f64 * 0.71).sin());
            let start = DMatrix::from_fn(n, n, |i, j| (i + 2 * j) as f64);
            let mut out = start.clone();
            subtract_gram(&mut out, &y);
            for j in 0..n {
                for i in 0..n {
                    let want = start[(i, j)] - y.column(i).dot(&y.column(j));
                    let scale = 1.0 + want.abs();
                    assert!(
                        (out[(i, j)] - want).abs() < 1e-12 * scale,
                        "entry ({i}, {j}) of {rows} x {n}"
                    );
                }
            }
        }
    }
}
