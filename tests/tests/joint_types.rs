//! Joint types beyond one degree of freedom: ball joints typed, centred, fitted, observed and
//! exported, on simulated skeletons and random mechanisms; hinges kept revolute under heavy
//! noise.

use kinetree_core::NotIdentifiableBasis;
use kinetree_core::model::{JointType, Model};
use kinetree_core::nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use kinetree_eval::{body_map, evaluate, functional_errors};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{
    RandomParams, SkeletonParams, SynthData, random_scenario, simulate, skeleton_scenario,
};

fn discover(data: &SynthData) -> Model {
    Pipeline::from_config(&PipelineConfig::default())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover")
        .model
}

fn skeleton(seed: u64, noise_sigma_m: f64) -> SynthData {
    simulate(&skeleton_scenario(&SkeletonParams {
        seed,
        noise_sigma_m,
        ..SkeletonParams::default()
    }))
    .expect("simulate")
}

/// A skeleton with universal wrists and ankles at 1 mm.
fn universal_skeleton(seed: u64) -> SynthData {
    simulate(&skeleton_scenario(&SkeletonParams {
        seed,
        universal_wrists_and_ankles: true,
        ..SkeletonParams::default()
    }))
    .expect("simulate")
}

/// The true rotation of spherical joint `k` at `frame`, in the parent's frame at the zero
/// configuration (the truth's coordinates are its rotation vector).
fn true_turn(data: &SynthData, k: usize, frame: usize) -> UnitQuaternion<f64> {
    let at = data.truth.mechanism.coordinate_offsets()[k];
    let q = &data.truth.joint_positions;
    UnitQuaternion::from_scaled_axis(Vector3::new(
        q[at][frame],
        q[at + 1][frame],
        q[at + 2][frame],
    ))
}

#[test]
fn skeleton_ball_joints_are_spherical_with_centres_within_two_millimetres() {
    let (mut joints, mut typed, mut balls, mut centred, mut hinges, mut straight) =
        (0, 0, 0, 0, 0, 0);
    let mut worst_centre: f64 = 0.0;
    let mut worst_axis: f64 = 0.0;
    // SCoRE on the true segmentation's poses: the functional method a biomechanist compares
    // with. Each centre is within 2 mm or 1.5 times SCoRE's error.
    let (mut beside_score, mut scored) = (0, 0);
    let pose = PipelineConfig::default().pose.build().expect("pose stage");
    for seed in 0..4 {
        let data = skeleton(seed, 0.001);
        let model = discover(&data);
        let e = evaluate(&model, &data.truth);
        let functional =
            functional_errors(&data.tracks, &data.truth, pose.as_ref(), 0.001).expect("SCoRE");
        for ((j, spec), f) in e
            .joints
            .iter()
            .zip(&data.truth.mechanism.joints)
            .zip(&functional)
        {
            joints += 1;
            typed += usize::from(j.found && j.type_ok);
            if spec.joint_type == kinetree_synth::JointType::Spherical {
                balls += 1;
                if let (Some(c), Some(score)) =
                    (j.centre_error_in_parent_m, f.centre_error_in_parent_m)
                {
                    scored += 1;
                    beside_score += usize::from(c <= 0.002_f64.max(1.5 * score));
                }
                if let Some(c) = j.centre_error_in_parent_m {
                    worst_centre = worst_centre.max(c);
                    centred += usize::from(c <= 0.002);
                }
            } else {
                hinges += 1;
                if let Some(a) = j.axis_error_in_parent_deg {
                    worst_axis = worst_axis.max(a);
                    straight += usize::from(a < 1.0);
                }
            }
        }
    }
    assert!(
        typed * 100 >= joints * 95,
        "{typed} of {joints} joints found and typed right"
    );
    assert_eq!(
        centred, balls,
        "ball centres within 2 mm (worst {worst_centre} m)"
    );
    assert_eq!(scored, balls, "SCoRE centres every ball joint");
    assert_eq!(
        beside_score, balls,
        "ball centres within 2 mm or 1.5 times SCoRE's error"
    );
    assert_eq!(
        straight, hinges,
        "hinge axes within 1 deg (worst {worst_axis} deg)"
    );
}

