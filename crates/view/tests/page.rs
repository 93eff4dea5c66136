//! The page's data: the tracks as given, and each joint's pivot and axis carried through its
//! parent's fitted pose, which at the joint's reference frame is the model's own.

use base64::Engine as _;
use kinetree_view::{ViewOptions, to_html};

fn data_of(page: &str) -> serde_json::Value {
    let start = page
        .find(r#"<script id="kinetree-data" type="application/json">"#)
        .expect("data element");
    let rest = &page[start..];
    let body = &rest[rest.find('>').expect("tag end") + 1..rest.find("</script>").expect("end")];
    serde_json::from_str(&body.replace("<\\/", "</")).expect("data JSON")
}

fn floats(v: &serde_json::Value) -> Vec<f32> {
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(v.as_str().expect("text"))
        .expect("base64");
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn discovered(seed: u64) -> (kinetree_core::Model, kinetree_core::Tracks) {
    let tracks = kinetree_synth::simulate(&kinetree_synth::paper_arm(seed))
        .expect("simulate")
        .tracks;
    let cfg = kinetree_pipeline::PipelineConfig {
        noise_sigma_m: Some(0.001),
        ..Default::default()
    };
    let model = kinetree_pipeline::Pipeline::from_config(&cfg)
        .expect("pipeline")
        .run(&tracks)
        .expect("discover")
        .model;
    (model, tracks)
}

#[test]
fn the_page_carries_the_tracks_bodies_and_joints() {
    let (model, tracks) = discovered(1);
    let page = to_html(&model, &tracks, &ViewOptions::default()).expect("page");
    let data = data_of(&page);
    let (t, n) = (tracks.n_frames(), tracks.n_points());
    assert_eq!(data["frames"].as_array().map(Vec::len), Some(t));
    let positions = floats(&data["positions"]);
    assert_eq!(positions.len(), t * n * 3);
    for (k, (&shown, &given)) in positions.iter().zip(tracks.raw()).enumerate() {
        assert!(
            (shown.is_nan() && given.is_nan()) || (f64::from(shown) - given).abs() < 1e-6,
            "value {k}"
        );
    }
    assert_eq!(
        data["bodies"].as_array().map(Vec::len),
        Some(model.bodies.len())
    );
    for body in data["bodies"].as_array().expect("bodies") {
        let origin = floats(&body["origin"]);
        assert_eq!(origin.len(), 3 * t);
        let posed = origin.chunks(3).filter(|p| p[0].is_finite()).count();
        assert!(
            posed > t * 9 / 10,
            "body {} posed in {posed} frames",
            body["id"]
        );
    }
    for (joint, shown) in model
        .joints
        .iter()
        .zip(data["joints"].as_array().expect("joints"))
    {
        assert_eq!(shown["type"], "revolute");
        let (pivot, axis, position) = (
            floats(&shown["pivot"]),
            floats(&shown["axis"]),
            floats(&shown["position"]),
        );
        assert_eq!((pivot.len(), axis.len(), position.len()), (3 * t, 3 * t, t));
        // At the reference frame the parent's fitted pose is the one the model's camera-frame
        // axis and point were given through: they agree to the fit's precision.
        let r = joint.reference_frame;
        let model_axis = joint.axis.expect("axis");
        let model_point = joint.point.expect("point");
        let dot: f64 = (0..3)
            .map(|c| f64::from(axis[3 * r + c]) * model_axis[c])
            .sum();
        assert!(
            dot > (1.0f64).to_radians().cos(),
            "axis at the reference frame: {dot}"
        );
        // The pivot is a point of the axis: its offset from the model's point is along it.
        let offset: Vec<f64> = (0..3)
            .map(|c| f64::from(pivot[3 * r + c]) - model_point[c])
            .collect();
        let along: f64 = (0..3).map(|c| offset[c] * model_axis[c]).sum();
        let across = (offset.iter().map(|v| v * v).sum::<f64>() - along * along)
            .max(0.0)
            .sqrt();
        assert!(across < 0.005, "pivot {across} m off the model's axis");
        let moving = position.iter().filter(|p| p.is_finite()).count();
        assert!(moving > t * 9 / 10);
    }
}

#[test]
fn long_recordings_keep_every_kth_frame_and_bad_options_are_refused() {
    let (model, tracks) = discovered(2);
    let n = tracks.n_points();
    let options = ViewOptions {
        max_samples: 10 * n,
        ..ViewOptions::default()
    };
    let data = data_of(&to_html(&model, &tracks, &options).expect("page"));
    let frames: Vec<u64> = data["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .map(|f| f.as_u64().expect("index"))
        .collect();
    assert_eq!(frames, (0..100).step_by(10).collect::<Vec<u64>>());
    assert_eq!(floats(&data["positions"]).len(), 10 * n * 3);
    for bad in [
        ViewOptions {
            max_samples: 0,
            ..ViewOptions::default()
        },
        ViewOptions {
            fps: Some(f64::NAN),
            ..ViewOptions::default()
        },
    ] {
        assert!(to_html(&model, &tracks, &bad).is_err(), "{bad:?}");
    }
    let fewer = tracks.select_frames(&[0, 1, 2]).expect("frames");
    assert!(to_html(&model, &fewer, &ViewOptions::default()).is_ok());
    let other = kinetree_synth::simulate(&kinetree_synth::paper_arm(3))
        .expect("sim")
        .tracks;
    let points: Vec<Vec<Option<kinetree_core::nalgebra::Point3<f64>>>> = (0..other.n_frames())
        .map(|f| (0..5).map(|i| other.get(f, i)).collect())
        .collect();
    let five = kinetree_core::Tracks::from_points(&points).expect("five points");
    let e = to_html(&model, &five, &ViewOptions::default()).expect_err("other points");
    assert!(e.to_string().contains("points"), "{e}");
}

/// With ball joints and no static body, the observer's matrix starts with the root's pose and
/// has three columns per ball: each joint's plot still is its own (a ball's is its angle).
#[test]
fn each_joint_plots_its_own_coordinates_with_a_free_root_and_ball_joints() {
    let mut scenario = kinetree_synth::random_scenario(&kinetree_synth::RandomParams {
        n_joints: 3,
        prismatic_fraction: 0.0,
        spherical_fraction: 0.5,
        n_frames: 300,
        seed: 5,
        ..Default::default()
    });
    scenario.mechanism.bodies[0].skip_corners = (0..8).collect();
    let tracks = kinetree_synth::simulate(&scenario)
        .expect("simulate")
        .tracks;
    let model = kinetree_pipeline::Pipeline::from_config(&Default::default())
        .expect("pipeline")
        .run(&tracks)
        .expect("discover")
        .model;
    assert!(model.static_body.is_none());
    let balls = model
        .joints
        .iter()
        .filter(|j| j.joint_type == kinetree_core::model::JointType::Spherical)
        .count();
    assert!(balls >= 1, "{balls} ball joints");
    let seen = kinetree_fit::observe(&model, &tracks, Default::default()).expect("observe");
    let page = to_html(&model, &tracks, &ViewOptions::default()).expect("page");
    let data = data_of(&page);
    for ((joint, shown), &column) in model
        .joints
        .iter()
        .zip(data["joints"].as_array().expect("joints"))
        .zip(&seen.joint_columns)
    {
        let name = format!("{}_{}_{}", joint.joint_type, joint.parent, joint.child);
        assert_eq!(shown["name"], name.as_str());
        let plotted = floats(&shown["position"]);
        for (f, &p) in plotted.iter().enumerate() {
            let expected = if joint.joint_type == kinetree_core::model::JointType::Spherical {
                (column..column + 3)
                    .map(|c| seen.positions[c][f].map(|v| v * v))
                    .sum::<Option<f64>>()
                    .map(f64::sqrt)
            } else {
                seen.positions[column][f]
            };
            match expected {
                Some(v) => assert!((f64::from(p) - v).abs() < 1e-5, "{name} frame {f}"),
                None => assert!(p.is_nan(), "{name} frame {f}"),
            }
        }
        assert!(plotted.iter().filter(|p| p.is_finite()).count() > 100);
    }
}
