//! Links that no keypoint shows well enough to pose: two seen bodies joined through a hidden
//! link by two hinges move against each other with two coordinates, which the pair test
//! can only call multi-DoF (the hinges' axes do not meet, so it is no universal joint). Such
//! a pair is fitted as two hinges through a body without keypoints, put into the tree
//! between them; it is kept when the whole-tree fit follows the child through both, and it
//! takes the keypoints its fitted motion explains clearly best.
//!
//! The start comes from the two bodies' fitted poses. With the child's motion from its pose
//! at the reference frame `D_t = R_1(q_1) R_2(q_2)` (rotations about the first axis `a_1`,
//! fixed in the parent, and the second `a_2`, where the first angle carries it), every frame
//! keeps `a_1 . (D_t - I) a_2 = 0`: the rotation about `a_1` does not move `a_1`, and the one
//! about `a_2` does not move `a_2`. The axes minimise the sum of its squares (a coarse search
//! over `a_1`, each direction with its best `a_2`, then alternating eigenvector steps); each
//! frame's angles follow from the rotation, and the pivots `p_1`, `p_2` from the
//! translations, `(I - R_1) p_1 + R_1 (I - R_2) p_2`, by linear least squares.

use crate::bundle::BundleLimits;
use crate::hubs::{adopt_children, rehang_multi_dof};
use crate::motions::{FittedMotions, in_body_frame};
use crate::policy::{FitState, adjust_model, any_above, clear_coordinates, store_joint};
use crate::refine::JointParams;
use crate::solver::{FrameFit, Observer, universal_angles};
use kinetree_core::geom::hemisphere;
use kinetree_core::model::{Body, JointFit, JointType};
use kinetree_core::nalgebra::{
    Isometry3, Matrix3, Matrix6, Point3, UnitQuaternion, Vector3, Vector6,
};
use kinetree_core::{Model, Result, Tracks, Warning};
use rayon::prelude::*;

/// When [`unseen_links`] puts a link between two bodies (`[pipeline.unseen_links]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnseenLinkLimits {
    /// Frames in which the whole-tree fit poses both bodies, at least (default 30).
    pub min_frames: usize,
    /// The start's RMS miss of the child's keypoints, in noise standard deviations, above
    /// which the pair is not tried further (default 20: the start comes from per-frame poses
    /// and is refined by the adjustment; a free or ball-jointed pair misses by far more).
    pub max_start_rms_in_sigma: f64,
    /// The child's joint excess, after the adjustment, must be within this (default 3, as
    /// `type_by_fit.max_excess`) ...
    pub max_excess: f64,
    /// ... and every other joint's within this (default 30, the freeing bound).
    pub others_max_excess: f64,
    /// The two axes must be at least this far apart, in noise standard deviations (default
    /// 3): nearer, the pair is a universal joint, not a link.
    pub min_offset_in_sigma: f64,
    /// ... and at least this angle apart, degrees (default 10): the angles of two nearly
    /// parallel hinges are not told apart by the rotation this start reads them from.
    pub min_axes_angle_deg: f64,
    /// A universal joint becomes two hinges only when they lower the fit's squared
    /// residual by more than this many noise variances (default 100; `docs/decisions.md`,
    /// `[pipeline.unseen_links]`): the axes' distance is one more parameter.
    pub min_gain_over_universal: f64,
    /// Whether the children of a hidden link that the tree hung elsewhere are moved (default
    /// true): a multi-DoF joint that is not two hinges is tried with its child on the other
    /// body whose two hinges carry it best, and once a link is put in, each body hung by a
    /// multi-DoF or universal joint, or one the fit does not follow, is tried on it by one
    /// hinge or slide; last, the child of every multi-DoF joint left is tried on the body
    /// the fit moves it against by one hinge or slide.
    pub rehang: bool,
    /// The bundle adjustment of each candidate.
    pub bundle: BundleLimits,
}

impl Default for UnseenLinkLimits {
    fn default() -> Self {
        Self {
            min_frames: 30,
            max_start_rms_in_sigma: 20.0,
            max_excess: 3.0,
            others_max_excess: crate::MAX_JOINT_EXCESS,
            min_offset_in_sigma: 3.0,
            min_axes_angle_deg: 10.0,
            min_gain_over_universal: 100.0,
            rehang: true,
            bundle: BundleLimits::default(),
        }
    }
}

