//! Hidden hubs: a link too little seen to pose that carries several seen children. Two
//! children of one link whose joints meet at one point (a link's end) move against each other
//! about two axes through that point, which the tree takes for a universal joint between
//! them; the link itself gets no body, so its own joint is lost and the children hang on each
//! other. The universal joint's cross, the frame its first angle turns, moves as that link
//! does. So a universal joint whose cross moves against some other body with one degree of
//! freedom is read as a link: the cross becomes a body without keypoints, hung on that body by
//! a hinge or a slide, with the two children on it by hinges; it is kept when the whole-tree
//! fit follows every joint. Other children of the link that hang elsewhere by a joint the fit
//! cannot follow, or by a universal or multi-DoF joint, are then tried on it by the same test.

use crate::policy::{FitState, adjust_model, any_above, clear_coordinates, store_joint};
use crate::refine::JointParams;
use crate::solver::{FrameFit, Measure, Observer};
use crate::unseen::{
    UnseenLinkLimits, edges, forget_joint_warnings, give_points, joint_between, link_body, subtree,
    turn_about,
};
use kinetree_core::geom::angle_about;
use kinetree_core::model::{JointFit, JointType};
use kinetree_core::nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use kinetree_core::{Model, Result, Tracks, Warning};

/// Every universal joint of `model` whose cross moves against another body with one degree of
/// freedom, as the fit follows it, becomes a link without keypoints (appended to
/// `model.bodies`) on that body, with both of the joint's bodies on the link by hinges; other
/// bodies whose joints are multi-DoF, universal or not followed are moved onto a link put in
/// when the fit follows them there. Each link gets an `unseen_link` warning and the keypoints
/// its fitted motion explains clearly best. Returns the links put in. The positions are not
/// written: the caller writes them from a fit of the new model.
///
/// # Errors
/// As [`Observer::new`] and [`Observer::fit_sequence`].
pub fn unseen_hubs(
    model: &mut Model,
    tracks: &Tracks,
    limits: &UnseenLinkLimits,
) -> Result<Vec<usize>> {
    let crosses = edges(model, |j| {
        j.joint_type == JointType::Universal && joint_above(model, j.parent).is_some()
    });
    let mut added = Vec::new();
    if crosses.is_empty() {
        return Ok(added);
    }
    let mut state = FitState::new(model, tracks)?;
    for (parent, child) in crosses {
        let Some(k) = joint_between(model, parent, child)
            .filter(|&k| model.joints[k].joint_type == JointType::Universal)
        else {
            continue;
        };
        let mut trial = model.clone();
        if let Some(kept) = try_hub(&mut trial, k, tracks, &state, limits)? {
            *model = trial;
            state = kept;
            let hub = model.bodies.len() - 1;
            added.push(hub);
            state = adopt_children(model, hub, tracks, state, limits)?;
        }
    }
    for &hub in &added {
        let without_points = model.clone();
        if give_points(model, tracks, hub)?.is_empty() {
            continue;
        }
        // The link's keypoints must leave the fit following every joint.
        let kept = FitState::new(model, tracks)?;
        let excess = kept.observer().joint_excess(tracks, kept.fits())?;
        if any_above(&excess, limits.others_max_excess) {
            *model = without_points;
        }
    }
    for &hub in &added {
        let points = model.bodies[hub].points.clone();
        for w in &mut model.warnings {
            if let Warning::UnseenLink {
                body, points: p, ..
            } = w
                && *body == hub
            {
                p.clone_from(&points);
            }
        }
    }
    Ok(added)
}

/// One degree of freedom fitted to a body's motions against another: the joint's parameters
/// in the parent's frame, the reference frame, and the probes' RMS miss, metres.
#[derive(Debug, Clone, Copy)]
struct OneDof {
    params: JointParams,
    reference_frame: usize,
    rms_m: f64,
}

