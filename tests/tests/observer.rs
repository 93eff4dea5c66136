//! The observer: joint positions of new frames from a discovered model.

use kinetree_core::geom::unwrap_angles;
use kinetree_core::nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};
use kinetree_core::{Error, Warning};
use kinetree_eval::aligned_rms;
use kinetree_fit::Observer;
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{paper_arm, simulate};

fn config() -> PipelineConfig {
    PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..PipelineConfig::default()
    }
}

/// `scenario` simulated and the model discovered from all its frames (sigma given).
fn discovered(
    scenario: &kinetree_synth::Scenario,
) -> (kinetree_synth::SynthData, kinetree_core::Model) {
    let data = simulate(scenario).expect("simulate");
    let model = Pipeline::from_config(&config())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("run")
        .model;
    (data, model)
}

/// The paper arm simulated from `seed` and the model discovered from all its frames.
fn discovered_arm(seed: u64) -> (kinetree_synth::SynthData, kinetree_core::Model) {
    discovered(&paper_arm(seed))
}

/// The true trajectory of `model`'s joint `k` on the paper arm (its child's first point's
/// true body, less the base, is the true joint).
fn true_positions<'a>(
    data: &'a kinetree_synth::SynthData,
    model: &kinetree_core::Model,
    k: usize,
) -> &'a [f64] {
    let child = model.joints[k].child;
    &data.truth.joint_positions[data.truth.point_body[model.bodies[child].points[0]] - 1]
}

/// Whether the fit freed any joint of `model` (a `joint_not_followed` warning).
fn any_joint_freed(model: &kinetree_core::Model) -> bool {
    kinetree_tests::warned(model, |w| matches!(w, Warning::JointNotFollowed { .. }))
}

fn observe_all(
    observer: &Observer,
    tracks: &kinetree_core::Tracks,
    revolute: &[bool],
) -> Vec<Vec<Option<f64>>> {
    let mut cols = vec![Vec::new(); observer.n_joints()];
    for t in 0..tracks.n_frames() {
        let frame: Vec<_> = (0..tracks.n_points()).map(|i| tracks.get(t, i)).collect();
        for (c, v) in cols
            .iter_mut()
            .zip(observer.observe(&frame).expect("observe"))
        {
            c.push(v);
        }
    }
    for (c, &r) in cols.iter_mut().zip(revolute) {
        if r {
            unwrap_angles(c);
        }
    }
    cols
}

#[test]
fn observing_the_training_frames_reproduces_the_batch_positions() {
    let (data, model) = discovered_arm(3);
    // Through JSON, as a user would load it.
    let path = std::env::temp_dir().join(format!("kinetree-observer-{}.json", std::process::id()));
    kinetree_io::write_json(&path, &model).expect("write");
    let model = kinetree_io::read_model(&path).expect("read");
    let observer = Observer::new(&model).expect("observer");
    let revolute: Vec<bool> = model
        .joints
        .iter()
        .map(|j| j.joint_type == kinetree_core::model::JointType::Revolute)
        .collect();
    let cols = observe_all(&observer, &data.tracks, &revolute);
    for (j, c) in model.joints.iter().zip(&cols) {
        // The batch positions are zero at the joint's reference frame; the observed column is
        // unwrapped from its first frame, so the two may differ by whole turns, the same
        // number in every frame.
        let turns = j
            .positions
            .iter()
            .zip(c)
            .find_map(|(a, b)| Some(a.as_ref()? - b.as_ref()?))
            .expect("a common frame");
        assert!(
            kinetree_core::geom::wrap_pi(turns).abs() < 1e-6,
            "offset {turns}"
        );
        for (a, b) in j.positions.iter().zip(c) {
            match (a, b) {
                // The batch fits start from the previous frame, the observer from the
                // frame's own poses: each stops within the solver's tolerance of the minimum
                // (about a micron or microradian), so the two agree within 1e-5 rad.
                (Some(a), Some(b)) => assert!((a - b - turns).abs() < 1e-5, "{a} vs {b}"),
                (None, None) => {}
                _ => panic!("known in one and not the other: {a:?} vs {b:?}"),
            }
        }
    }
}