/// Directions of the coarse search over the first axis (about 6 deg apart).
const AXES_GRID: usize = 600;
/// Starts of the alternating steps, the best of the search at least 10 deg apart.
const AXES_STARTS: usize = 6;
/// Alternating eigenvector steps from each start.
const AXES_ROUNDS: usize = 40;

/// Every multi-DoF or universal joint of `model` that the whole-tree fit follows as two hinges
/// through a body without keypoints (a universal joint: better than through its centre) gets
/// that body, in the tree between its parent and child (appended to `model.bodies`), and two
/// revolute joints in its place, and the keypoints its fitted motion explains clearly best
/// ([`FittedMotions::points_for_body`]), with an `unseen_link` warning in place of its
/// `multi_dof_joint` one. With [`UnseenLinkLimits::rehang`], a multi-DoF joint that is not
/// two hinges is tried with its child on the body whose two hinges carry it best, the bodies
/// hung by doubtful joints are tried on each link put in, and the multi-DoF joints left are
/// tried on the body the fit moves their child against by one hinge or slide. Returns the
/// bodies put in. The positions and their precision are not written: the caller writes them
/// from a fit of the new model.
///
/// # Errors
/// As [`Observer::new`] and [`Observer::fit_sequence`].
pub fn unseen_links(
    model: &mut Model,
    tracks: &Tracks,
    limits: &UnseenLinkLimits,
) -> Result<Vec<usize>> {
    let pairs = edges(model, |j| {
        matches!(j.joint_type, JointType::MultiDof | JointType::Universal)
    });
    let mut added = Vec::new();
    if pairs.is_empty() {
        return Ok(added);
    }
    let mut state = FitState::new(model, tracks)?;
    for (parent, child) in pairs {
        let Some(k) = joint_between(model, parent, child) else {
            continue;
        };
        let mut trial = model.clone();
        if let Some(kept) = try_link(&mut trial, k, tracks, state.fits(), limits)? {
            *model = trial;
            let link = model.bodies.len() - 1;
            added.push(link);
            state = adopt_children(model, link, tracks, kept, limits)?;
            continue;
        }
        // The tree may have hung the child on a neighbour of the hidden link's parent: the
        // body whose two hinges carry the child's keypoints best is tried in its place.
        if !limits.rehang || model.joints[k].joint_type != JointType::MultiDof {
            continue;
        }
        let Some(other) = other_parent(model, k, state.fits(), limits) else {
            continue;
        };
        let mut trial = model.clone();
        trial.joints[k].parent = other;
        trial.bodies[child].parent = Some(other);
        trial.chain = None;
        if let Some(kept) = try_link(&mut trial, k, tracks, state.fits(), limits)? {
            forget_joint_warnings(&mut trial, parent, child);
            *model = trial;
            let link = model.bodies.len() - 1;
            added.push(link);
            state = adopt_children(model, link, tracks, kept, limits)?;
        }
    }
    rehang_multi_dof(model, tracks, state, limits)?;
    Ok(added)
}

/// The body other than its parent, outside its own subtree, on which multi-DoF joint `k`'s
/// child moves as two hinges carrying its keypoints best (a start within the limits; see
/// [`try_link`]), the candidates fitted in parallel and ties to the lower body.
fn other_parent(
    model: &Model,
    k: usize,
    fits: &[FrameFit],
    limits: &UnseenLinkLimits,
) -> Option<usize> {
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    let reference = model.joints[k].reference_frame;
    let below = subtree(model, child);
    let misses: Vec<Option<f64>> = (0..model.bodies.len())
        .into_par_iter()
        .map(|b| {
            if b == parent || below[b] {
                return None;
            }
            two_hinge_start(model, (b, child), reference, fits, limits).map(|s| s.rms_m)
        })
        .collect();
    let mut best: Option<(f64, usize)> = None;
    for (b, miss) in misses.iter().enumerate() {
        if let Some(m) = *miss
            && best.is_none_or(|(x, _)| m < x)
        {
            best = Some((m, b));
        }
    }
    best.map(|(_, b)| b)
}