/// The hinge or slide that best carries `probes` (points in the child's frame) through
/// `motions` (`(frame, parent_from_child)`): a hinge's axis is the principal direction of the
/// rotations from the first frame's pose, its pivot the least-squares point the translations
/// turn about; a slide's axis the principal direction of the translations. `None` with fewer
/// than eight frames.
fn one_dof(motions: &[(usize, Isometry3<f64>)], probes: &[Point3<f64>]) -> Option<OneDof> {
    let &(reference_frame, zero) = motions.first()?;
    if motions.len() < 8 || probes.is_empty() {
        return None;
    }
    let steps: Vec<Isometry3<f64>> = motions.iter().map(|(_, m)| m * zero.inverse()).collect();
    let principal = |vectors: &mut dyn Iterator<Item = Vector3<f64>>| {
        let scatter: Matrix3<f64> = vectors.map(|v| v * v.transpose()).sum();
        let e = scatter.symmetric_eigen();
        e.eigenvectors.column(e.eigenvalues.imax()).into_owned()
    };
    let axis = principal(&mut steps.iter().map(|s| s.rotation.scaled_axis()));
    // (I - R_t) p = d_t in least squares, the pivot level with the reference pose's origin
    // along the axis.
    let mut normal = Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    let angles: Vec<f64> = steps
        .iter()
        .map(|s| angle_about(&s.rotation, &axis))
        .collect();
    for (s, &q) in steps.iter().zip(&angles) {
        let a = Matrix3::identity()
            - turn_about(&axis, &Point3::origin(), q)
                .rotation
                .to_rotation_matrix()
                .into_inner();
        normal += a.transpose() * a;
        rhs += a.transpose() * s.translation.vector;
    }
    let scale = normal.trace() / 3.0;
    let along = axis * axis.dot(&zero.translation.vector);
    let system = normal + axis * axis.transpose() * scale.max(f64::MIN_POSITIVE);
    let pivot = system
        .cholesky()
        .map(|c| Point3::from(c.solve(&(rhs + along * scale.max(f64::MIN_POSITIVE)))));
    let slide = principal(&mut steps.iter().map(|s| s.translation.vector));
    // The probes' RMS miss with the joint at `positions`, one a motion.
    let miss = |params: &JointParams, positions: &[f64]| {
        let mut sum = 0.0;
        for ((_, m), &q) in motions.iter().zip(positions) {
            let predicted = params.transform(q);
            for p in probes {
                sum += (predicted * p - m * p).norm_squared();
            }
        }
        (sum / (motions.len() * probes.len()) as f64).sqrt()
    };
    let mut best: Option<OneDof> = None;
    if let Some(pivot) = pivot {
        let params = JointParams {
            axis,
            pivot,
            reference: zero,
            revolute: true,
        };
        let rms_m = miss(&params, &angles);
        best = Some(OneDof {
            params,
            reference_frame,
            rms_m,
        });
    }
    let params = JointParams {
        axis: slide,
        pivot: Point3::origin(),
        reference: zero,
        revolute: false,
    };
    let shifts: Vec<f64> = motions
        .iter()
        .map(|(_, m)| slide.dot(&(m.translation.vector - zero.translation.vector)))
        .collect();
    let rms_m = miss(&params, &shifts);
    if best.is_none_or(|b| rms_m < b.rms_m) {
        best = Some(OneDof {
            params,
            reference_frame,
            rms_m,
        });
    }
    best.filter(|b| b.rms_m.is_finite())
}

/// The joint carrying `body` when it is one the fit cannot stand by (multi-DoF, universal,
/// rigid, or not followed): a link's joint and its first hinge may replace it.
fn joint_above(model: &Model, body: usize) -> Option<usize> {
    model.joints.iter().position(|j| {
        j.child == body
            && (matches!(
                j.joint_type,
                JointType::MultiDof | JointType::Universal | JointType::Rigid
            ) || j.fit == JointFit::Freed)
    })
}

/// The best one-DoF parent, among the bodies `allowed`, of a body posed at `poses` (one per
/// frame), with the probes in its frame; `None` when none carries them within
/// `max_rms_m`.
fn best_parent(
    fits: &[FrameFit],
    poses: &[Option<Isometry3<f64>>],
    allowed: &[bool],
    probes: &[Point3<f64>],
    min_frames: usize,
    max_rms_m: f64,
) -> Option<(usize, OneDof)> {
    let mut best: Option<(usize, OneDof)> = None;
    for (b, _) in allowed.iter().enumerate().filter(|(_, a)| **a) {
        let motions: Vec<(usize, Isometry3<f64>)> = fits
            .iter()
            .zip(poses)
            .enumerate()
            .filter_map(|(t, (f, pose))| {
                let parent = f.poses.get(b).copied().flatten()?;
                Some((t, parent.inverse() * (*pose)?))
            })
            .collect();
        if motions.len() < min_frames.max(8) {
            continue;
        }
        let Some(fit) = one_dof(&motions, probes) else {
            continue;
        };
        if fit.rms_m <= max_rms_m && best.as_ref().is_none_or(|(_, x)| fit.rms_m < x.rms_m) {
            best = Some((b, fit));
        }
    }
    best
}