#[test]
fn held_back_frames_follow_the_truth() {
    let data = simulate(&paper_arm(4)).expect("simulate");
    let first: Vec<usize> = (0..70).collect();
    let training = data.tracks.select_frames(&first).expect("first 70 frames");
    let model = Pipeline::from_config(&config())
        .expect("pipeline")
        .run(&training)
        .expect("run")
        .model;
    assert_eq!(model.joints.len(), 2);
    let observer = Observer::new(&model).expect("observer");
    let cols = observe_all(&observer, &data.tracks, &[true, true]);
    // Match the discovered joints to the true ones by their child's points.
    for (k, col) in cols.iter().enumerate() {
        let child_points = &model.bodies[model.joints[k].child].points;
        let truth_joint = data.truth.point_body[child_points[0]] - 1;
        let truth = &data.truth.joint_positions[truth_joint];
        let held_back: Vec<Option<f64>> = col
            .iter()
            .enumerate()
            .map(|(t, v)| if t >= 70 { *v } else { None })
            .collect();
        assert!(
            held_back.iter().flatten().count() >= 25,
            "most held-back frames observed"
        );
        let rms = aligned_rms(col, truth).expect("rms");
        assert!(rms < 0.05, "joint {k}: RMS {rms} rad over all 100 frames");
    }
}

#[test]
fn bad_observer_input_gets_typed_errors() {
    let (_, mut model) = discovered_arm(5);
    let observer = Observer::new(&model).expect("observer");
    assert!(matches!(
        observer.observe(&[None; 5]),
        Err(Error::Shape { .. })
    ));
    // A frame with nothing visible: no positions, no panic.
    let empty = vec![None; model.n_points];
    assert!(
        observer
            .observe(&empty)
            .expect("observe")
            .iter()
            .all(Option::is_none)
    );
    // A model without reference shapes (an older file).
    model.bodies[0].shape.clear();
    assert!(matches!(Observer::new(&model), Err(Error::Config(_))));
}

#[test]
fn keypoints_are_re_predicted_from_the_joints() {
    let (data, model) = discovered_arm(6);
    let r = model.reprediction_rms_in_sigma.expect("reprediction");
    // Per-body fitted poses alone give about 1.45 sigma here. The whole-tree fit has fewer
    // free parameters per frame and carries the axes' errors (0.3 and 0.7 deg): 1.63 measured.
    assert!(r > 1.0 && r < 2.5, "right model: {r} sigma");
    // Tilt the second joint's axis by about 10 degrees: the re-predicted keypoints drift.
    let mut wrong = model.clone();
    let a = wrong.joints[1].axis_in_parent.expect("axis");
    wrong.joints[1].axis_in_parent = Some([a[0] + 0.18, a[1], a[2]]);
    let bad = Observer::new(&wrong)
        .expect("observer")
        .reprediction_rms_in_sigma(&data.tracks, model.noise.sigma_m)
        .expect("reprediction")
        .expect("value");
    // 22 sigma measured.
    assert!(bad > 5.0 * r, "wrong axis: {bad} sigma against {r}");
}

fn frame_of(tracks: &kinetree_core::Tracks, t: usize) -> Vec<Option<Point3<f64>>> {
    (0..tracks.n_points()).map(|i| tracks.get(t, i)).collect()
}

/// The tree fit follows a joint whose child shows one or two points, where a per-body pose
/// (three points) cannot; with none below the joint the position is unknown.
#[test]
fn a_joint_is_followed_from_two_child_points_and_unknown_from_none() {
    let (data, model) = discovered_arm(3);
    let observer = Observer::new(&model).expect("observer");
    let last = model.joints.len() - 1;
    let child = model.joints[last].child;
    let points = &model.bodies[child].points;
    let (mut compared, mut worst) = (0, 0.0f64);
    for t in (10..90).step_by(4) {
        let mut frame = frame_of(&data.tracks, t);
        // Keep the first two visible points of the last link, hide the rest.
        let mut kept = 0;
        for &i in points {
            if frame[i].is_some() && kept < 2 {
                kept += 1;
            } else {
                frame[i] = None;
            }
        }
        if kept < 2 {
            continue;
        }
        assert!(observer.body_poses(&frame)[child].is_none());
        let fit = observer.fit(&frame, None).expect("fit");
        let (Some(q), Some(batch)) = (fit.positions[last], model.joints[last].positions[t]) else {
            panic!("frame {t}: no position from two points");
        };
        let sd = fit.std[last].expect("std");
        assert!(sd > 0.0 && sd < 0.05, "frame {t}: std {sd}");
        worst = worst.max(kinetree_core::geom::wrap_pi(q - batch).abs());
        compared += 1;
        // Nothing below the joint: unknown, and so is the child's pose.
        for &i in points {
            frame[i] = None;
        }
        let fit = observer.fit(&frame, None).expect("fit");
        assert_eq!(fit.positions[last], None, "frame {t}");
        assert!(fit.poses[child].is_none());
        assert!(fit.positions[..last].iter().all(Option::is_some));
    }
    assert!(compared >= 15, "{compared} frames compared");
    // Two points 10-20 cm from the axis at 1 mm noise: about 0.01 rad.
    assert!(worst < 0.05, "two points against all: {worst} rad");
}