/// The `(parent, child)` of each joint of `model` that `which` picks, in joint order.
pub(crate) fn edges(
    model: &Model,
    which: impl Fn(&kinetree_core::model::Joint) -> bool,
) -> Vec<(usize, usize)> {
    model
        .joints
        .iter()
        .filter(|j| which(j))
        .map(|j| (j.parent, j.child))
        .collect()
}

/// Drops the warnings about the joint from `parent` to `child` that its replacement answers.
pub(crate) fn forget_joint_warnings(model: &mut Model, parent: usize, child: usize) {
    model.warnings.retain(|w| {
        !matches!(w,
            Warning::MultiDofJoint { parent: p, child: c, .. }
            | Warning::JointNotFollowed { parent: p, child: c, .. }
            if *p == parent && *c == child)
    });
}

/// A link put in as body `id` on `parent`: no keypoints yet, never registered on its own.
pub(crate) fn link_body(id: usize, parent: usize) -> Body {
    Body {
        id,
        points: Vec::new(),
        is_static: false,
        parent: Some(parent),
        frames_registered: 0,
        median_residual_m: None,
        shape: Vec::new(),
        internal_dissimilarity: None,
    }
}

/// The index of `model`'s joint from `parent` to `child`, if it has one.
pub(crate) fn joint_between(model: &Model, parent: usize, child: usize) -> Option<usize> {
    model
        .joints
        .iter()
        .position(|j| j.parent == parent && j.child == child)
}

/// Whether each body is `root` or below it in `model`'s tree.
pub(crate) fn subtree(model: &Model, root: usize) -> Vec<bool> {
    let n = model.bodies.len();
    let mut below = vec![false; n];
    for (b, flag) in below.iter_mut().enumerate() {
        let mut at = Some(b);
        let mut steps = 0;
        while let Some(x) = at {
            if x == root {
                *flag = true;
                break;
            }
            steps += 1;
            if steps > n {
                break;
            }
            at = model.joints.iter().find(|j| j.child == x).map(|j| j.parent);
        }
    }
    below
}

/// Joint `k` of `model` fitted as two hinges through a new body; the model keeps it and the
/// fit is returned when the fit follows it (see [`unseen_links`]).
fn try_link(
    model: &mut Model,
    k: usize,
    tracks: &Tracks,
    fits: &[FrameFit],
    limits: &UnseenLinkLimits,
) -> Result<Option<FitState>> {
    let sigma = model.noise.sigma_m;
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    let reference = model.joints[k].reference_frame;
    let universal = model.joints[k].joint_type == JointType::Universal;
    let before: f64 = fits.iter().map(|f| f.sum_sq_m2).sum();
    // A universal joint's fit poses the child through the joint, whose axes meet: the start
    // needs the child posed freely.
    let freed_fits;
    let posed = if universal {
        let mut freed = Observer::new(model)?;
        freed.free_joint(k);
        freed_fits = freed.fit_sequence(tracks)?;
        &freed_fits
    } else {
        fits
    };
    let Some(Start {
        hinges: start,
        zero,
        cam_parent,
        reference,
        ..
    }) = two_hinge_start(model, (parent, child), reference, posed, limits)
    else {
        return Ok(None);
    };
    let body = model.bodies.len();
    insert_link(model, k, body, &start, &zero, &cam_parent, reference);
    let mut observer = Observer::new(model)?;
    let mut fits = observer.fit_sequence(tracks)?;
    if let Some(adjusted) = adjust_model(model, &observer, tracks, &fits, &limits.bundle, None)? {
        (observer, fits) = adjusted;
    }
    let excess = observer.joint_excess(tracks, &fits)?;
    let followed = excess[k + 1].is_some_and(|e| e <= limits.max_excess)
        && !any_above(&excess, limits.others_max_excess);
    let offset = line_distance(&observer, k);
    if !followed || offset.is_none_or(|d| d < limits.min_offset_in_sigma * sigma) {
        return Ok(None);
    }
    // A universal joint is two hinges whose axes meet: the hinges' one more parameter, the
    // axes' distance, must lower the squared residual by more than chance would.
    let gain = (before - fits.iter().map(|f| f.sum_sq_m2).sum::<f64>()) / (sigma * sigma);
    if universal && gain < limits.min_gain_over_universal {
        return Ok(None);
    }
    model.bodies[body].frames_registered = fits
        .iter()
        .filter(|f| f.poses.get(body).copied().flatten().is_some())
        .count();
    let this = |p: &usize, c: &usize| *p == parent && *c == child;
    model
        .warnings
        .retain(|w| !matches!(w, Warning::MultiDofJoint { parent: p, child: c, .. } if this(p, c)));
    let without_points = model.clone();
    let points = give_points(model, tracks, body)?;
    let mut state = FitState::new(model, tracks)?;
    if !points.is_empty() {
        // The link's keypoints must leave the fit following every joint as before.
        let excess = state.observer().joint_excess(tracks, state.fits())?;
        if excess[k + 1].is_none_or(|e| e > limits.max_excess)
            || any_above(&excess, limits.others_max_excess)
        {
            *model = without_points;
            state = FitState::new(model, tracks)?;
        }
    }
    let points = model.bodies[body].points.clone();
    for w in &mut model.warnings {
        if let Warning::UnseenLink {
            body: b,
            offset_m,
            points: p,
            ..
        } = w
            && *b == body
        {
            *offset_m = offset.unwrap_or(0.0);
            *p = points.clone();
        }
    }
    Ok(Some(state))
}