/// The centroid of body `b`'s placed keypoints in its own frame.
fn centroid(model: &Model, b: usize) -> Option<Point3<f64>> {
    let shape: Vec<Vector3<f64>> = model.bodies[b]
        .shape
        .iter()
        .flatten()
        .map(|s| Vector3::from(*s))
        .collect();
    (!shape.is_empty())
        .then(|| Point3::from(shape.iter().sum::<Vector3<f64>>() / shape.len() as f64))
}

/// A new joint from `parent` to `child`, `template`'s fields cleared, with `params` stored
/// against the parent's pose `cam_parent` at `reference_frame`.
fn new_joint(
    template: &kinetree_core::model::Joint,
    (parent, child): (usize, usize),
    params: &JointParams,
    reference_frame: usize,
    cam_parent: &Isometry3<f64>,
) -> kinetree_core::model::Joint {
    let mut j = template.clone();
    j.parent = parent;
    j.child = child;
    j.joint_type = if params.revolute {
        JointType::Revolute
    } else {
        JointType::Prismatic
    };
    j.dof = 1;
    j.fit = JointFit::TypedByFit;
    j.reference_frame = reference_frame;
    j.point = None;
    j.point_in_parent = None;
    clear_coordinates(&mut j);
    store_joint(&mut j, params, cam_parent);
    j
}

/// Fits `model` (changed) and keeps it when the fit follows every joint: those in `new`
/// within `limits.max_excess`, the others within `limits.others_max_excess`.
fn followed(
    model: &mut Model,
    tracks: &Tracks,
    new: &[usize],
    limits: &UnseenLinkLimits,
) -> Result<Option<FitState>> {
    let mut observer = Observer::new(model)?;
    let mut fits = observer.fit_sequence(tracks)?;
    if let Some(adjusted) = adjust_model(model, &observer, tracks, &fits, &limits.bundle, None)? {
        (observer, fits) = adjusted;
    }
    let excess = observer.joint_excess(tracks, &fits)?;
    let ok = new.iter().all(|&k| {
        excess
            .get(k)
            .copied()
            .flatten()
            .is_some_and(|e| e <= limits.max_excess)
    }) && !any_above(&excess, limits.others_max_excess);
    Ok(ok.then(|| FitState::of(model, observer, fits)))
}

/// Universal joint `k` of `model` read as a link (see [`unseen_hubs`]); the model keeps it and
/// the fit is returned when the fit follows it.
fn try_hub(
    model: &mut Model,
    k: usize,
    tracks: &Tracks,
    state: &FitState,
    limits: &UnseenLinkLimits,
) -> Result<Option<FitState>> {
    let sigma = model.noise.sigma_m;
    let (observer, fits) = (state.observer(), state.fits());
    let Some(cross) = observer.joints.get(k) else {
        return Ok(None);
    };
    let Measure::Universal(first, second, centre) = cross.measure else {
        return Ok(None);
    };
    if observer.freed.get(k).copied().unwrap_or(true) {
        return Ok(None);
    }
    let (s1, s2) = (cross.parent, cross.child);
    let Some(above) = joint_above(model, s1) else {
        return Ok(None);
    };
    // The cross: the first body turned by the first angle about the first axis.
    let hub: Vec<Option<Isometry3<f64>>> = fits
        .iter()
        .map(|f| {
            let p = f.poses.get(s1).copied().flatten()?;
            let q = f.angles.get(k).copied().flatten()?;
            Some(p * turn_about(&first, &centre, q[0]))
        })
        .collect();
    let mut probes = vec![centre];
    probes.extend(centroid(model, s1));
    probes.extend(centroid(model, s2).map(|c| cross.reference * c));
    let allowed: Vec<bool> = subtree(model, s1).iter().map(|b| !b).collect();
    let Some((parent, fit)) = best_parent(
        fits,
        &hub,
        &allowed,
        &probes,
        limits.min_frames,
        limits.max_start_rms_in_sigma * sigma,
    ) else {
        return Ok(None);
    };
    let r = fit.reference_frame;
    let (Some(cam_parent), Some(cam_hub)) = (
        fits.get(r)
            .and_then(|f| f.poses.get(parent).copied().flatten()),
        hub.get(r).copied().flatten(),
    ) else {
        return Ok(None);
    };
    let id = model.bodies.len();
    model.bodies.push(link_body(id, parent));
    model.bodies[s1].parent = Some(id);
    model.bodies[s2].parent = Some(id);
    let template = model.joints[k].clone();
    let to_hub = new_joint(&template, (parent, id), &fit.params, r, &cam_parent);
    let first_hinge = JointParams {
        axis: first,
        pivot: centre,
        reference: Isometry3::identity(),
        revolute: true,
    };
    let to_first = new_joint(&template, (id, s1), &first_hinge, r, &cam_hub);
    let second_hinge = JointParams {
        axis: second,
        pivot: centre,
        reference: cross.reference,
        revolute: true,
    };
    let to_second = new_joint(&template, (id, s2), &second_hinge, r, &cam_hub);
    let old_parent = model.joints[above].parent;
    for i in [above.max(k), above.min(k)] {
        model.joints.remove(i);
    }
    forget_joint_warnings(model, old_parent, s1);
    forget_joint_warnings(model, s1, s2);
    let n = model.joints.len();
    model.joints.extend([to_hub, to_first, to_second]);
    model.chain = None;
    model.warnings.push(Warning::UnseenLink {
        parent,
        body: id,
        child: s1,
        offset_m: 0.0,
        points: Vec::new(),
    });
    // The link has no keypoints of its own: its children's keypoints judge its joint too.
    let kept = followed(model, tracks, &[n + 1, n + 2], limits)?;
    if let Some(state) = &kept {
        model.bodies[id].frames_registered = state
            .fits()
            .iter()
            .filter(|f| f.poses.get(id).copied().flatten().is_some())
            .count();
    }
    Ok(kept)
}