/// A joint the model gets wrong (a hinge typed as a slide, which no refinement of its axis
/// can make follow a rotation) is freed with a warning, and the joint above it keeps its
/// accuracy; its own positions then come from the body poses. Its ranks here say the pair
/// test saw two rotation directions, so the fit does not try it as a hinge (see
/// `a_hinge_typed_as_a_slide_is_typed_back_by_the_fit`).
#[test]
fn a_joint_the_model_gets_wrong_is_freed() {
    let (data, model) = discovered_arm(3);
    let truth_of = |k: usize| true_positions(&data, &model, k);
    let before: Vec<f64> = (0..2)
        .map(|k| aligned_rms(&model.joints[k].positions, truth_of(k)).expect("rms"))
        .collect();
    assert!(before.iter().all(|&r| r < 0.01), "{before:?}");
    let mut wrong = model.clone();
    wrong.joints[1].joint_type = kinetree_core::model::JointType::Prismatic;
    wrong.joints[1].ranks.rotation = 2;
    wrong.warnings.clear();
    kinetree_fit::fit_model_positions(&mut wrong, &data.tracks).expect("fit");
    let freed: Vec<(usize, usize)> = wrong
        .warnings
        .iter()
        .filter_map(|w| match w {
            Warning::JointNotFollowed { parent, child, .. } => Some((*parent, *child)),
            _ => None,
        })
        .collect();
    assert_eq!(freed, vec![(wrong.joints[1].parent, wrong.joints[1].child)]);
    let after: Vec<f64> = (0..2)
        .map(|k| aligned_rms(&wrong.joints[k].positions, truth_of(k)).expect("rms"))
        .collect();
    assert!(after[0] < 0.01, "the joint above: {after:?}");
    // An observer built from the model frees the same joint: the training frames give the
    // model's positions back (up to whole turns, the same in every frame).
    let fits = Observer::new(&wrong)
        .expect("observer")
        .fit_sequence(&data.tracks)
        .expect("fit");
    for (k, joint) in wrong.joints.iter().enumerate() {
        let offsets: Vec<f64> = joint
            .positions
            .iter()
            .zip(&fits)
            .filter_map(|(b, f)| Some(b.as_ref()? - f.positions[k].as_ref()?))
            .collect();
        assert!(offsets.len() > 90, "joint {k}: {} frames", offsets.len());
        let turns = (offsets[0] / std::f64::consts::TAU).round() * std::f64::consts::TAU;
        assert!(
            offsets.iter().all(|o| (o - turns).abs() < 1e-6),
            "joint {k}: {offsets:?}"
        );
    }
}

/// The hinge typed as a slide again, with the pair test's own ranks (one rotation
/// direction): the fit does not follow the slide, tries a hinge fitted from the fitted
/// poses, follows it, and types the joint back (`joint_typed_by_fit`, no joint freed), its
/// positions as accurate as the discovered model's.
#[test]
fn a_hinge_typed_as_a_slide_is_typed_back_by_the_fit() {
    let (data, model) = discovered_arm(3);
    let truth = true_positions(&data, &model, 1);
    assert!(
        model.joints[1].ranks.rotation <= 1,
        "{:?}",
        model.joints[1].ranks
    );
    let mut wrong = model.clone();
    wrong.joints[1].joint_type = kinetree_core::model::JointType::Prismatic;
    wrong.warnings.clear();
    kinetree_fit::fit_model_positions(&mut wrong, &data.tracks).expect("fit");
    assert_eq!(
        wrong.joints[1].joint_type,
        kinetree_core::model::JointType::Revolute
    );
    assert!(
        wrong.warnings.iter().any(|w| matches!(
            w,
            Warning::JointTypedByFit { joint_type, .. } if *joint_type == kinetree_core::model::JointType::Revolute
        )),
        "{:?}",
        wrong.warnings
    );
    assert!(!any_joint_freed(&wrong), "{:?}", wrong.warnings);
    let rms = aligned_rms(&wrong.joints[1].positions, truth).expect("rms");
    assert!(rms < 0.01, "positions {rms} rad RMS");
}