/// Two hinges fitted to a child's motion against a parent, as [`try_link`] starts from them.
struct Start {
    hinges: TwoHinges,
    /// `parent_from_child` at the reference frame.
    zero: Isometry3<f64>,
    /// The parent's pose at the reference frame.
    cam_parent: Isometry3<f64>,
    reference: usize,
    /// The child's placed keypoints' RMS miss through the two hinges, metres.
    rms_m: f64,
}

/// The two-hinge start of `child` on `parent` from their poses in `posed`, its reference
/// frame `reference` where both are posed there (else the first frame both are); `None` with
/// fewer than `limits.min_frames` such frames, hinges nearly parallel or meeting (see
/// [`UnseenLinkLimits`]), or a miss of the child's keypoints beyond
/// `limits.max_start_rms_in_sigma`.
fn two_hinge_start(
    model: &Model,
    (parent, child): (usize, usize),
    reference: usize,
    posed: &[FrameFit],
    limits: &UnseenLinkLimits,
) -> Option<Start> {
    let sigma = model.noise.sigma_m;
    let relative: Vec<(usize, Isometry3<f64>)> = posed
        .iter()
        .enumerate()
        .filter_map(|(t, f)| {
            let p = f.poses.get(parent).copied().flatten()?;
            let c = f.poses.get(child).copied().flatten()?;
            Some((t, p.inverse() * c))
        })
        .collect();
    if relative.len() < limits.min_frames.max(8) {
        return None;
    }
    let &(reference, zero) = relative
        .iter()
        .find(|(t, _)| *t == reference)
        .or(relative.first())?;
    let cam_parent = posed
        .get(reference)
        .and_then(|f| f.poses.get(parent).copied().flatten())?;
    let motions: Vec<Isometry3<f64>> = relative.iter().map(|(_, x)| x * zero.inverse()).collect();
    let start = two_hinges(&motions, &zero)?;
    if start.axes_angle_deg() < limits.min_axes_angle_deg
        || start.offset() < limits.min_offset_in_sigma * sigma
    {
        return None;
    }
    // The start's miss of the child's placed keypoints, every frame with both poses.
    let shape: Vec<Point3<f64>> = model.bodies[child]
        .shape
        .iter()
        .flatten()
        .map(|s| Point3::from(Vector3::from(*s)))
        .collect();
    if shape.is_empty() {
        return None;
    }
    let (mut sum, mut count) = (0.0, 0usize);
    for ((_, x), angles) in relative.iter().zip(&start.angles) {
        let predicted = start.motion(angles) * zero;
        for s in &shape {
            sum += (predicted * s - x * s).norm_squared();
            count += 1;
        }
    }
    let rms_m = (sum / count as f64).sqrt();
    (rms_m <= limits.max_start_rms_in_sigma * sigma).then_some(Start {
        hinges: start,
        zero,
        cam_parent,
        reference,
        rms_m,
    })
}