/// Moves onto `hub` (a link put in) each body whose joint is multi-DoF, universal or not
/// followed and whose motion against the link is one-DoF, when the fit follows it there
/// (unless `limits.rehang` is off).
pub(crate) fn adopt_children(
    model: &mut Model,
    hub: usize,
    tracks: &Tracks,
    state: FitState,
    limits: &UnseenLinkLimits,
) -> Result<FitState> {
    let doubtful = |j: &kinetree_core::model::Joint| {
        matches!(j.joint_type, JointType::MultiDof | JointType::Universal)
            || j.fit == JointFit::Freed
    };
    let onto_hub = |m: &Model, _: usize, child: usize| {
        let below = subtree(m, child);
        (!below.get(hub).copied().unwrap_or(true)).then(|| {
            let mut allowed = vec![false; m.bodies.len()];
            allowed[hub] = true;
            allowed
        })
    };
    rehang_each(model, doubtful, onto_hub, tracks, state, limits)
}

/// Moves the child of each multi-DoF joint of `model` onto the body, outside its subtree,
/// against which the whole-tree fit moves it by one hinge or slide, when the fit follows it
/// there (unless `limits.rehang` is off): the pair tests judged the child from poses of its
/// own, which may have been too poor to find that joint.
pub(crate) fn rehang_multi_dof(
    model: &mut Model,
    tracks: &Tracks,
    state: FitState,
    limits: &UnseenLinkLimits,
) -> Result<FitState> {
    let multi = |j: &kinetree_core::model::Joint| j.joint_type == JointType::MultiDof;
    let elsewhere = |m: &Model, parent: usize, child: usize| {
        let mut allowed: Vec<bool> = subtree(m, child).iter().map(|b| !b).collect();
        allowed[parent] = false;
        Some(allowed)
    };
    rehang_each(model, multi, elsewhere, tracks, state, limits)
}

/// Each joint of `model` that `which` picks, in order, tried with its child on the bodies
/// `allowed` names for it (given the model then, the parent and the child; `None` skips it),
/// by [`try_rehang`] (unless `limits.rehang` is off). Returns the fit of the final model.
fn rehang_each(
    model: &mut Model,
    which: impl Fn(&kinetree_core::model::Joint) -> bool,
    allowed: impl Fn(&Model, usize, usize) -> Option<Vec<bool>>,
    tracks: &Tracks,
    mut state: FitState,
    limits: &UnseenLinkLimits,
) -> Result<FitState> {
    if !limits.rehang {
        return Ok(state);
    }
    for (parent, child) in edges(model, which) {
        let Some(k) = joint_between(model, parent, child) else {
            continue;
        };
        let Some(allowed) = allowed(model, parent, child) else {
            continue;
        };
        if let Some(kept) = try_rehang(model, k, &allowed, tracks, &state, limits)? {
            state = kept;
        }
    }
    Ok(state)
}