/// A joint whose pivot is 8 cm off is not followed by the fit at first; refined against its
/// child's keypoints with the parent posed by the fit, it is followed again: no warning, the
/// pivot back on the discovered axis line, and the positions as accurate as before.
#[test]
fn a_joint_with_a_wrong_pivot_is_refined_back() {
    let (data, model) = discovered_arm(3);
    let truth = true_positions(&data, &model, 1);
    let mut wrong = model.clone();
    let p = wrong.joints[1].point_in_parent.expect("pivot");
    wrong.joints[1].point_in_parent = Some([p[0] + 0.08, p[1], p[2]]);
    wrong.warnings.clear();
    kinetree_fit::fit_model_positions(&mut wrong, &data.tracks).expect("fit");
    assert!(!any_joint_freed(&wrong), "{:?}", wrong.warnings);
    let axis =
        kinetree_core::nalgebra::Vector3::from(model.joints[1].axis_in_parent.expect("axis"));
    let offset =
        kinetree_core::nalgebra::Vector3::from(wrong.joints[1].point_in_parent.expect("pivot"))
            - kinetree_core::nalgebra::Vector3::from(p);
    let off_line = (offset - axis * axis.dot(&offset) / axis.norm_squared()).norm();
    assert!(
        off_line < 0.005,
        "pivot {off_line} m off the discovered axis line"
    );
    let rms = aligned_rms(&wrong.joints[1].positions, truth).expect("rms");
    assert!(rms < 0.01, "positions {rms} rad RMS");
}

#[test]
fn bad_fit_input_gets_typed_errors() {
    let (data, model) = discovered_arm(5);
    let observer = Observer::new(&model).expect("observer");
    let frame = frame_of(&data.tracks, 0);
    let fit = observer.fit(&frame, None).expect("fit");
    // A previous fit of another model.
    let mut other = fit.clone();
    other.positions.push(None);
    assert!(matches!(
        observer.fit(&frame, Some(&other)),
        Err(Error::Shape { .. })
    ));
    // Fits that do not match the tracks.
    assert!(matches!(
        observer.joint_excess(&data.tracks, &[fit]),
        Err(Error::Shape { .. })
    ));
    // A body with two parents, and a cycle.
    let mut two = model.clone();
    let mut extra = two.joints[1].clone();
    extra.parent = 0;
    two.joints.push(extra);
    assert!(matches!(Observer::new(&two), Err(Error::Config(_))));
    let mut itself = model.clone();
    itself.joints[0].parent = itself.joints[0].child;
    assert!(matches!(Observer::new(&itself), Err(Error::Config(_))));
    let mut cycle = model.clone();
    cycle.joints[0].parent = cycle.joints[1].child;
    assert!(matches!(Observer::new(&cycle), Err(Error::Config(_))));
}

/// Fitted motions used with a model they were not fitted for: a typed error from both checks.
#[test]
fn fitted_motions_of_another_model_are_a_typed_error() {
    let (data, model) = discovered_arm(5);
    let motions = kinetree_fit::FittedMotions::new(&model, &data.tracks).expect("fit");
    assert!(motions.points_settled(&model, &data.tracks, &[0]).is_ok());
    let mut other = model.clone();
    other.bodies.push(other.bodies[0].clone());
    assert!(matches!(
        motions.points_fitting_another_body(&other, &data.tracks),
        Err(Error::Shape { .. })
    ));
    assert!(matches!(
        motions.points_settled(&other, &data.tracks, &[0]),
        Err(Error::Shape { .. })
    ));
}

/// The fitted motions laid onto the per-body poses: the same body frames (each fitted pose
/// within a few pose-noise widths of the body's own), only registered frames posed, and a
/// typed error for per-body poses of another segmentation.
#[test]
fn fitted_motions_onto_per_body_poses() {
    let data = simulate(&paper_arm(5)).expect("simulate");
    let d = Pipeline::from_config(&config())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("run");
    let motions = kinetree_fit::FittedMotions::new(&d.model, &data.tracks).expect("fit");
    let fitted = motions.onto_body_poses(&d.poses).expect("onto");
    let mut compared = 0;
    for (own, new) in d.poses.bodies.iter().zip(&fitted.bodies) {
        for (a, b) in own.cam_from_body.iter().zip(&new.cam_from_body) {
            assert_eq!(a.is_some(), b.is_some());
            if let (Some(a), Some(b)) = (a, b) {
                let diff = a.inverse() * b;
                assert!(diff.rotation.angle() < 0.05, "{}", diff.rotation.angle());
                assert!(diff.translation.vector.norm() < 0.01);
                compared += 1;
            }
        }
    }
    assert!(compared > 100, "{compared} poses compared");
    let mut fewer = d.poses.clone();
    fewer.bodies.pop();
    assert!(matches!(
        motions.onto_body_poses(&fewer),
        Err(Error::Shape { .. })
    ));
}

