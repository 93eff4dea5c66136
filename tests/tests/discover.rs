//! `discover` on other mechanisms, through .npy and .csv files.

use kinetree_eval::evaluate;
use kinetree_io::{read_tracks, write_csv, write_npy};
use kinetree_pipeline::{Pipeline, PipelineConfig};
use kinetree_synth::{RandomParams, random_scenario, simulate};

fn roundtrip_and_discover(params: RandomParams) {
    let data = simulate(&random_scenario(&params)).expect("simulate");
    let dir = std::env::temp_dir().join(format!(
        "kinetree-discover-{}-{}",
        std::process::id(),
        params.seed
    ));
    std::fs::create_dir_all(&dir).expect("dir");
    let npy = dir.join("tracks.npy");
    let csv = dir.join("tracks.csv");
    write_npy(&npy, &data.tracks).expect("npy");
    write_csv(&csv, &data.tracks).expect("csv");
    let from_npy = read_tracks(&npy).expect("read npy");
    let from_csv = read_tracks(&csv).expect("read csv");
    // Occluded entries are NaN, so compare observation by observation (NaN != NaN).
    assert_eq!(from_npy.n_frames(), data.tracks.n_frames());
    assert_eq!(from_npy.n_points(), data.tracks.n_points());
    assert_eq!(
        from_csv.n_points(),
        data.tracks.n_points(),
        "declared size kept"
    );
    assert_eq!(from_csv.n_frames(), data.tracks.n_frames());
    for t in 0..data.tracks.n_frames() {
        for i in 0..data.tracks.n_points() {
            assert_eq!(
                from_npy.get(t, i),
                data.tracks.get(t, i),
                "npy frame {t} point {i}"
            );
            assert_eq!(
                from_csv.get(t, i),
                data.tracks.get(t, i),
                "csv frame {t} point {i}"
            );
        }
    }
    let pipeline = Pipeline::from_config(&PipelineConfig::default()).expect("pipeline");
    for tracks in [&from_npy, &from_csv] {
        let d = pipeline.run(tracks).expect("discover");
        let e = evaluate(&d.model, &data.truth);
        assert!(e.structure_exact, "seed {}: {e:?}", params.seed);
        for j in &e.joints {
            assert!(j.axis_error_deg.is_some_and(|a| a < 3.0), "{j:?}");
        }
        let sigma = d.model.noise.sigma_m;
        assert!(
            (sigma / params.noise_sigma_m - 1.0).abs() < 0.1,
            "noise estimate {sigma}"
        );
    }
}

#[test]
fn chain_with_prismatic_and_revolute_joints() {
    roundtrip_and_discover(RandomParams {
        n_joints: 4,
        prismatic_fraction: 0.5,
        seed: 2,
        dropout: 0.2,
        ..RandomParams::default()
    });
}

#[test]
fn branching_tree() {
    roundtrip_and_discover(RandomParams {
        n_joints: 5,
        tree: true,
        seed: 3,
        dropout: 0.2,
        ..RandomParams::default()
    });
}

/// A random box mechanism simulated, and the default pipeline's model of it.
fn discovered(params: &RandomParams) -> (kinetree_synth::SynthData, kinetree_core::Model) {
    let data = simulate(&random_scenario(params)).expect("simulate");
    let model = kinetree_tests::discover_default(&data.tracks);
    (data, model)
}

#[test]
fn a_body_mixing_two_bodies_is_split_and_not_merged_back() {
    use kinetree_core::Warning;
    // A 3-joint chain seen for 20 frames in which the clustering merges two bodies: the
    // merged body fits at about 8 sigma and must be split, and its parts must not be merged
    // back.
    let params = RandomParams {
        n_frames: 20,
        seed: 5,
        ..RandomParams::default()
    };
    let (data, model) = discovered(&params);
    let m = &model;
    assert!(
        m.warnings
            .iter()
            .any(|w| matches!(w, Warning::BodySplit { .. })),
        "{:?}",
        m.warnings
    );
    let e = evaluate(m, &data.truth);
    assert_eq!(e.n_bodies_found, 4, "{e:?}");
    assert!(e.ari > 0.95, "{e:?}");
    let sigma = m.noise.sigma_m;
    for b in &m.bodies {
        let r = b.median_residual_m.expect("registered");
        assert!(
            r < 3.0 * sigma,
            "body {} still fits at {:.1} sigma",
            b.id,
            r / sigma
        );
    }
}

