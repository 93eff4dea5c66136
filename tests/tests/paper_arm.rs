//! The paper's 2-DoF arm end to end (issue 2's acceptance tests).

use kinetree_core::Model;
use kinetree_eval::evaluate;
use kinetree_pipeline::config::{DataConfig, PaperArmData};
use kinetree_pipeline::{ExperimentConfig, PAPER_EXPERIMENT_TOML, run_experiment};
use std::path::Path;

fn paper_outcome(seed: u64, estimate_noise: bool) -> kinetree_pipeline::ExperimentOutcome {
    let mut cfg =
        ExperimentConfig::from_toml(PAPER_EXPERIMENT_TOML).expect("embedded config parses");
    if let DataConfig::PaperArm(p) = &mut cfg.data {
        *p = PaperArmData { seed, ..*p };
    }
    if estimate_noise {
        cfg.pipeline.noise_sigma_m = None;
    }
    run_experiment(&cfg, Path::new(".")).expect("paper experiment runs")
}

fn check_paper_structure(model: &Model, truth: &kinetree_synth::GroundTruth) {
    let e = evaluate(model, truth);
    assert!((e.ari - 1.0).abs() < 1e-12, "ARI {}", e.ari);
    assert_eq!(model.bodies.len(), 3, "three bodies");
    assert_eq!(model.static_body, Some(0), "base static and the root");
    assert_eq!(
        model.chain,
        Some(vec![0, 1, 2]),
        "chain base -> link1 -> link2"
    );
    assert!(e.structure_exact, "{e:?}");
    for j in &e.joints {
        assert!(j.type_ok, "joint {} type", j.joint);
        let axis = j.axis_error_deg.expect("axis");
        assert!(axis < 2.0, "joint {} axis error {axis} deg", j.joint);
        let rms = j.position_rms.expect("positions");
        assert!(rms < 0.05, "joint {} RMS {rms} rad", j.joint);
    }
    assert!(
        model
            .joints
            .iter()
            .all(|j| j.joint_type == kinetree_core::model::JointType::Revolute)
    );
}

#[test]
fn paper_arm_structure_axes_and_angles() {
    for seed in [1, 2, 3] {
        let out = paper_outcome(seed, false);
        check_paper_structure(&out.discovery.model, out.truth.as_ref().expect("synthetic"));
    }
}

#[test]
fn paper_arm_with_estimated_noise() {
    // Seed 1 has a base point whose noise came out high over its 48 visible frames; the
    // pairwise clustering discards it and the pose-based attachment brings it back.
    for seed in 1..=4 {
        let out = paper_outcome(seed, true);
        let model = &out.discovery.model;
        let sigma = model.noise.sigma_m;
        assert!((sigma / 0.001 - 1.0).abs() < 0.1, "noise estimate {sigma}");
        check_paper_structure(model, out.truth.as_ref().expect("synthetic"));
    }
}

#[test]
fn table_one_pattern_matches_the_paper() {
    let out = paper_outcome(1, false);
    let m = &out.discovery.model;
    let pair = |a: Option<usize>, b: usize| m.pair(a, b).expect("pair tested");
    // Base: no DoF relative to the camera.
    let base = pair(None, 0);
    assert_eq!((base.translation.rank, base.rotation.rank), (0, 0));
    // Link 1: one rotational DoF relative to the base (and to the camera).
    for a in [None, Some(0)] {
        let p = pair(a, 1);
        assert_eq!(p.rotation.rank, 1);
        assert_eq!(p.centre.rank, 0, "fixed centre of rotation");
        assert_eq!(p.dof, 1);
    }
    // Link 2: rotation rank 1 and translation rank 2 relative to camera and base, so no joint;
    // one rotational DoF relative to link 1.
    for a in [None, Some(0)] {
        let p = pair(a, 2);
        assert_eq!(p.rotation.rank, 1);
        assert_eq!(p.translation.rank, 2);
        assert!(p.centre.rank >= 1, "moving centre: not a joint");
        assert!(p.dof > 1);
    }
    let p = pair(Some(1), 2);
    assert_eq!((p.rotation.rank, p.centre.rank, p.dof), (1, 0, 1));
    // The printed C cells (the paper's uncentred centre matrix): empty for the base, one value
    // for the three revolute pairs, more for link 2 against camera and base.
    assert_eq!(base.centre_uncentred.rank, 0);
    for (a, b) in [(None, 1), (Some(0), 1), (Some(1), 2)] {
        assert_eq!(
            pair(a, b).centre_uncentred.rank,
            1,
            "{a:?}-{b}: fixed centre"
        );
    }
    for a in [None, Some(0)] {
        assert_eq!(
            pair(a, 2).centre_uncentred.rank,
            2,
            "{a:?}-2: moving centre"
        );
    }
    // Rotation singular values of the size of the paper's (18.9, 19.6, 8.9): several radians
    // times sqrt(T).
    for (a, b) in [(None, 1), (None, 2), (Some(1), 2)] {
        let s = pair(a, b).rotation.singular_values[0];
        assert!(
            (5.0..30.0).contains(&s),
            "rotation singular value {s} for {a:?}-{b}"
        );
    }
}