/// Every body's fitted pose, as `observe` tables them, against the truth: each body's motion
/// from its first posed frame (`P(t) P(t0)^-1`, which does not depend on where the body
/// frame is) within four of the stated standard deviations, on a skeleton of ball joints
/// and hinges and on a random tree; the standard deviations not inflated either; and the table's layout.
#[test]
fn body_poses_follow_the_truth_within_their_standard_deviations() {
    use kinetree_synth::{RandomParams, SkeletonParams, random_scenario, skeleton_scenario};
    let scenarios = [
        skeleton_scenario(&SkeletonParams::default()),
        random_scenario(&RandomParams {
            seed: 5,
            n_joints: 5,
            tree: true,
            ..RandomParams::default()
        }),
    ];
    for scenario in scenarios {
        let (data, model) = discovered(&scenario);
        let seen =
            kinetree_fit::observe(&model, &data.tracks, Default::default()).expect("observe");
        let (table, shape) = seen.pose_table();
        let (nt, nb) = (data.tracks.n_frames(), model.bodies.len());
        assert_eq!(shape, [nt, nb, kinetree_fit::POSE_COLUMNS.len()]);
        assert_eq!(table.len(), nt * nb * 9);
        let truth = &data.truth;
        let map = kinetree_eval::body_map(&model, truth);
        let true_pose = |b: usize, t: usize| {
            let q: Vec<f64> = truth.joint_positions.iter().map(|c| c[t]).collect();
            truth.cam_from_world * truth.mechanism.forward(&q)[map[b]]
        };
        let (mut checked, mut within, mut posed) = (0usize, 0usize, 0usize);
        let mut worst: f64 = 0.0;
        for b in 0..nb {
            let at = |t: usize| &table[(t * nb + b) * 9..(t * nb + b + 1) * 9];
            let Some(t0) = (0..nt).find(|&t| at(t)[0].is_finite()) else {
                continue;
            };
            let pose = |t: usize| {
                let r = at(t);
                Isometry3::from_parts(
                    Translation3::new(r[4], r[5], r[6]),
                    UnitQuaternion::from_quaternion(Quaternion::new(r[3], r[0], r[1], r[2])),
                )
            };
            for t in t0 + 1..nt {
                if !at(t)[0].is_finite() {
                    continue;
                }
                posed += 1;
                // The table's pose is the observation's own.
                let own = seen.poses[t][b].expect("a pose where the table has one");
                assert!((own.translation.vector - pose(t).translation.vector).norm() < 1e-12);
                let fitted = pose(t) * pose(t0).inverse();
                let moved = true_pose(b, t) * true_pose(b, t0).inverse();
                let angle = (fitted.rotation.inverse() * moved.rotation).angle();
                let origin = pose(t).translation.vector;
                let true_origin = moved * Point3::from(pose(t0).translation.vector);
                let shift = (origin - true_origin.coords).norm();
                let (s, s0) = (at(t), at(t0));
                let rot_sd = s[7].hypot(s0[7]);
                // The origin at t0 carried by the true motion also moves with that origin's
                // own error; a lever of one metre bounds the rotation's part.
                let origin_sd = s[8].hypot(s0[8]).hypot(s0[7]);
                checked += 1;
                let z = (angle / rot_sd).max(shift / origin_sd);
                worst = worst.max(z);
                within += usize::from(z <= 4.0);
            }
        }
        assert!(posed > nt, "{posed} poses checked");
        assert!(
            within * 100 >= checked * 99,
            "{within} of {checked} poses within 4 standard deviations (worst {worst:.1})"
        );
        // Nor are the standard deviations inflated: the worst of thousands of errors is
        // several of them (3.1 and 4.2 here).
        assert!(
            worst > 1.5,
            "the worst error is only {worst:.2} standard deviations"
        );
    }
}