/// Joint `k`'s child hung on the best of the `allowed` bodies by one hinge or slide fitted to
/// its motion in `state`'s fit (its placed keypoints the probes); `model` keeps it and the fit
/// is returned when the fit follows it.
fn try_rehang(
    model: &mut Model,
    k: usize,
    allowed: &[bool],
    tracks: &Tracks,
    state: &FitState,
    limits: &UnseenLinkLimits,
) -> Result<Option<FitState>> {
    let sigma = model.noise.sigma_m;
    let (parent, child) = (model.joints[k].parent, model.joints[k].child);
    let fits = state.fits();
    let poses: Vec<Option<Isometry3<f64>>> = fits
        .iter()
        .map(|f| f.poses.get(child).copied().flatten())
        .collect();
    let probes: Vec<Point3<f64>> = model.bodies[child]
        .shape
        .iter()
        .flatten()
        .map(|s| Point3::from(Vector3::from(*s)))
        .collect();
    let Some((to, fit)) = best_parent(
        fits,
        &poses,
        allowed,
        &probes,
        limits.min_frames,
        limits.max_start_rms_in_sigma * sigma,
    ) else {
        return Ok(None);
    };
    let Some(cam_to) = fits
        .get(fit.reference_frame)
        .and_then(|f| f.poses.get(to).copied().flatten())
    else {
        return Ok(None);
    };
    let mut trial = model.clone();
    let joint = new_joint(
        &trial.joints[k],
        (to, child),
        &fit.params,
        fit.reference_frame,
        &cam_to,
    );
    trial.joints[k] = joint;
    trial.bodies[child].parent = Some(to);
    trial.chain = None;
    forget_joint_warnings(&mut trial, parent, child);
    let kept = followed(&mut trial, tracks, &[k], limits)?;
    if kept.is_some() {
        *model = trial;
    }
    Ok(kept)
}
#[cfg(test)]
mod tests {
    use super::*;

    fn probes() -> Vec<Point3<f64>> {
        vec![
            Point3::new(0.05, 0.0, 0.0),
            Point3::new(0.0, 0.08, 0.01),
            Point3::new(-0.02, 0.01, 0.1),
        ]
    }

    #[test]
    fn a_hinge_is_read_back_from_its_motions() {
        let axis = Vector3::new(0.2, -0.5, 0.8).normalize();
        let pivot = Point3::new(0.1, -0.05, 0.3);
        let zero = Isometry3::translation(0.02, 0.1, 0.35);
        let motions: Vec<(usize, Isometry3<f64>)> = (0..40)
            .map(|t| {
                let q = 0.9 * (0.2 * t as f64).sin();
                (t, turn_about(&axis, &pivot, q) * zero)
            })
            .collect();
        let found = one_dof(&motions, &probes()).expect("fitted");
        assert!(found.params.revolute);
        assert!(found.params.axis.dot(&axis).abs() > 1.0 - 1e-9);
        // The pivot lies on the true axis line.
        let off = (found.params.pivot - pivot) - axis * axis.dot(&(found.params.pivot - pivot));
        assert!(off.norm() < 1e-9, "pivot {} off the axis", off.norm());
        assert!(found.rms_m < 1e-9, "rms {}", found.rms_m);
    }

    #[test]
    fn a_slide_is_read_back_and_a_free_motion_misses() {
        let axis = Vector3::new(0.6, 0.0, -0.8);
        let zero = Isometry3::translation(0.0, 0.2, 0.4);
        let slide: Vec<(usize, Isometry3<f64>)> = (0..40)
            .map(|t| {
                let s = 0.1 * (0.15 * t as f64).cos();
                (
                    t,
                    Isometry3::translation(axis.x * s, axis.y * s, axis.z * s) * zero,
                )
            })
            .collect();
        let found = one_dof(&slide, &probes()).expect("fitted");
        assert!(!found.params.revolute);
        assert!(found.params.axis.dot(&axis).abs() > 1.0 - 1e-9);
        assert!(found.rms_m < 1e-9, "rms {}", found.rms_m);
        // Two hinges far apart: no single hinge or slide carries the probes.
        let (a, b) = (Vector3::x(), Vector3::z());
        let (p, q) = (Point3::origin(), Point3::new(0.0, 0.2, 0.0));
        let two: Vec<(usize, Isometry3<f64>)> = (0..40)
            .map(|t| {
                let t = t as f64;
                let m = turn_about(&a, &p, 0.6 * (0.2 * t).sin())
                    * turn_about(&b, &q, 0.7 * (0.33 * t + 1.0).sin());
                (t as usize, m * zero)
            })
            .collect();
        let missed = one_dof(&two, &probes()).expect("fitted");
        assert!(missed.rms_m > 0.01, "rms {}", missed.rms_m);
    }
}