/// Gives the link `body` of `model` the keypoints whose tracks its fitted motion explains
/// clearly best ([`FittedMotions::points_for_body`]; a link seen in a few frames by a few
/// keypoints), each placed at its mean position in the link's frame; keypoints shared by
/// two bodies stay where they are. Returns them.
pub(crate) fn give_points(model: &mut Model, tracks: &Tracks, body: usize) -> Result<Vec<usize>> {
    let motions = FittedMotions::new(model, tracks)?;
    let points: Vec<usize> = motions
        .points_for_body(model, tracks, body)?
        .into_iter()
        .filter(|&i| !model.shared_points.iter().any(|s| s[0] == i))
        .collect();
    let poses = &motions.into_fitted().body_poses[body];
    for &i in &points {
        let seen = in_body_frame(poses, tracks, i);
        let place = seen.iter().sum::<Vector3<f64>>() / seen.len().max(1) as f64;
        if let Ok(old) = usize::try_from(model.point_body[i])
            && let Some(b) = model.bodies.get_mut(old)
            && let Some(at) = b.points.iter().position(|&p| p == i)
        {
            b.points.remove(at);
            if at < b.shape.len() {
                b.shape.remove(at);
            }
        }
        model.point_body[i] = body as i64;
        let link = &mut model.bodies[body];
        let at = link.points.partition_point(|&p| p < i);
        link.points.insert(at, i);
        link.shape.insert(at, Some([place.x, place.y, place.z]));
    }
    Ok(points)
}

/// Shortest distance between the axes of the observer's revolute joints `k` and `k + 1`, in
/// the frame of joint `k`'s parent at the reference pose (the link's frame there).
fn line_distance(observer: &Observer, k: usize) -> Option<f64> {
    let first = JointParams::of(observer.joints.get(k)?)?;
    let second = JointParams::of(observer.joints.get(k + 1)?)?;
    Some(axes_distance(
        &first.axis,
        &first.pivot,
        &second.axis,
        &second.pivot,
    ))
}

/// Shortest distance between the line through `p` along `a` and the one through `q` along
/// `b` (unit directions).
fn axes_distance(a: &Vector3<f64>, p: &Point3<f64>, b: &Vector3<f64>, q: &Point3<f64>) -> f64 {
    let normal = a.cross(b);
    let d = q - p;
    if normal.norm() > 1e-9 {
        d.dot(&normal).abs() / normal.norm()
    } else {
        (d - a * a.dot(&d)).norm()
    }
}

/// Two hinges fitted to a pair's motions: both axes and pivots in the parent's frame at the
/// reference pose, and each frame's angles.
#[derive(Debug, Clone)]
struct TwoHinges {
    first: Vector3<f64>,
    first_pivot: Point3<f64>,
    second: Vector3<f64>,
    second_pivot: Point3<f64>,
    angles: Vec<[f64; 2]>,
}

impl TwoHinges {
    /// The child's motion from its reference pose at `angles`: about the second hinge, then
    /// about the first.
    fn motion(&self, angles: &[f64; 2]) -> Isometry3<f64> {
        turn_about(&self.first, &self.first_pivot, angles[0])
            * turn_about(&self.second, &self.second_pivot, angles[1])
    }

    fn axes_angle_deg(&self) -> f64 {
        self.first
            .dot(&self.second)
            .abs()
            .min(1.0)
            .acos()
            .to_degrees()
    }

    fn offset(&self) -> f64 {
        axes_distance(
            &self.first,
            &self.first_pivot,
            &self.second,
            &self.second_pivot,
        )
    }
}

/// The rotation by `q` about the line through `pivot` along the unit `axis`.
pub(crate) fn turn_about(axis: &Vector3<f64>, pivot: &Point3<f64>, q: f64) -> Isometry3<f64> {
    let r =
        UnitQuaternion::from_axis_angle(&kinetree_core::nalgebra::Unit::new_unchecked(*axis), q);
    Isometry3::from_parts((pivot.coords - r * pivot.coords).into(), r)
}

