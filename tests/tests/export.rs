//! URDF and DOT export: parsed back with urdf-rs, and the URDF's forward kinematics checked
//! against the poses the pipeline fitted.

use kinetree_core::nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use kinetree_io::export::{joint_name, link_name, link_offsets, to_dot, to_urdf};
use kinetree_pipeline::{Discovery, Pipeline, PipelineConfig};
use kinetree_synth::{MechanismSpec, simulate, strategies};

fn discover(scenario: &kinetree_synth::Scenario) -> Discovery {
    let data = simulate(scenario).expect("simulate");
    Pipeline::from_config(&PipelineConfig::default())
        .expect("pipeline")
        .run(&data.tracks)
        .expect("discover")
}

fn pose(p: &urdf_rs::Pose) -> Isometry3<f64> {
    let [r, pi, y] = p.rpy.0;
    Isometry3::from_parts(
        Translation3::from(Vector3::from(p.xyz.0)),
        UnitQuaternion::from_euler_angles(r, pi, y),
    )
}

/// Parses the URDF and compares, at every frame where a joint has a position, the URDF's
/// transform from parent to child body (joint origin, motion by the position about or along
/// the axis, link offsets) with the relative pose the pipeline fitted. The fitted poses carry
/// per-frame noise (the single-DoF model filters it), so the median and the 95th percentile
/// of the differences are bounded: rotations in units of the two fits' expected rotation
/// noise, translations in metres. A wrong sign, axis frame or offset gives errors that grow
/// with the joint position, tens of degrees over these motions. Returns the number of checks.
fn check_urdf(d: &Discovery, median: (f64, f64), p95: (f64, f64)) -> usize {
    let model = &d.model;
    let text = to_urdf(model).expect("export");
    let robot = urdf_rs::read_from_string(&text).expect("urdf-rs parses our URDF");
    assert_eq!(robot.links.len(), model.bodies.len());
    assert_eq!(robot.joints.len(), model.joints.len());
    let offsets = link_offsets(model).expect("offsets");
    let (mut degs, mut metres) = (Vec::new(), Vec::new());
    for j in &model.joints {
        let u = robot
            .joints
            .iter()
            .find(|u| u.name == joint_name(j.parent, j.child))
            .expect("joint by name");
        assert_eq!(u.parent.link, link_name(j.parent));
        assert_eq!(u.child.link, link_name(j.child));
        let axis = Vector3::from(u.axis.xyz.0);
        match (j.joint_type.as_str(), &u.joint_type) {
            ("revolute", urdf_rs::JointType::Revolute)
            | ("prismatic", urdf_rs::JointType::Prismatic) => {
                let [lo, hi] = j.range.expect("range");
                assert_eq!((u.limit.lower, u.limit.upper), (lo, hi), "limits");
            }
            ("revolute", urdf_rs::JointType::Continuous) => {}
            (ours, theirs) => panic!("joint type {ours} exported as {theirs:?}"),
        }
        assert!((axis.norm() - 1.0).abs() < 1e-9, "unit axis");
        let origin = pose(&u.origin);
        let off_p = Translation3::from(Vector3::from(offsets[j.parent]));
        let off_c = Translation3::from(Vector3::from(offsets[j.child]));
        let (sp, sc) = (j.parent, j.child);
        for (t, q) in j.positions.iter().enumerate() {
            let Some(q) = *q else { continue };
            let (Some(cp), Some(cc)) = (
                d.poses.bodies[sp].cam_from_body[t],
                d.poses.bodies[sc].cam_from_body[t],
            ) else {
                continue;
            };
            let fitted = cp.inverse() * cc;
            let motion = if j.joint_type == kinetree_core::model::JointType::Prismatic {
                Isometry3::from_parts(Translation3::from(axis * q), UnitQuaternion::identity())
            } else {
                Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_scaled_axis(axis * q),
                )
            };
            let urdf = off_p.inverse() * origin * motion * off_c;
            let diff = fitted.inverse() * urdf;
            // In units of the two fits' expected rotation noise (worst axis, three axes).
            let (Some(qp), Some(qc)) =
                (d.poses.bodies[sp].quality[t], d.poses.bodies[sc].quality[t])
            else {
                continue;
            };
            let expected = (3.0 * (qp.rot_std_per_sigma.powi(2) + qc.rot_std_per_sigma.powi(2)))
                .sqrt()
                * model.noise.sigma_m;
            degs.push(diff.rotation.angle() / expected);
            metres.push(diff.translation.vector.norm());
        }
    }
    let quantile = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * q) as usize]
    };
    let checks = degs.len();
    let got = (
        (quantile(&mut degs, 0.5), quantile(&mut metres, 0.5)),
        (quantile(&mut degs, 0.95), quantile(&mut metres, 0.95)),
    );
    assert!(
        got.0.0 < median.0 && got.0.1 < median.1 && got.1.0 < p95.0 && got.1.1 < p95.1,
        "(median, p95) of (rotation / expected noise, m) differences: {got:?}"
    );
    checks
}