#[test]
fn ball_joint_rotations_follow_the_truth_within_their_stated_precision() {
    let data = skeleton(7, 0.001);
    let model = discover(&data);
    let map = body_map(&model, &data.truth);
    let mut checked = 0;
    let mut z2 = Vec::new();
    for (k, spec) in data.truth.mechanism.joints.iter().enumerate() {
        if spec.joint_type != kinetree_synth::JointType::Spherical {
            continue;
        }
        let j = model
            .joints
            .iter()
            .find(|j| map[j.parent] == spec.parent && map[j.child] == spec.child)
            .expect("ball joint found");
        assert_eq!(j.joint_type, JointType::Spherical);
        assert!(
            j.positions.iter().all(Option::is_none),
            "no scalar positions"
        );
        assert_eq!(j.coordinates.len(), model.n_frames);
        let zero = true_turn(&data, k, j.reference_frame);
        for (t, (c, s)) in j.coordinates.iter().zip(&j.coordinate_std).enumerate() {
            let (Some(c), Some(s)) = (c, s) else { continue };
            // The model's rotation is the true one seen from the parent's body frame, which
            // the angle does not depend on.
            let ours = UnitQuaternion::from_scaled_axis(Vector3::new(c[0], c[1], c[2]));
            let truth = true_turn(&data, k, t) * zero.inverse();
            let miss = ours.angle() - truth.angle();
            let sd = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt() / 3f64.sqrt();
            assert!(
                sd > 0.0 && sd <= model.position_limits.max_std_rad,
                "joint {k} frame {t}: std {s:?} rad"
            );
            z2.push((miss / sd).powi(2));
            checked += 1;
        }
        let smoothed = j.smoothed_coordinates.iter().flatten().count();
        assert!(smoothed > model.n_frames / 2, "{smoothed} smoothed frames");
    }
    assert!(checked > 1000, "{checked} frames checked");
    let z_rms = (z2.iter().sum::<f64>() / z2.len() as f64).sqrt();
    // The angle's error against the mean of the three axes' deviations: about 1 for a
    // deviation as good as it says.
    assert!(z_rms > 0.2 && z_rms < 3.0, "z RMS {z_rms}");
}

/// Whether nine in ten of model body `b`'s points are on true body `truth_body`.
fn pure(model: &Model, data: &SynthData, b: usize, truth_body: usize) -> bool {
    let points = &model.bodies[b].points;
    let own = points
        .iter()
        .filter(|&&i| data.truth.point_body[i] == truth_body)
        .count();
    own * 10 >= points.len() * 9
}

#[test]
fn hinges_stay_revolute_at_ten_millimetres_of_noise() {
    // The typing is judged where the bodies are right: a body mixing two links has no joint
    // of any type.
    let (mut hinges, mut spherical) = (0, Vec::new());
    for seed in 0..16 {
        let data = simulate(&random_scenario(&RandomParams {
            n_joints: 3,
            prismatic_fraction: 0.0,
            extra_points: 10,
            noise_sigma_m: 0.01,
            n_frames: 300,
            seed,
            ..RandomParams::default()
        }))
        .expect("simulate");
        let model = discover(&data);
        let map = body_map(&model, &data.truth);
        for spec in &data.truth.mechanism.joints {
            let Some(j) = model
                .joints
                .iter()
                .find(|j| map[j.parent] == spec.parent && map[j.child] == spec.child)
            else {
                continue;
            };
            if !(pure(&model, &data, j.parent, spec.parent)
                && pure(&model, &data, j.child, spec.child))
            {
                continue;
            }
            hinges += 1;
            if j.joint_type == JointType::Spherical {
                spherical.push((seed, spec.child));
            }
        }
    }
    assert!(hinges >= 12, "{hinges} hinges between pure bodies");
    assert!(
        spherical.is_empty(),
        "hinges typed spherical: {spherical:?}"
    );
}

#[test]
fn the_observer_follows_ball_joints_in_new_frames() {
    let data = skeleton(3, 0.001);
    let model = discover(&data);
    let observer = kinetree_fit::Observer::new(&model).expect("observer");
    let fits = observer.fit_sequence(&data.tracks).expect("fit");
    let balls: Vec<usize> = (0..model.joints.len())
        .filter(|&k| model.joints[k].joint_type == JointType::Spherical)
        .collect();
    assert!(balls.len() >= 9, "{} ball joints", balls.len());
    for &k in &balls {
        let j = &model.joints[k];
        let mut compared = 0;
        for (t, f) in fits.iter().enumerate() {
            let (Some(ours), Some(batch)) = (f.rotations[k], j.coordinates[t].as_ref()) else {
                continue;
            };
            // The batch's coordinates are the observer's, turned to zero at the reference
            // frame: the rotation between two frames is the same.
            let a = UnitQuaternion::from_scaled_axis(Vector3::from(ours));
            let b = UnitQuaternion::from_scaled_axis(Vector3::new(batch[0], batch[1], batch[2]));
            let r = fits[j.reference_frame].rotations[k]
                .map(|v| UnitQuaternion::from_scaled_axis(Vector3::from(v)));
            if let Some(r) = r {
                let off = (a * r.inverse()).angle_to(&b);
                assert!(off < 1e-4, "joint {k} frame {t}: {off} rad apart");
                compared += 1;
            }
        }
        assert!(compared > 100, "joint {k}: {compared} frames compared");
    }
}