/// A 3-joint chain seen for 20 frames (seed 13): a body mixing two links fits at 2.57 sigma.
/// Rigid bodies fit under 1.5 sigma once their shapes are refined, and the split's test for
/// two bodies in one finds them even under a residual bound of 3 sigma, so the body is split;
/// every joint is then found and every identifiable point placed.
#[test]
fn a_mixed_body_fitting_under_three_sigma_is_split() {
    use kinetree_core::Warning;
    let params = RandomParams {
        n_frames: 20,
        seed: 13,
        ..RandomParams::default()
    };
    let (data, model) = discovered(&params);
    let m = &model;
    let split: Vec<f64> = m
        .warnings
        .iter()
        .filter_map(|w| match w {
            Warning::BodySplit {
                residual_in_sigma, ..
            } => Some(*residual_in_sigma),
            _ => None,
        })
        .collect();
    assert!(
        split.iter().any(|&r| r > 2.5 && r < 3.0),
        "splits at {split:?} sigma"
    );
    let e = evaluate(m, &data.truth);
    assert!(e.joints_exact, "{e:?}");
    let amb = kinetree_eval::ambiguous_points(&data.tracks, &data.truth, params.noise_sigma_m);
    let ari = kinetree_eval::identifiable_ari(m, &data.truth, &amb);
    assert!(ari > 1.0 - 1e-12, "identifiable ARI {ari}");
}

#[test]
fn revolute_on_a_perpendicular_prismatic_is_not_a_joint_to_the_base() {
    use kinetree_core::JointKind;
    use kinetree_synth::{
        BodySpec, BoxShape, Camera, JointSpec, JointType, Mechanism, Scenario, Trajectory,
    };
    // Base -> carriage sliding along x -> arm turning about z (perpendicular to the slide).
    // Relative to the base the arm's centre of rotation moves along a line (centre rank 1):
    // the base-arm pair must not be taken for a joint.
    let body = |name: &str, centre: [f64; 3], half: [f64; 3], n: usize| BodySpec {
        name: name.into(),
        shape: BoxShape {
            centre,
            half_extents: half,
        },
        skip_corners: (0..8).collect(),
        extra_points: 0,
        interior_points: n,
        marked_points: Vec::new(),
    };
    let scenario = Scenario {
        mechanism: Mechanism {
            bodies: vec![
                body("base", [0.0, 0.0, -0.05], [0.3, 0.2, 0.05], 8),
                body("carriage", [0.0, 0.0, 0.05], [0.1, 0.08, 0.05], 8),
                body("arm", [0.15, 0.0, 0.15], [0.15, 0.03, 0.03], 8),
            ],
            joints: vec![
                JointSpec {
                    parent: 0,
                    child: 1,
                    joint_type: JointType::Prismatic,
                    axis: [1.0, 0.0, 0.0],
                    anchor: [0.0; 3],
                    second_axis: None,
                },
                JointSpec {
                    parent: 1,
                    child: 2,
                    joint_type: JointType::Revolute,
                    axis: [0.0, 0.0, 1.0],
                    anchor: [0.0, 0.0, 0.15],
                    second_axis: None,
                },
            ],
        },
        trajectories: vec![
            Trajectory::Sine {
                offset: 0.0,
                amplitude: 0.12,
                frequency_hz: 0.3,
                phase_rad: 0.0,
            },
            Trajectory::Sine {
                offset: 0.0,
                amplitude: 1.0,
                frequency_hz: 0.55,
                phase_rad: 1.0,
            },
        ],
        n_frames: 200,
        frame_rate_hz: 30.0,
        camera: Camera::looking_at([1.5, -1.5, 1.2], [0.0, 0.0, 0.1], 90.0, 80.0),
        noise_sigma_m: 0.001,
        dropout: 0.1,
        seed: 5,
        self_occlusion: false,
        partly_seen: Vec::new(),
        soft_tissue_m: 0.0,
    };
    let data = simulate(&scenario).expect("simulate");
    for dof in ["", "[dof]\nkind = \"svd_rank\"\n"] {
        let cfg = kinetree_pipeline::config::pipeline_from_toml(dof).expect("config");
        let d = Pipeline::from_config(&cfg)
            .expect("pipeline")
            .run(&data.tracks)
            .expect("discover");
        let e = evaluate(&d.model, &data.truth);
        assert!(e.joints_exact, "{dof:?}: {e:?}");
        let base = d.model.static_body.expect("static base");
        let arm = (0..d.model.bodies.len())
            .find(|&b| d.model.bodies[b].points.contains(&16))
            .expect("arm body");
        let pair = d.model.pair(Some(base), arm).expect("base-arm pair");
        assert!(
            !matches!(
                pair.joint,
                JointKind::Revolute { .. } | JointKind::Prismatic { .. }
            ),
            "{dof:?}: base-arm taken for a joint: {:?}",
            pair.joint
        );
    }
}