#[test]
fn paper_arm_with_the_chi2_tester() {
    use kinetree_dof::Chi2RankParams;
    use kinetree_pipeline::config::DofConfig;
    let mut cfg =
        ExperimentConfig::from_toml(PAPER_EXPERIMENT_TOML).expect("embedded config parses");
    cfg.pipeline.dof = DofConfig::Chi2Rank(Chi2RankParams::default());
    let out = run_experiment(&cfg, Path::new(".")).expect("runs");
    let m = &out.discovery.model;
    assert_eq!(m.stages.dof, "chi2_rank");
    check_paper_structure(m, out.truth.as_ref().expect("synthetic"));
    // The chi-square rule reports its statistics, and rigid base vs camera sits near 1.
    // The reports render chi-square tests too (the pivot test has no singular values).
    assert!(kinetree_pipeline::report::table_text(m).contains("F0"));
    assert!(kinetree_pipeline::report::table_markdown(m).contains("F0"));
    let base = m.pair(None, 0).expect("pair");
    assert!(base.rotation.threshold.is_none());
    let chi = base.rotation.chi2_per_dof[0];
    assert!(chi > 0.3 && chi < base.rotation.chi2_bound[0], "{chi}");
}

#[test]
fn model_json_round_trips() {
    let out = paper_outcome(2, false);
    let path = std::env::temp_dir().join(format!("kinetree-model-{}.json", std::process::id()));
    kinetree_io::write_json(&path, &out.discovery.model).expect("write");
    let back = kinetree_io::read_model(&path).expect("read back");
    assert_eq!(back.bodies, out.discovery.model.bodies);
    assert_eq!(back.point_body, out.discovery.model.point_body);
    assert_eq!(back.joints.len(), 2);
    assert_eq!(back.pairs.len(), out.discovery.model.pairs.len());
    // Tests with no data (empty centre tests) survive the trip too.
    assert!(back.pairs.iter().any(|p| p.centre.n_columns == 0));
}

#[test]
fn paper_arm_with_dbscan() {
    use kinetree_pipeline::config::ClusteringConfig;
    let mut cfg =
        ExperimentConfig::from_toml(PAPER_EXPERIMENT_TOML).expect("embedded config parses");
    cfg.pipeline.clustering =
        ClusteringConfig::Dbscan(kinetree_clustering::DbscanParams::default());
    let out = run_experiment(&cfg, Path::new(".")).expect("runs");
    assert_eq!(out.discovery.model.stages.clustering, "dbscan");
    check_paper_structure(&out.discovery.model, out.truth.as_ref().expect("synthetic"));
}

#[test]
fn segmentation_diagnostics_on_the_paper_arm() {
    let out = paper_outcome(2, false);
    let m = &out.discovery.model;
    assert_eq!(m.point_confidence.len(), m.n_points);
    for (i, c) in m.point_confidence.iter().enumerate() {
        let c = c.expect("every point assigned");
        // Under the F-test a point's own body averages about 0.5 and other bodies near 1.
        assert!(c > 0.2, "point {i}: confidence {c}");
    }
    for b in &m.bodies {
        let [median, p90] = b.internal_dissimilarity.expect("spread");
        assert!(
            (0.3..0.7).contains(&median),
            "body {}: median q {median}",
            b.id
        );
        assert!(p90 >= median && p90 <= 1.0);
    }
}

/// The committed expected output is what the embedded experiment writes, byte for byte.
#[test]
fn table_md_matches_the_committed_expected_output() {
    let cfg = ExperimentConfig::from_toml(PAPER_EXPERIMENT_TOML).expect("parses");
    let out = run_experiment(&cfg, Path::new(".")).expect("runs");
    let dir = std::env::temp_dir().join(format!("kinetree-expected-{}", std::process::id()));
    kinetree_pipeline::write_results(&cfg, &out, &dir).expect("writes");
    let ours = std::fs::read_to_string(dir.join("table.md")).expect("table.md");
    let expected = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../experiments/paper-table1/expected-table.md"),
    )
    .expect("expected-table.md");
    assert_eq!(ours, expected);
    assert!(ours.contains("The paper's Table I, as printed"));
}