/// The `continuous` joints `<name>_<suffix>` of a URDF, in the order of `suffixes`.
fn urdf_joints<'a>(
    robot: &'a urdf_rs::Robot,
    name: &str,
    suffixes: &[&str],
) -> Vec<&'a urdf_rs::Joint> {
    suffixes
        .iter()
        .map(|s| {
            let u = robot
                .joints
                .iter()
                .find(|u| u.name == format!("{name}_{s}"))
                .unwrap_or_else(|| panic!("joint {name}_{s}"));
            assert!(matches!(u.joint_type, urdf_rs::JointType::Continuous));
            u
        })
        .collect()
}

/// The first joint's parent link from the last one's child link, each joint turned by its
/// angle.
fn urdf_turned(chain: &[&urdf_rs::Joint], angles: &[f64]) -> Isometry3<f64> {
    let mut link = Isometry3::identity();
    for (u, a) in chain.iter().zip(angles) {
        let [r, p, y] = u.origin.rpy.0;
        let origin = Isometry3::from_parts(
            Translation3::from(Vector3::from(u.origin.xyz.0)),
            UnitQuaternion::from_euler_angles(r, p, y),
        );
        let axis = Vector3::from(u.axis.xyz.0);
        link = link * origin * UnitQuaternion::from_scaled_axis(axis * *a);
    }
    link
}

#[test]
fn urdf_ball_joints_turn_about_their_centre() {
    let data = skeleton(1, 0.001);
    let model = discover(&data);
    let text = kinetree_io::export::to_urdf(&model).expect("urdf");
    let robot = urdf_rs::read_from_string(&text).expect("urdf-rs parses it");
    let offsets = kinetree_io::export::link_offsets(&model).expect("offsets");
    let mut checked = 0;
    for j in model
        .joints
        .iter()
        .filter(|j| j.joint_type == JointType::Spherical)
    {
        let name = kinetree_io::export::joint_name(j.parent, j.child);
        let chain = urdf_joints(&robot, &name, &["rx", "ry", "rz"]);
        let centre_p = Point3::from(Vector3::from(j.point_in_parent.expect("centre")));
        let reference = j
            .reference_pose
            .and_then(|r| r.to_isometry())
            .expect("pose");
        let centre_c = reference.inverse_transform_point(&centre_p);
        let off_p = Translation3::from(Vector3::from(offsets[j.parent]));
        let off_c = Translation3::from(Vector3::from(offsets[j.child]));
        for angles in [[0.0, 0.0, 0.0], [0.4, -0.7, 1.1], [-1.2, 0.3, -0.5]] {
            let link = urdf_turned(&chain, &angles);
            // Child body frame -> child link -> parent link -> parent body frame.
            let moved = off_p.inverse() * link * off_c * centre_c;
            assert!(
                (moved - centre_p).norm() < 1e-9,
                "{name} at {angles:?}: centre moved by {}",
                (moved - centre_p).norm()
            );
            if angles == [0.0; 3] {
                let at_zero = off_p.inverse() * link * off_c;
                let diff = at_zero.inverse() * reference;
                assert!(diff.translation.vector.norm() < 1e-9 && diff.rotation.angle() < 1e-9);
            }
            checked += 1;
        }
    }
    assert!(checked >= 27, "{checked} checks");
}

/// URDF's two revolute joints of a universal joint, turned by the model's two angles, move
/// the child as the model says: `T(c) R(axis, q1) R(second_axis, q2) T(-c) reference_pose`.
#[test]
fn urdf_universal_joints_turn_by_the_models_angles() {
    let data = universal_skeleton(1);
    let model = discover(&data);
    let text = kinetree_io::export::to_urdf(&model).expect("urdf");
    let robot = urdf_rs::read_from_string(&text).expect("urdf-rs parses it");
    let offsets = kinetree_io::export::link_offsets(&model).expect("offsets");
    let turn = |axis: [f64; 3], q: f64| {
        UnitQuaternion::from_scaled_axis(Vector3::from(axis).normalize() * q)
    };
    let mut checked = 0;
    for j in model
        .joints
        .iter()
        .filter(|j| j.joint_type == JointType::Universal)
    {
        let name = kinetree_io::export::joint_name(j.parent, j.child);
        let chain = urdf_joints(&robot, &name, &["1", "2"]);
        let centre = Translation3::from(Vector3::from(j.point_in_parent.expect("centre")));
        let reference = j
            .reference_pose
            .and_then(|r| r.to_isometry())
            .expect("pose");
        let (first, second) = (
            j.axis_in_parent.expect("axis"),
            j.second_axis_in_parent.expect("second axis"),
        );
        let off_p = Translation3::from(Vector3::from(offsets[j.parent]));
        let off_c = Translation3::from(Vector3::from(offsets[j.child]));
        for angles in [[0.0, 0.0], [0.4, -0.7], [-1.2, 0.9]] {
            let urdf = off_p.inverse() * urdf_turned(&chain, &angles) * off_c;
            let expected = centre
                * turn(first, angles[0])
                * turn(second, angles[1])
                * centre.inverse()
                * reference;
            let gap = urdf.inverse() * expected;
            assert!(
                gap.translation.vector.norm() < 1e-9 && gap.rotation.angle() < 1e-9,
                "{name} at {angles:?}: {gap}"
            );
            checked += 1;
        }
    }
    assert!(checked >= 12, "{checked} checks");
}

