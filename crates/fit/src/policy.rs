//! The fit's policy on a model: joints the whole-tree fit cannot follow freed, the followed
//! ones bundle-adjusted ([`crate::bundle`]), freed joints refined alone ([`crate::refine`])
//! and readmitted when they fit again, multi-DoF joints typed by the fit; then the positions,
//! their precision, their smoothing and every joint's range written into the model.

use crate::solver::{FrameFit, Measure, Observer, rms_in_sigma};
use kinetree_core::model::JointType;
use kinetree_core::nalgebra::{Isometry3, Matrix3, Point3, UnitQuaternion, Vector3};
use kinetree_core::{Model, Result, Tracks, Warning};
use rayon::prelude::*;

/// Replaces the joint positions of `model` (discovered on `tracks`) with the kinematic fit of
/// every frame ([`Observer::fit_sequence`]) and returns the fit's RMS residual in units of
/// the model's noise level (`None` with no usable frame). Joints the fit cannot follow are
/// freed (a `joint_not_followed` warning); then the axes, pivots and reference poses of the
/// single-DoF joints the fit follows are bundle-adjusted with every frame's configuration
/// (`crate::bundle`), and each freed joint is refined against its child's keypoints with the
/// parent posed by the fit and put back when refined well enough (see the comments inside). Each
/// joint's reference pose is turned (or slid) to its position at the joint's reference frame,
/// so the positions stay zero there; every joint's observed range is computed here.
///
/// # Errors
/// As [`Observer::new`] and [`Observer::fit_sequence`].
pub fn fit_model_positions(model: &mut Model, tracks: &Tracks) -> Result<Option<f64>> {
    let mut observer = Observer::new(model)?;
    let mut fits = observer.fit_sequence(tracks)?;
    // Joints the model cannot follow are freed one at a time and the sequence refitted. A
    // wrong joint also spoils the joints above it, which bend to absorb its miss (their
    // excess can be the larger), so each round tries every joint over the limit and every
    // joint below one, and frees the one whose freeing leaves the smallest residual.
    loop {
        let excess = observer.joint_excess(tracks, &fits)?;
        let over: Vec<usize> = (0..observer.joints.len())
            .filter(|&k| excess[k].is_some_and(|e| e > MAX_JOINT_EXCESS))
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
        let j = &model.joints[k];
        model.warnings.push(Warning::JointNotFollowed {
            parent: j.parent,
            child: j.child,
            excess_in_sigma2: excess[k].unwrap_or(f64::NAN),
        });
    }
    // The joints the fit follows are bundle-adjusted with every frame's configuration (see
    // `crate::bundle`), after the freeing so a wrong joint does not bend the others. It
    // replaced rounds of one-joint refinements (`refine_joint`) against the whole-tree fit's
    // poses, which stopped when a round raised the tree's residual: on the issue-4 draw of
    // 640 mechanisms at 1 mm, axes under 1 deg went from 2764 to 2830 of 2837 joints and
    // positions within their limit from 2642 to 2764, with the same results with or
    // without those rounds before the adjustment.
    if let Some(adjusted) = adjust_model(model, &observer, tracks)? {
        (observer, fits) = adjusted;
    }
    // A freed joint may only have had poor parameters (a small parent's noisy poses misled
    // the tester): each is refined with its parent posed by the fit, in which its child moves
    // freely, put back into the fit, and kept there when its excess is then within
    // READMIT_EXCESS and every other joint's within MAX_JOINT_EXCESS.
    for k in 0..observer.joints.len() {
        if !observer.freed[k] {
            continue;
        }
        let (joints, warnings) = (model.joints.clone(), model.warnings.clone());
        if !refine_joint(model, k, &observer, tracks, &fits) {
            continue;
        }
        let (parent, child) = (model.joints[k].parent, model.joints[k].child);
        model.warnings.retain(|w| {
            !matches!(w, Warning::JointNotFollowed { parent: p, child: c, .. } if *p == parent && *c == child)
        });
        let trial = Observer::new(model)?;
        let trial_fits = trial.fit_sequence(tracks)?;
        let excess = trial.joint_excess(tracks, &trial_fits)?;
        let followed = excess[k].is_some_and(|e| e <= READMIT_EXCESS)
            && excess
                .iter()
                .all(|e| e.is_none_or(|e| e <= MAX_JOINT_EXCESS));
        if followed {
            (observer, fits) = (trial, trial_fits);
        } else {
            (model.joints, model.warnings) = (joints, warnings);
        }
    }
    // A multi-DoF joint whose child still moves as a hinge or a slide in the fit (a small
    // body's noisy poses can fake a second degree of freedom in the pair test) is typed by
    // the fit: a slide, then a hinge, is fitted from the two bodies' fitted poses, refined
    // like a freed joint, and the first the fit then follows closely is kept (see
    // `type_by_fit`). Only a joint whose pair test found one rotation direction and at most
    // two translation ones is tried: tried on every multi-DoF joint, the human joints of the
    // tennis serve (rotation rank 2-3) were typed, one as a slide, and the keypoints'
    // re-prediction rose from 2.3 to 3.4 sigma.
    //
    // A joint the fit still does not follow gets the other single-DoF type tried the same
    // way: a 3.9 cm link turning +-0.19 rad on the base (rate-test case 548, 2 mm of noise)
    // showed no rotation in its pair test and a straight path, so it was typed prismatic; its
    // child missed the fit by 36 sigma^2 per point as a slide and fits as a hinge.
    for k in 0..observer.joints.len() {
        let ranks = &model.joints[k].ranks;
        if ranks.rotation > 1 || ranks.translation > 2 {
            continue;
        }
        let types: &[bool] = match model.joints[k].joint_type {
            JointType::MultiDof => &[false, true],
            JointType::Prismatic if observer.freed[k] => &[true],
            JointType::Revolute if observer.freed[k] => &[false],
            _ => continue,
        };
        if let Some((trial, trial_fits)) = type_by_fit(model, k, tracks, &fits, types)? {
            (observer, fits) = (trial, trial_fits);
        }
    }
    for (k, joint) in model.joints.iter_mut().enumerate() {
        let j = &observer.joints[k];
        // Joints in the fit and freed ones (from the fitted poses); multi-DoF ones keep the
        // positions they came with.
        if !matches!(j.measure, Measure::None) {
            let mut column: Vec<Option<f64>> = fits.iter().map(|f| f.positions[k]).collect();
            if let Some(zero) = column.get(joint.reference_frame).copied().flatten() {
                let turned = Observer::joint_transform(j, zero);
                let r = turned.rotation;
                let t = turned.translation.vector;
                joint.reference_pose = Some(kinetree_core::model::RigidTransform {
                    rotation_xyzw: [r.i, r.j, r.k, r.w],
                    translation: [t.x, t.y, t.z],
                });
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
        )?;
        let known: Vec<f64> = joint.positions.iter().flatten().copied().collect();
        joint.range = (!known.is_empty()).then(|| {
            [
                known.iter().copied().fold(f64::INFINITY, f64::min),
                known.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            ]
        });
    }
    Ok(rms_in_sigma(&fits, model.noise.sigma_m))
}

/// Bundle-adjusts the joints `observer` (built from `model`) follows ([`crate::bundle`]) and
/// writes them into `model`; returns the observer rebuilt from the model and its fit, or
/// `None` (the model unchanged) when the adjustment changed nothing.
fn adjust_model(
    model: &mut Model,
    observer: &Observer,
    tracks: &Tracks,
) -> Result<Option<(Observer, Vec<FrameFit>)>> {
    let Some(adjusted) = crate::bundle::adjust(observer, tracks)? else {
        return Ok(None);
    };
    let adjusted_fits = adjusted.fit_sequence(tracks)?;
    for (k, j) in adjusted.joints.iter().enumerate() {
        if adjusted.joint_col[k].is_none() {
            continue;
        }
        let (Some(params), Some(cam_parent)) = (
            crate::refine::JointParams::of(j),
            adjusted_fits
                .get(model.joints[k].reference_frame)
                .and_then(|f| f.poses.get(j.parent).copied().flatten()),
        ) else {
            continue;
        };
        store_joint(&mut model.joints[k], &params, &cam_parent);
    }
    let observer = Observer::new(model)?;
    let fits = observer.fit_sequence(tracks)?;
    Ok(Some((observer, fits)))
}

/// Types joint `k` of `model` (multi-DoF, or single-DoF and not followed) by the whole-tree
/// fit `fits`: a candidate of each type of `revolute` in turn ([`candidate_joint`] on the
/// fitted relative poses) is refined as a freed joint is ([`refine_joint`]) and every joint
/// bundle-adjusted with it; the first the fit follows closely (its excess within
/// [`TYPE_EXCESS`], every other joint's within [`MAX_JOINT_EXCESS`]) is kept, with a
/// `joint_typed_by_fit` warning in place of the `multi_dof_joint` or `joint_not_followed`
/// one. Returns the new observer and fits, or `None` (the model unchanged) when none is
/// followed. For a multi-DoF joint the slide comes first: a hinge about a distant pivot
/// approximates a slide with two more parameters, and fitted a true slide better (excess 4.6
/// against 7.3 on rate-test case 83).
///
/// Case 83: a 3.1 cm, 4-point slider at 1.5 mm of noise had rotation residuals of 4.5 per
/// degree of freedom against a bound of 3.3 at rank 0 in its pair test (its poses from three
/// or four points are noisier than their propagated precision says), so the joint was
/// multi-DoF; it stays so, its slide missing the child's points by 7.3 sigma^2 per point
/// (6.8 with the joints below it freed, so not the pull of the seven joints below), though
/// its fitted axis is 0.05 deg off. Case 536: a 31 cm hinge at 4 mm of noise, multi-DoF in
/// its pair test, has an excess of 36 as a slide and 1.0 as a hinge.
fn type_by_fit(
    model: &mut Model,
    k: usize,
    tracks: &Tracks,
    fits: &[FrameFit],
    revolute: &[bool],
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
        // Put back into the fit (a joint with this warning is freed by `Observer::new`).
        model.warnings.retain(
            |w| !matches!(w, Warning::JointNotFollowed { parent: p, child: c, .. } if this(p, c)),
        );
        model.joints[k].joint_type = if revolute {
            JointType::Revolute
        } else {
            JointType::Prismatic
        };
        model.joints[k].dof = 1;
        store_joint(&mut model.joints[k], &start, &cam_parent);
        let mut freed = Observer::new(model)?;
        freed.free_joint(k);
        if !refine_joint(model, k, &freed, tracks, fits) {
            continue;
        }
        let mut trial = Observer::new(model)?;
        let mut trial_fits = trial.fit_sequence(tracks)?;
        if let Some(adjusted) = adjust_model(model, &trial, tracks)? {
            (trial, trial_fits) = adjusted;
        }
        let excess = trial.joint_excess(tracks, &trial_fits)?;
        let Some(own) = excess[k].filter(|&e| e <= TYPE_EXCESS) else {
            continue;
        };
        if excess
            .iter()
            .any(|e| e.is_some_and(|e| e > MAX_JOINT_EXCESS))
        {
            continue;
        }
        model.warnings.retain(
            |w| !matches!(w, Warning::MultiDofJoint { parent: p, child: c, .. } if this(p, c)),
        );
        model.warnings.push(Warning::JointTypedByFit {
            parent,
            child,
            joint_type: model.joints[k].joint_type,
            excess_in_sigma2: own,
        });
        return Ok(Some((trial, trial_fits)));
    }
    (model.joints, model.warnings) = original;
    Ok(None)
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

/// A multi-DoF joint is typed by [`type_by_fit`] only when its child's excess with the
/// single-DoF joint is at most this. Measured: a 31 cm hinge at 4 mm of noise, multi-DoF in
/// its pair test, 1.0 (and 36 as a slide); with [`READMIT_EXCESS`] (10) instead, a 3.1 cm
/// slider came back at 7.3, but human joints of the tennis serve were typed too (one as a
/// slide; re-prediction 2.3 -> 3.4 sigma), and on the noise sweep at 3 mm a wrongly typed
/// joint moved points (two runs lost their ARI of 1). With this bound and the rank rule of
/// [`fit_model_positions`] (session 8): rate test +1 (case 536), sweeps +7 runs with every
/// joint right and -1 (1 cm of noise, DBSCAN, where the ARI was 0.84), real recordings
/// unchanged.
const TYPE_EXCESS: f64 = 3.0;

/// A joint freed by [`fit_model_positions`] is put back into the fit after its refinement
/// only if its [`Observer::joint_excess`] is then below this. Measured: joints of random
/// mechanisms whose small parents had misled the tester came back at 0.7-1.9; human joints
/// of the real recordings at 21-25, and with them in the fit the keypoints' re-prediction
/// rose from 2.3 to 2.8 sigma (a freed joint describes a joint that is no hinge better).
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
    let r = refined.reference.rotation;
    let t = refined.reference.translation.vector;
    joint.reference_pose = Some(kinetree_core::model::RigidTransform {
        rotation_xyzw: [r.i, r.j, r.k, r.w],
        translation: [t.x, t.y, t.z],
    });
}

/// A joint whose [`Observer::joint_excess`] is above this is freed by
/// [`fit_model_positions`]. On 200 random mechanisms the largest excess of a model was under
/// 4 in nine of ten and 10-30 where a joint's pivot was a few centimetres off; joints the
/// model gets wrong reach 50-200. Freeing at 9 instead also freed joints whose neighbour's
/// pivot was off, which then gave worse positions than the fit through the joint.
pub const MAX_JOINT_EXCESS: f64 = 30.0;