#[test]
fn urdf_of_the_paper_arm_reproduces_the_fitted_motion() {
    let d = discover(&kinetree_synth::paper_arm(0));
    assert_eq!(d.model.joints.len(), 2);
    // Joint positions come from the same fitted poses, so the URDF reproduces them up to the
    // single-DoF projection: a rigid residual of about the pose noise.
    let checks = check_urdf(&d, (1.5, 0.005), (3.0, 0.01));
    assert!(checks > 100, "{checks} checks");
}

#[test]
fn urdf_of_random_mechanisms_with_prismatic_joints() {
    use proptest::strategy::{Strategy, ValueTree};
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let strategy = strategies::mechanism(2..=5, proptest::bool::ANY).prop_map(|s| MechanismSpec {
        noise_sigma_m: 0.001,
        dropout: 0.1,
        ..s
    });
    let mut prismatic = 0;
    let mut checked = 0;
    for _ in 0..12 {
        let spec = strategy.new_tree(&mut runner).expect("draw").current();
        let d = discover(&spec.scenario());
        if d.model
            .joints
            .iter()
            .any(|j| j.joint_type == kinetree_core::model::JointType::MultiDof)
        {
            continue;
        }
        prismatic += d
            .model
            .joints
            .iter()
            .filter(|j| j.joint_type == kinetree_core::model::JointType::Prismatic)
            .count();
        // Translations: bodies up to 50 cm carry their rotation noise to their origins.
        check_urdf(&d, (1.5, 0.005), (3.0, 0.02));
        checked += 1;
    }
    assert!(checked >= 8, "{checked} mechanisms checked");
    assert!(prismatic >= 2, "{prismatic} prismatic joints seen");
}

#[test]
fn dot_names_every_body_and_joint() {
    let d = discover(&kinetree_synth::paper_arm(1));
    let dot = to_dot(&d.model);
    assert!(dot.starts_with("digraph kinematic_tree {"));
    assert!(dot.trim_end().ends_with('}'));
    for b in &d.model.bodies {
        assert!(dot.contains(&format!("{} [label=\"body {}", link_name(b.id), b.id)));
    }
    for j in &d.model.joints {
        assert!(dot.contains(&format!(
            "{} -> {} [label=\"{}",
            link_name(j.parent),
            link_name(j.child),
            j.joint_type
        )));
    }
    // Edges: the camera to the root plus one per joint.
    assert_eq!(dot.matches(" -> ").count(), d.model.joints.len() + 1);
}

#[test]
fn a_model_without_reference_poses_cannot_be_exported_to_urdf() {
    let mut m = discover(&kinetree_synth::paper_arm(2)).model;
    m.joints[0].reference_pose = None;
    let e = to_urdf(&m).expect_err("no reference pose");
    assert!(e.to_string().contains("reference_pose"), "{e}");
}