#[test]
fn with_no_static_body_the_configuration_starts_with_the_root_pose() {
    let mut scenario = random_scenario(&RandomParams {
        n_joints: 3,
        prismatic_fraction: 0.0,
        spherical_fraction: 0.5,
        n_frames: 300,
        seed: 5,
        ..RandomParams::default()
    });
    // A base without keypoints: nothing static is seen.
    scenario.mechanism.bodies[0].skip_corners = (0..8).collect();
    let data = simulate(&scenario).expect("simulate");
    let model = discover(&data);
    assert!(model.static_body.is_none());
    assert!(
        model
            .joints
            .iter()
            .any(|j| j.joint_type == JointType::Spherical)
    );
    let seen = kinetree_fit::observe(&model, &data.tracks, Default::default()).expect("observe");
    let root = model.root_body;
    let names: Vec<String> = ["x", "y", "z", "rx", "ry", "rz"]
        .iter()
        .map(|a| format!("root_{root}_{a}"))
        .collect();
    assert_eq!(seen.joint_names[..6], names[..]);
    let joint_columns: usize = model
        .joints
        .iter()
        .map(|j| j.joint_type.n_coordinates().max(1))
        .sum();
    assert_eq!(seen.joint_names.len(), 6 + joint_columns);
    let mut checked = 0;
    for (t, poses) in seen.poses.iter().enumerate() {
        let Some(pose) = poses[root] else { continue };
        let column: Vec<f64> = (0..6).filter_map(|c| seen.positions[c][t]).collect();
        assert_eq!(column.len(), 6, "frame {t}");
        let back = Isometry3::from_parts(
            Translation3::new(column[0], column[1], column[2]),
            UnitQuaternion::from_scaled_axis(Vector3::new(column[3], column[4], column[5])),
        );
        assert!((back.inverse() * pose).translation.vector.norm() < 1e-12);
        assert!((back.inverse() * pose).rotation.angle() < 1e-9);
        checked += 1;
    }
    assert!(checked > 150, "{checked} frames with a root pose");
}

/// A universal wrist or ankle handed to the whole-tree fit as a hinge about its first axis
/// (what the pair test gives when the second angle hides in its rotation noise, as at a
/// finger's knuckle) is typed universal again when `hinges_as_universal` is on, its second
/// axis within 5 deg of the discovered one; the elbows and knees, true hinges, stay revolute.
#[test]
fn a_hinge_hiding_a_second_axis_is_typed_universal_by_the_fit() {
    let data = universal_skeleton(0);
    let found = discover(&data);
    let k = found
        .joints
        .iter()
        .position(|j| j.joint_type == JointType::Universal)
        .expect("a universal joint");
    let second = Vector3::from(found.joints[k].second_axis_in_parent.expect("second axis"));
    let hinges: Vec<usize> = (0..found.joints.len())
        .filter(|&h| found.joints[h].joint_type == JointType::Revolute)
        .collect();
    assert!(!hinges.is_empty(), "the skeleton has hinges");
    let mut model = found.clone();
    {
        let j = &mut model.joints[k];
        j.joint_type = JointType::Revolute;
        j.dof = 1;
        (j.second_axis, j.second_axis_in_parent) = (None, None);
        j.coordinates.clear();
        j.coordinate_std.clear();
        j.smoothed_coordinates.clear();
        j.smoothed_coordinate_std.clear();
    }
    let off = kinetree_fit::TypeByFitLimits::default();
    let state = kinetree_fit::FitState::new(&model, &data.tracks).expect("fit");
    let (_, typed) =
        kinetree_fit::type_joints_by_fit(&mut model.clone(), &data.tracks, state, &off)
            .expect("typing");
    assert!(!typed.contains(&k), "off by default: {typed:?}");
    let on = kinetree_fit::TypeByFitLimits {
        hinges_as_universal: true,
        ..off
    };
    let state = kinetree_fit::FitState::new(&model, &data.tracks).expect("fit");
    let (_, typed) =
        kinetree_fit::type_joints_by_fit(&mut model, &data.tracks, state, &on).expect("typing");
    assert!(typed.contains(&k), "joint {k} not typed: {typed:?}");
    assert_eq!(model.joints[k].joint_type, JointType::Universal);
    let again = Vector3::from(model.joints[k].second_axis_in_parent.expect("second axis"));
    let angle = again
        .normalize()
        .dot(&second.normalize())
        .abs()
        .min(1.0)
        .acos()
        .to_degrees();
    assert!(
        angle < 5.0,
        "second axis {angle:.2} deg off the discovered one"
    );
    for h in hinges {
        assert_eq!(
            model.joints[h].joint_type,
            JointType::Revolute,
            "hinge {h} typed {:?}",
            model.joints[h].joint_type
        );
    }
}