/// Two hinges fitted to `motions` (each frame's child motion from the reference pose `zero`,
/// in the parent's frame; see the module's doc); `None` when the motions do not fix them.
fn two_hinges(motions: &[Isometry3<f64>], zero: &Isometry3<f64>) -> Option<TwoHinges> {
    let turns: Vec<Matrix3<f64>> = motions
        .iter()
        .map(|m| m.rotation.to_rotation_matrix().into_inner() - Matrix3::identity())
        .collect();
    let (first, second) = two_axes(&turns)?;
    let angles: Vec<[f64; 2]> = motions
        .iter()
        .map(|m| universal_angles(&m.rotation, &first, &second))
        .collect();
    // (I - R_1) p_1 + R_1 (I - R_2) p_2 = d_t in least squares; each pivot is free along its
    // axis, where a ridge holds it level with the midpoint of the two bodies' origins.
    let mut normal = Matrix6::<f64>::zeros();
    let mut rhs = Vector6::<f64>::zeros();
    for (m, q) in motions.iter().zip(&angles) {
        let r1 = turn_about(&first, &Point3::origin(), q[0]).rotation;
        let r2 = turn_about(&second, &Point3::origin(), q[1]).rotation;
        let r1 = r1.to_rotation_matrix().into_inner();
        let r2 = r2.to_rotation_matrix().into_inner();
        let a = Matrix3::identity() - r1;
        let b = r1 * (Matrix3::identity() - r2);
        let mut row = kinetree_core::nalgebra::Matrix3x6::<f64>::zeros();
        row.fixed_view_mut::<3, 3>(0, 0).copy_from(&a);
        row.fixed_view_mut::<3, 3>(0, 3).copy_from(&b);
        normal += row.transpose() * row;
        rhs += row.transpose() * m.translation.vector;
    }
    let scale = normal.trace() / 6.0;
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let middle = zero.translation.vector / 2.0;
    let mut ridge = Matrix6::<f64>::zeros();
    ridge
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(first * first.transpose() * scale));
    ridge
        .fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(second * second.transpose() * scale));
    let mut target = Vector6::<f64>::zeros();
    target
        .fixed_rows_mut::<3>(0)
        .copy_from(&(first * first.dot(&middle)));
    target
        .fixed_rows_mut::<3>(3)
        .copy_from(&(second * second.dot(&middle)));
    let system = normal + ridge;
    let eigen = system.symmetric_eigen();
    if eigen.eigenvalues.min() < 1e-9 * eigen.eigenvalues.max() {
        return None;
    }
    let pivots = system.cholesky()?.solve(&(rhs + ridge * target));
    Some(TwoHinges {
        first,
        first_pivot: Point3::from(pivots.fixed_rows::<3>(0).into_owned()),
        second,
        second_pivot: Point3::from(pivots.fixed_rows::<3>(3).into_owned()),
        angles,
    })
}

/// The unit axes `(a_1, a_2)` minimising `sum_t (a_1 . M_t a_2)^2` over `turns` (`M_t =
/// D_t - I`): a coarse search over `a_1`, each with its best `a_2` (the smallest eigenvector
/// of `sum (M_t^T a_1)(M_t^T a_1)^T`), then alternating steps from the best few. `None`
/// with fewer than eight frames.
fn two_axes(turns: &[Matrix3<f64>]) -> Option<(Vector3<f64>, Vector3<f64>)> {
    if turns.len() < 8 {
        return None;
    }
    let smallest = |vectors: &mut dyn Iterator<Item = Vector3<f64>>| {
        let scatter: Matrix3<f64> = vectors.map(|v| v * v.transpose()).sum();
        let e = scatter.symmetric_eigen();
        let i = e.eigenvalues.imin();
        (e.eigenvectors.column(i).into_owned(), e.eigenvalues[i])
    };
    let best_second = |a: &Vector3<f64>| smallest(&mut turns.iter().map(|m| m.transpose() * a));
    let best_first = |b: &Vector3<f64>| smallest(&mut turns.iter().map(|m| m * b));
    let mut scored: Vec<(f64, Vector3<f64>)> = hemisphere(AXES_GRID)
        .into_iter()
        .map(|a| (best_second(&a).1, a))
        .filter(|(s, _)| s.is_finite())
        .collect();
    scored.sort_by(|x, y| x.0.total_cmp(&y.0));
    let separation = 10f64.to_radians().cos();
    let mut starts: Vec<Vector3<f64>> = Vec::new();
    for (_, a) in scored {
        if starts.len() == AXES_STARTS {
            break;
        }
        if starts.iter().all(|s| s.dot(&a).abs() < separation) {
            starts.push(a);
        }
    }
    let mut best: Option<(f64, Vector3<f64>, Vector3<f64>)> = None;
    for mut a in starts {
        let (mut b, mut value) = best_second(&a);
        for _ in 0..AXES_ROUNDS {
            a = best_first(&b).0;
            (b, value) = best_second(&a);
        }
        if best.is_none_or(|x| value < x.0) {
            best = Some((value, a, b));
        }
    }
    best.map(|(_, a, b)| (a, b))
}