#[test]
fn heavy_occlusion_keeps_most_mechanisms_right() {
    use proptest::strategy::{Just, Strategy, ValueTree};
    use proptest::test_runner::TestRunner;
    // Issue 3's occlusion regime: 50 % and 60 % of observations hidden in bursts. Measured:
    // 35/40 chains of 2-5 joints with every joint right at both levels, and 16/20 on the
    // first 20 used here. The bound (one fewer) catches a regression without depending
    // on any one mechanism.
    const N: usize = 20;
    const MIN_RIGHT: usize = 15;
    for dropout in [0.5, 0.6] {
        let mut runner = TestRunner::deterministic();
        let mut right = 0;
        for _ in 0..N {
            let spec = kinetree_synth::strategies::mechanism(2..=5, Just(false))
                .new_tree(&mut runner)
                .expect("draw")
                .current();
            let mut scenario = spec.scenario();
            scenario.dropout = dropout;
            let data = simulate(&scenario).expect("simulate");
            let occluded = data.truth.occluded_fraction;
            assert!((occluded - dropout).abs() < 0.05, "occluded {occluded}");
            if let Ok(d) = Pipeline::from_config(&PipelineConfig::default())
                .expect("pipeline")
                .run(&data.tracks)
            {
                right += usize::from(evaluate(&d.model, &data.truth).joints_exact);
            }
        }
        assert!(
            right >= MIN_RIGHT,
            "{dropout}: {right}/{N} mechanisms right"
        );
    }
}

/// A marker that is not rigid with any body (a loose marker wobbling by a few centimetres on
/// its link) is left off the bodies, and the summary names it by its label.
#[test]
fn a_loose_marker_is_left_out_and_named() {
    use kinetree_core::nalgebra::{Point3, Vector3};
    let (data, _) = discovered(&RandomParams {
        n_joints: 2,
        seed: 3,
        ..RandomParams::default()
    });
    let tracks = &data.tracks;
    let n = tracks.n_points();
    // The loose marker follows the last point of the last body, 3 cm off it and swinging
    // through 2.5 cm about that offset.
    let carrier = (0..n)
        .rev()
        .find(|&i| data.truth.point_body[i] == data.truth.n_bodies() - 1)
        .expect("a point on the last body");
    let frames: Vec<Vec<Option<Point3<f64>>>> = (0..tracks.n_frames())
        .map(|t| {
            let phase = t as f64 * 0.37;
            let wobble = Vector3::new(0.03 + 0.025 * phase.sin(), 0.025 * phase.cos(), 0.0);
            let mut row: Vec<Option<Point3<f64>>> = (0..n).map(|i| tracks.get(t, i)).collect();
            row.push(tracks.get(t, carrier).map(|p| p + wobble));
            row
        })
        .collect();
    let mut labels: Vec<String> = (0..n).map(|i| format!("M{i}")).collect();
    labels.push("LOOSE".into());
    let with_loose = kinetree_core::Tracks::from_points(&frames)
        .expect("tracks")
        .with_labels(labels)
        .expect("labels");
    let model = kinetree_tests::discover_default(&with_loose);
    assert_eq!(model.point_body[n], -1, "the loose marker is on a body");
    let summary = kinetree_pipeline::report::summary(&model);
    assert!(
        summary
            .lines()
            .any(|l| l.contains("warning") && l.contains("markers LOOSE")),
        "{summary}"
    );
    let e = evaluate(&model, &data.truth);
    assert_eq!(e.n_bodies_found, data.truth.n_bodies(), "{e:?}");
}