/// Skeletons whose wrists and ankles are universal joints (flexion, then deviation about an
/// axis of the hand or foot): typed universal, centred, their two angles followed, observed in
/// two columns each; the ball joints stay spherical and the hinges revolute.
#[test]
fn universal_wrists_and_ankles_are_typed_centred_and_followed() {
    let (mut joints, mut typed, mut universal, mut centred) = (0, 0, 0, 0);
    let mut worst_centre: f64 = 0.0;
    let mut angle_rms = Vec::new();
    for seed in 0..3 {
        let data = universal_skeleton(seed);
        let model = discover(&data);
        let e = evaluate(&model, &data.truth);
        let map = body_map(&model, &data.truth);
        let offsets = data.truth.mechanism.coordinate_offsets();
        let seen =
            kinetree_fit::observe(&model, &data.tracks, Default::default()).expect("observe");
        for (k, (j, spec)) in e
            .joints
            .iter()
            .zip(&data.truth.mechanism.joints)
            .enumerate()
        {
            joints += 1;
            typed += usize::from(j.found && j.type_ok);
            if spec.joint_type != kinetree_synth::JointType::Universal {
                continue;
            }
            universal += 1;
            if let Some(c) = j.centre_error_in_parent_m {
                worst_centre = worst_centre.max(c);
                centred += usize::from(c <= 0.002);
            }
            let Some((m, joint)) = model
                .joints
                .iter()
                .enumerate()
                .find(|(_, m)| map[m.parent] == spec.parent && map[m.child] == spec.child)
            else {
                continue;
            };
            if joint.joint_type != JointType::Universal {
                continue;
            }
            let column = seen.joint_columns[m];
            assert!(
                seen.joint_names[column].ends_with("_q1"),
                "{:?}",
                seen.joint_names
            );
            assert!(seen.joint_names[column + 1].ends_with("_q2"));
            for i in 0..2 {
                let model_angle: Vec<Option<f64>> = joint
                    .coordinates
                    .iter()
                    .map(|c| c.as_ref().map(|c| c[i]))
                    .collect();
                let truth = &data.truth.joint_positions[offsets[k] + i];
                let rms = kinetree_eval::aligned_rms(&model_angle, truth).expect("aligned");
                // The observer's columns are the model's angles on the frames it was found on.
                let observed = kinetree_eval::aligned_rms(&seen.positions[column + i], truth)
                    .expect("observed");
                assert!((observed - rms).abs() < 1e-6, "{observed} {rms}");
                angle_rms.push(rms);
            }
        }
    }
    assert!(
        typed * 100 >= joints * 95,
        "{typed} of {joints} joints typed right"
    );
    assert_eq!(
        centred, universal,
        "universal centres within 2 mm (worst {worst_centre} m)"
    );
    assert_eq!(
        angle_rms.len(),
        2 * universal,
        "every universal joint's angles"
    );
    // The bundle adjustment fits the axes of small hands and feet to every frame: their
    // angles are 0.006-0.043 rad RMS from the truth, median 0.013.
    angle_rms.sort_by(f64::total_cmp);
    assert!(
        angle_rms[angle_rms.len() / 2] < 0.02 && angle_rms[angle_rms.len() - 1] < 0.08,
        "angle RMS against the truth: {angle_rms:?}"
    );
}