/// Puts body `body` (without points) between joint `k`'s parent and child: joint `k` becomes
/// the first hinge (parent to the link, whose frame is the parent's at the reference pose),
/// and the second (link to child) follows it.
fn insert_link(
    model: &mut Model,
    k: usize,
    body: usize,
    hinges: &TwoHinges,
    zero: &Isometry3<f64>,
    cam_parent: &Isometry3<f64>,
    reference: usize,
) {
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    model.bodies.push(link_body(body, parent));
    model.bodies[child].parent = Some(body);
    // The warning names the link from the start: the fit holds its frame (its offset and
    // keypoints are written once it is kept).
    model.warnings.push(Warning::UnseenLink {
        parent,
        body,
        child,
        offset_m: 0.0,
        points: Vec::new(),
    });
    if let Some(chain) = model.chain.as_mut()
        && let Some(at) = chain.iter().position(|&b| b == child)
    {
        chain.insert(at, body);
    }
    let mut first = model.joints[k].clone();
    first.child = body;
    first.joint_type = JointType::Revolute;
    first.dof = 1;
    first.fit = JointFit::TypedByFit;
    first.reference_frame = reference;
    clear_coordinates(&mut first);
    let mut second = first.clone();
    second.parent = body;
    second.child = child;
    store_joint(
        &mut first,
        &JointParams {
            axis: hinges.first,
            pivot: hinges.first_pivot,
            reference: Isometry3::identity(),
            revolute: true,
        },
        cam_parent,
    );
    store_joint(
        &mut second,
        &JointParams {
            axis: hinges.second,
            pivot: hinges.second_pivot,
            reference: *zero,
            revolute: true,
        },
        cam_parent,
    );
    model.joints[k] = first;
    model.joints.insert(k + 1, second);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_hinges_are_read_back_from_their_motions() {
        // Two skew hinges 4 cm apart, 60 deg between them, turned through a Lissajous path.
        let first = Vector3::new(0.3, -0.2, 0.9).normalize();
        let second = Vector3::new(0.8, 0.5, -0.1).normalize();
        let (p1, p2) = (Point3::new(0.01, 0.02, 0.1), Point3::new(-0.02, 0.01, 0.14));
        let zero = Isometry3::translation(0.0, 0.0, 0.25);
        let truth = TwoHinges {
            first,
            first_pivot: p1,
            second,
            second_pivot: p2,
            angles: Vec::new(),
        };
        let motions: Vec<Isometry3<f64>> = (0..60)
            .map(|t| {
                let t = t as f64 * 0.1;
                truth.motion(&[0.5 * (0.7 * t).sin(), 0.4 * (1.3 * t + 0.5).sin()])
            })
            .collect();
        let found = two_hinges(&motions, &zero).expect("fitted");
        assert!(found.first.dot(&first).abs() > 1.0 - 1e-9, "first axis");
        assert!(found.second.dot(&second).abs() > 1.0 - 1e-9, "second axis");
        assert!((found.offset() - truth.offset()).abs() < 1e-9, "offset");
        for (m, a) in motions.iter().zip(&found.angles) {
            let back = found.motion(a);
            assert!((back.translation.vector - m.translation.vector).norm() < 1e-9);
            assert!(back.rotation.angle_to(&m.rotation) < 1e-9);
        }
    }
}