/// The whole-tree fit of a sequence again, given the observer's own earlier fit, is the same
/// fit bit for bit, though its frames run in parallel chunks (700 frames make three): each
/// chunk starts from the last known values of the frames before it, as the sequence had
/// them.
#[test]
fn a_refit_from_the_observers_own_fit_is_the_same_fit_bit_for_bit() {
    // The paper arm's first link turns about once: its angle runs past half a turn, where
    // a chunk started without the frames before it would wrap.
    let mut scenario = paper_arm(3);
    scenario.n_frames = 700;
    scenario.dropout = 0.2;
    let (data, model) = discovered(&scenario);
    let observer = Observer::new(&model).expect("observer");
    let fits = observer.fit_sequence(&data.tracks).expect("fit");
    let again = observer.refit_sequence(&data.tracks, &fits).expect("refit");
    assert_eq!(again.len(), fits.len());
    for (t, (a, b)) in again.iter().zip(&fits).enumerate() {
        assert!(a == b, "frame {t} differs");
    }
    // Without one earlier fit per frame, the frames are fitted in turn.
    let fresh = observer
        .refit_sequence(&data.tracks, &fits[..10])
        .expect("refit");
    assert!(fresh == fits);
}

/// The fit of listed frames is the fit of a recording of those frames alone, and a frame
/// beyond the tracks is refused with a shape error that names it.
#[test]
fn a_fit_of_listed_frames_is_the_fit_of_those_frames_alone() {
    let (data, model) = discovered_arm(2);
    let observer = Observer::new(&model).expect("observer");
    let frames: Vec<usize> = (0..data.tracks.n_frames()).step_by(4).collect();
    let listed = observer
        .fit_frames(&data.tracks, &frames)
        .expect("fit frames");
    let alone = observer
        .fit_sequence(&data.tracks.select_frames(&frames).expect("select"))
        .expect("fit");
    assert_eq!(listed.len(), frames.len());
    assert!(listed == alone, "the listed frames' fits differ");
    let beyond = data.tracks.n_frames();
    match observer.fit_frames(&data.tracks, &[0, beyond]) {
        Err(Error::Shape { found, .. }) => assert!(found.contains(&beyond.to_string()), "{found}"),
        other => panic!("frame {beyond} accepted: {other:?}"),
    }
}

/// The residual of listed frames settled from a known fit is the residual of fitting those
/// frames: from the observer's own fit, and for an observer with a joint freed, whose child
/// then starts from the pose the joint gave it. A frame beyond the tracks, or without a
/// known fit, is refused with a shape error that names it.
#[test]
fn a_settled_residual_is_the_residual_of_fitting_those_frames() {
    let (data, model) = discovered_arm(2);
    let observer = Observer::new(&model).expect("observer");
    let fits = observer.fit_sequence(&data.tracks).expect("fit");
    let frames: Vec<usize> = (0..data.tracks.n_frames()).step_by(4).collect();
    let sum = |fits: &[kinetree_fit::FrameFit]| fits.iter().map(|f| f.sum_sq_m2).sum::<f64>();
    let own: f64 = frames.iter().map(|&t| fits[t].sum_sq_m2).sum();
    let settled = observer
        .settled_miss(&data.tracks, &fits, &frames)
        .expect("settled");
    assert!(
        (settled - own).abs() <= 1e-6 * own,
        "settled {settled:e} against the fit's {own:e}"
    );
    let mut freed = observer.clone();
    freed.free_joint(model.joints.len() - 1);
    let fitted = sum(&freed.fit_frames(&data.tracks, &frames).expect("fit frames"));
    let settled = freed
        .settled_miss(&data.tracks, &fits, &frames)
        .expect("settled");
    assert!(
        (settled - fitted).abs() <= 1e-3 * fitted,
        "settled {settled:e} against the freed fit's {fitted:e}"
    );
    // Freeing a joint can only lower the residual: the child's six coordinates include the
    // joint's one.
    assert!(settled <= own * (1.0 + 1e-9), "{settled:e} above {own:e}");
    let beyond = data.tracks.n_frames();
    match observer.settled_miss(&data.tracks, &fits, &[0, beyond]) {
        Err(Error::Shape { found, .. }) => assert!(found.contains(&beyond.to_string()), "{found}"),
        other => panic!("frame {beyond} accepted: {other:?}"),
    }
    match observer.settled_miss(&data.tracks, &fits[..10], &[12]) {
        Err(Error::Shape { found, .. }) => assert!(found.contains("12"), "{found}"),
        other => panic!("a frame without a known fit accepted: {other:?}"),
    }
}