/// An observer that records the stages it is told, in order.
#[derive(Default)]
struct Stages(std::sync::Mutex<Vec<String>>);

impl kinetree_pipeline::DiscoveryObserver for Stages {
    fn stage(&self, name: &str) {
        self.0.lock().expect("lock").push(name.to_string());
    }
}

/// An observer that records every repair time it is told.
#[derive(Default)]
struct RepairCalls(std::sync::Mutex<Vec<(String, f64)>>);

impl kinetree_pipeline::DiscoveryObserver for RepairCalls {
    fn repair_time(&self, repair: &str, seconds: f64) {
        self.0
            .lock()
            .expect("lock")
            .push((repair.to_string(), seconds));
    }
}

/// `StageTimes` sums each repair's calls as the discovery reports them, passes every call on,
/// and lists the repairs longest first; every repair asked is one of the pipeline's, the fit
/// phase's `free_joints` and `bundle_adjust` among them.
#[test]
fn repair_times_sum_every_call_of_each_repair() {
    let data = simulate(&kinetree_synth::paper_arm(0)).expect("simulate");
    let pipeline = Pipeline::from_config(&PipelineConfig::default()).expect("pipeline");
    let seen = RepairCalls::default();
    let timer = kinetree_pipeline::StageTimes::new(&seen);
    pipeline
        .run_observed(&data.tracks, &timer)
        .expect("discover");
    let calls = seen.0.lock().expect("lock").clone();
    let totals = timer.repair_totals();
    let names: Vec<&str> = pipeline.repairs.iter().map(|r| r.name()).collect();
    assert!(!totals.is_empty());
    for t in &totals {
        assert!(
            names.contains(&t.repair.as_str()),
            "{} is no repair",
            t.repair
        );
        let own: Vec<f64> = calls
            .iter()
            .filter(|(n, _)| *n == t.repair)
            .map(|(_, s)| *s)
            .collect();
        assert_eq!(t.calls, own.len(), "{}", t.repair);
        let sum: f64 = own.iter().sum();
        assert!(
            (t.seconds - sum).abs() <= 1e-9 * sum.max(1.0),
            "{}",
            t.repair
        );
        assert!(t.seconds.is_finite() && t.seconds >= 0.0);
    }
    assert_eq!(
        totals.iter().map(|t| t.calls).sum::<usize>(),
        calls.len(),
        "every call counted once"
    );
    assert!(totals.windows(2).all(|w| w[0].seconds >= w[1].seconds));
    for repair in ["free_joints", "bundle_adjust"] {
        assert!(
            totals.iter().any(|t| t.repair == repair),
            "{repair}: {totals:?}"
        );
    }
}

/// `StageTimes` times every stage the discovery announces, in their first order, after the
/// setup, and passes each announcement on to the observer it wraps.
#[test]
fn stage_times_cover_every_stage_and_pass_them_on() {
    let data = simulate(&kinetree_synth::paper_arm(0)).expect("simulate");
    let pipeline = Pipeline::from_config(&PipelineConfig::default()).expect("pipeline");
    let seen = Stages::default();
    let timer = kinetree_pipeline::StageTimes::new(&seen);
    pipeline
        .run_observed(&data.tracks, &timer)
        .expect("discover");
    let totals = timer.totals();
    let told = seen.0.lock().expect("lock").clone();
    assert!(told.len() >= 7, "stages told: {told:?}");
    assert_eq!(totals[0].stage, "setup");
    // One row per distinct stage, in the order each first started, counting its starts.
    let mut distinct: Vec<&String> = Vec::new();
    for name in &told {
        if !distinct.contains(&name) {
            distinct.push(name);
        }
    }
    let rows: Vec<&String> = totals[1..].iter().map(|s| &s.stage).collect();
    assert_eq!(rows, distinct);
    for row in &totals[1..] {
        let starts = told.iter().filter(|n| **n == row.stage).count();
        assert_eq!(row.starts, starts, "{}", row.stage);
    }
    for stage in [
        "pair statistics",
        "clustering",
        "bodies",
        "tree",
        "whole-tree fit",
    ] {
        assert!(rows.iter().any(|r| *r == stage), "{stage} in {rows:?}");
    }
    assert!(
        totals
            .iter()
            .all(|s| s.seconds.is_finite() && s.seconds >= 0.0),
        "{totals:?}"
    );
}