/// The bundle adjustment fits ball and universal joints' centres and axes, and the model
/// states their precision (`centre_std_m`, `axis_std_deg`, `second_axis_std_deg`): on
/// skeletons with universal wrists and ankles at 1 mm, the centres' errors in the parent's
/// frame are within 1.5 times their bound in the RMS, and the axes' too.
#[test]
fn ball_and_universal_joints_reach_their_stated_precision() {
    let (mut centre_z, mut axis_z, mut second_z) = (Vec::new(), Vec::new(), Vec::new());
    let mut centred = 0;
    for seed in 0..6 {
        let data = universal_skeleton(seed);
        let model = discover(&data);
        let e = evaluate(&model, &data.truth);
        for j in &model.joints {
            let is_centred = matches!(j.joint_type, JointType::Spherical | JointType::Universal);
            assert_eq!(
                j.centre_std_m.is_some(),
                is_centred,
                "centre precision of a {:?} joint",
                j.joint_type
            );
            assert_eq!(
                j.second_axis_std_deg.is_some(),
                j.joint_type == JointType::Universal
            );
        }
        for (j, spec) in e.joints.iter().zip(&data.truth.mechanism.joints) {
            if !(j.found && j.type_ok) {
                continue;
            }
            if let Some(z) = j.centre_z {
                centre_z.push(z);
                centred += 1;
            }
            if spec.joint_type != kinetree_synth::JointType::Spherical
                && let Some(z) = j.axis_z
            {
                axis_z.push(z);
            }
            second_z.extend(j.second_axis_z);
        }
    }
    let rms = |z: &[f64]| (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
    let within = |z: &[f64]| z.iter().filter(|&&z| z <= 3.0).count();
    let groups = [
        ("centres", &centre_z),
        ("axes", &axis_z),
        ("second axes", &second_z),
    ];
    for (what, z) in groups {
        eprintln!(
            "{what}: {} joints, errors {:.3} of their bound in the RMS, {} within 3",
            z.len(),
            rms(z),
            within(z)
        );
    }
    assert!(
        centred >= 55 && second_z.len() >= 18,
        "{centred} centres, {} second axes",
        second_z.len()
    );
    for (what, z) in groups {
        let r = rms(z);
        assert!(
            (0.5..=1.5).contains(&r),
            "{what}: errors {r} of their bound in the RMS ({z:?})"
        );
        assert!(
            within(z) * 100 >= z.len() * 95,
            "{what}: {} of {} within 3 bounds",
            within(z),
            z.len()
        );
    }
}

/// Skeletons whose pelvis moves freely: nothing is static, the root's joint is free and the
/// root is the pelvis, every joint is found with its type, and the root's six coordinates,
/// first in the configuration, follow the pelvis' true motion within their stated precision.
#[test]
fn a_floating_pelvis_is_the_free_root_and_its_pose_follows_the_truth() {
    use kinetree_core::model::RootJoint;
    let (mut joints, mut typed, mut frames, mut within) = (0, 0, 0, 0);
    let mut turns = Vec::new();
    for seed in 0..2 {
        let data = simulate(&skeleton_scenario(&SkeletonParams {
            seed,
            floating_pelvis: true,
            ..SkeletonParams::default()
        }))
        .expect("simulate");
        assert_eq!(
            data.truth.mechanism.joints[0].joint_type,
            kinetree_synth::JointType::Free
        );
        let model = discover(&data);
        assert!(model.static_body.is_none());
        assert_eq!(model.root_joint, Some(RootJoint::Free));
        let map = body_map(&model, &data.truth);
        assert_eq!(map[model.root_body], 1, "the pelvis is the root");
        let e = evaluate(&model, &data.truth);
        for j in &e.joints {
            joints += 1;
            typed += usize::from(j.found && j.type_ok);
            assert_eq!(j.miss.is_none(), j.found && j.type_ok, "{j:?}");
        }
        // The same model with its root held static misses the free root, and says so.
        let mut pinned = model.clone();
        pinned.static_body = Some(pinned.root_body);
        assert_eq!(
            evaluate(&pinned, &data.truth).joints[0].miss,
            Some(kinetree_eval::JointMiss::RootNotFree)
        );
        let seen =
            kinetree_fit::observe(&model, &data.tracks, Default::default()).expect("observe");
        assert!(seen.joint_names[0].starts_with("root_"));
        let reference = model.joints[0].reference_frame;
        let truth_pose = |t: usize| {
            let q: Vec<f64> = data.truth.joint_positions.iter().map(|p| p[t]).collect();
            data.truth.cam_from_world * data.truth.mechanism.forward(&q)[1]
        };
        let (Some(model_reference), Some([reference_std, _])) = (
            seen.poses[reference][model.root_body],
            seen.pose_std[reference][model.root_body],
        ) else {
            panic!("the root is posed at the reference frame");
        };
        let true_reference = truth_pose(reference);
        // The pelvis' centre at the reference frame, in the camera frame.
        let centre = true_reference * Point3::new(0.0, 0.0, 1.0);
        for (t, poses) in seen.poses.iter().enumerate() {
            let (Some(pose), Some([turn_std, shift_std])) =
                (poses[model.root_body], seen.pose_std[t][model.root_body])
            else {
                continue;
            };
            // Both motions from the reference frame, in the camera frame, and the precision
            // stated for them.
            let found = pose * model_reference.inverse();
            let truth = truth_pose(t) * true_reference.inverse();
            let turn = (found.rotation.inverse() * truth.rotation).angle();
            let shift = (found * centre - truth * centre).norm();
            let turn_bound = 4.0 * turn_std.hypot(reference_std);
            within += usize::from(turn <= turn_bound && shift <= 4.0 * shift_std + turn_bound);
            turns.push(turn);
            frames += 1;
        }
    }
    assert!(
        typed * 100 >= joints * 95,
        "{typed} of {joints} joints (the free root included) typed right"
    );
    assert!(frames > 500, "{frames} frames with a root pose");
    turns.sort_by(f64::total_cmp);
    assert!(
        within * 100 >= frames * 98 && turns[frames / 2] < 0.015,
        "{within} of {frames} root poses within 4 stated std; median turn error {} rad",
        turns[frames / 2]
    );
}

/// A skeleton whose joints named in `limited` move only through the given amplitudes (radians,
/// one per coordinate; `None` keeps the drawn one).
fn limited_skeleton(seed: u64, limited: &[(&str, &[Option<f64>])]) -> SynthData {
    let mut scenario = skeleton_scenario(&SkeletonParams {
        seed,
        ..SkeletonParams::default()
    });
    let offsets = scenario.mechanism.coordinate_offsets();
    for (name, amplitudes) in limited {
        let k = scenario
            .mechanism
            .joints
            .iter()
            .position(|j| scenario.mechanism.bodies[j.child].name == *name)
            .expect("a segment of the skeleton");
        for (i, a) in amplitudes.iter().enumerate() {
            if let (Some(a), kinetree_synth::Trajectory::Sine { amplitude, .. }) =
                (a, &mut scenario.trajectories[offsets[k] + i])
            {
                *amplitude = *a;
            }
        }
    }
    simulate(&scenario).expect("simulate")
}

/// The `joint_not_identifiable` warnings of `model` for motion too small to tell the types
/// apart: each joint's child and alternatives.
fn verdicts(model: &Model) -> Vec<(usize, Vec<JointType>)> {
    model
        .warnings
        .iter()
        .filter_map(|w| match w {
            kinetree_core::Warning::JointNotIdentifiable {
                child,
                alternatives,
                spread_in_std,
                bound_in_std,
                basis: NotIdentifiableBasis::SmallMotion,
                ..
            } => {
                assert!(spread_in_std < bound_in_std);
                Some((*child, alternatives.clone()))
            }
            _ => None,
        })
        .collect()
}

/// Knees that swing through 3 deg: their shank moves a few millimetres, as a slide would,
/// and the hinge's rotation is a few of its standard deviations. Such a knee comes out
/// revolute, rigid, or prismatic with a `joint_not_identifiable` warning naming the hinge. A
/// shoulder that turned about one axis only is typed revolute, the fewest DoF its motion
/// allows. Joints that moved fully get no such warning.
#[test]
fn a_knee_that_barely_bends_is_a_hinge_or_a_slide_not_identifiable_from_one() {
    let mut slides = 0;
    for seed in 0..6 {
        let data = limited_skeleton(
            seed,
            &[
                ("shank_l", &[Some(0.025)]),
                ("upper_arm_l", &[Some(0.0), None, Some(0.0)]),
            ],
        );
        let model = discover(&data);
        let map = body_map(&model, &data.truth);
        let name = |b: usize| data.truth.mechanism.bodies[map[b]].name.as_str();
        let found = verdicts(&model);
        for j in &model.joints {
            let flagged = found.iter().find(|(c, _)| *c == j.child);
            match (name(j.child), j.joint_type) {
                ("upper_arm_l", t) => assert_eq!(t, JointType::Revolute, "seed {seed}"),
                ("shank_l", JointType::Prismatic) => {
                    slides += 1;
                    assert!(
                        flagged.is_some_and(|(_, a)| a == &[JointType::Revolute]),
                        "seed {seed}: a slide for a knee without a verdict: {found:?}"
                    );
                }
                ("shank_l", _) => {}
                (other, t) => assert!(
                    flagged.is_none(),
                    "seed {seed}: the {other}'s {t} joint, which moved fully: {found:?}"
                ),
            }
        }
    }
    // The class this guards: at this swing some knees do come out as slides.
    assert!(slides >= 1, "no knee came out prismatic");
}

/// The children of `model`'s revolute joints that a `joint_not_identifiable` warning finds
/// turning off their axis, with the spread it states.
fn off_axis_verdicts(model: &Model) -> Vec<(usize, f64)> {
    model
        .warnings
        .iter()
        .filter_map(|w| match w {
            kinetree_core::Warning::JointNotIdentifiable {
                child,
                joint_type: JointType::Revolute,
                alternatives,
                spread_in_std,
                bound_in_std,
                basis: NotIdentifiableBasis::WithinModelError,
                ..
            } => {
                assert!(spread_in_std >= bound_in_std);
                assert_eq!(alternatives, &[JointType::Spherical, JointType::Universal]);
                Some((*child, *spread_in_std))
            }
            _ => None,
        })
        .collect()
}

/// Shoulders and hips that turn mostly about one axis, with secondary swings of 3 deg: the
/// motion-capture settings' model error (0.02 rad a body) takes those swings for skin
/// motion, so the joints come out revolute, and a `joint_not_identifiable` warning says a
/// ball or universal joint fits as well, as the swings exceed the keypoint noise. Knees and
/// elbows, true hinges, get no such warning; nor does any joint with the default settings,
/// which allow no model error and type these shoulders and hips with two or three rotations.
#[test]
fn a_ball_joint_whose_swings_the_model_error_absorbs_is_not_identifiable_from_a_hinge() {
    let swing = 0.06;
    let balls = ["upper_arm_l", "upper_arm_r", "thigh_l", "thigh_r"];
    let hinges = ["forearm_l", "forearm_r", "shank_l", "shank_r"];
    let (mut flagged, mut revolute, mut hinges_judged) = (0, 0, 0);
    let mut spreads = Vec::new();
    let amplitudes = [None, Some(swing), Some(swing)];
    for seed in 0..4 {
        let limited: Vec<(&str, &[Option<f64>])> =
            balls.iter().map(|b| (*b, &amplitudes[..])).collect();
        let data = limited_skeleton(seed, &limited);
        let mocap = Pipeline::from_config(&PipelineConfig::motion_capture())
            .expect("pipeline")
            .run(&data.tracks)
            .expect("discover")
            .model;
        let map = body_map(&mocap, &data.truth);
        let name = |b: usize| data.truth.mechanism.bodies[map[b]].name.as_str();
        let found = off_axis_verdicts(&mocap);
        for j in &mocap.joints {
            let verdict = found.iter().find(|(c, _)| *c == j.child);
            if balls.contains(&name(j.child)) && j.joint_type == JointType::Revolute {
                revolute += 1;
                flagged += usize::from(verdict.is_some());
                spreads.extend(verdict.map(|v| v.1));
            }
            if hinges.contains(&name(j.child)) && j.joint_type == JointType::Revolute {
                hinges_judged += 1;
                assert!(
                    verdict.is_none(),
                    "seed {seed}: the {}: {found:?}",
                    name(j.child)
                );
            }
        }
        let default = discover(&data);
        assert!(
            off_axis_verdicts(&default).is_empty(),
            "seed {seed}: an off-axis verdict without a model error"
        );
        let map = body_map(&default, &data.truth);
        for j in &default.joints {
            let n = data.truth.mechanism.bodies[map[j.child]].name.as_str();
            assert!(
                !balls.contains(&n) || j.joint_type != JointType::Revolute,
                "seed {seed}: the default settings typed the {n} revolute"
            );
        }
    }
    // The class this guards: the model error does make hinges of these balls.
    assert!(
        revolute >= 8,
        "{revolute} shoulders and hips came out revolute"
    );
    assert_eq!(flagged, revolute, "spreads {spreads:?}");
    assert!(
        hinges_judged >= 12,
        "{hinges_judged} knees and elbows judged"
    );
}

/// Slides and hinges of random mechanisms, which move through their whole drawn ranges, are
/// identifiable: no `joint_not_identifiable` warning on a joint typed right.
#[test]
fn full_travel_slides_and_hinges_are_identifiable() {
    let mut judged = 0;
    for seed in 0..6 {
        let data = simulate(&random_scenario(&RandomParams {
            n_joints: 3,
            prismatic_fraction: 0.5,
            seed,
            ..RandomParams::default()
        }))
        .expect("simulate");
        let model = discover(&data);
        let e = evaluate(&model, &data.truth);
        let map = body_map(&model, &data.truth);
        let found = verdicts(&model);
        for (j, spec) in e.joints.iter().zip(&data.truth.mechanism.joints) {
            if !(j.found && j.type_ok) {
                continue;
            }
            judged += 1;
            assert!(
                !found.iter().any(|(c, _)| map[*c] == spec.child),
                "seed {seed}: {found:?}"
            );
        }
    }
    assert!(judged >= 12, "{judged} joints judged");
}
