//! Every TOML file under experiments/ parses (unknown keys are errors) and runs, so configs
//! cannot rot: experiment configs (with an `[experiment]` table) end to end, pipeline configs
//! (such as experiments/real/pipeline.toml) by building their pipeline.

use kinetree_pipeline::sweep::{Sweep, run_sweep, runs_csv};
use kinetree_pipeline::{ExperimentConfig, Pipeline, run_experiment};
use std::path::{Path, PathBuf};

fn tomls(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("readable")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            // `results/` holds outputs (a sweep's resolved.toml), not configs.
            if p.file_name().is_some_and(|n| n == "results") {
                continue;
            }
            tomls(&p, out);
        } else if p.extension().is_some_and(|e| e == "toml") {
            out.push(p);
        }
    }
}

#[test]
fn every_config_under_experiments_parses_and_runs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../experiments");
    let mut files = Vec::new();
    tomls(&root, &mut files);
    assert!(files.len() >= 2, "{files:?}");
    let (mut experiments, mut pipelines) = (0, 0);
    for f in &files {
        let text = std::fs::read_to_string(f).expect("read");
        let value: toml::Table =
            toml::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        if value.contains_key("sweep") {
            // Quick profile: every grid point once, with the first seed.
            let sweep = Sweep::from_toml(&text).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            let seed = sweep.seeds().first().copied().unwrap_or(0);
            for p in 0..sweep.points.len() {
                let cfg = sweep.config(p, seed).expect("valid point");
                run_experiment(&cfg, f.parent().expect("dir"))
                    .unwrap_or_else(|e| panic!("{} point {p}: {e}", f.display()));
            }
            experiments += 1;
        } else if value.contains_key("experiment") {
            let cfg = ExperimentConfig::from_toml(&text)
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            let out = run_experiment(&cfg, f.parent().expect("dir"))
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            assert!(!out.discovery.model.bodies.is_empty(), "{}", f.display());
            experiments += 1;
        } else {
            let cfg = kinetree_pipeline::config::pipeline_from_toml(&text)
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            Pipeline::from_config(&cfg).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            pipelines += 1;
        }
    }
    assert!(
        experiments >= 1 && pipelines >= 1,
        "{experiments} {pipelines}"
    );
}

const SWEEP: &str = r#"
[experiment]
name = "tiny-sweep"

[sweep]
seeds = [4, 9]

[sweep.grid]
"data.noise_sigma_m" = [0.0005, 0.002]
"pipeline.dof" = [{ kind = "chi2_rank" }, { kind = "svd_rank" }]

[data]
kind = "random"
n_joints = 2
n_frames = 120
"#;

#[test]
fn a_sweep_expands_its_grid_over_seeds_and_writes_its_tables() {
    let sweep = Sweep::from_toml(SWEEP).expect("parses");
    assert_eq!(sweep.points.len(), 4);
    assert_eq!(sweep.seeds(), vec![4, 9]);
    // The seed and the grid values land in the run's config.
    let cfg = sweep.config(3, 9).expect("config");
    let data = toml::to_string(&cfg.data).expect("toml");
    assert!(
        data.contains("seed = 9") && data.contains("noise_sigma_m = 0.002"),
        "{data}"
    );
    let dir = std::env::temp_dir().join(format!("kinetree-sweep-{}", std::process::id()));
    let runs = run_sweep(&sweep, Path::new("."), &dir, &|_, _| {}).expect("runs");
    assert_eq!(runs.len(), 8);
    assert!(runs.iter().all(|r| r.error.is_none() && r.ari.is_some()));
    let csv = std::fs::read_to_string(dir.join("runs.csv")).expect("runs.csv");
    assert_eq!(csv, runs_csv(&sweep, &runs));
    assert_eq!(csv.lines().count(), 9, "{csv}");
    let table = std::fs::read_to_string(dir.join("table.md")).expect("table.md");
    assert_eq!(table.matches("| 2 | 0 |").count(), 4, "{table}");
    let resolved = std::fs::read_to_string(dir.join("resolved.toml")).expect("resolved");
    assert!(
        resolved.contains("[sweep]") && resolved.contains("[pipeline.clustering]"),
        "{resolved}"
    );
    // Same seeds, same runs: the sweep is deterministic whatever the thread order.
    let again = run_sweep(&sweep, Path::new("."), &dir, &|_, _| {}).expect("runs");
    assert_eq!(runs_csv(&sweep, &again), csv);
}

#[test]
fn bad_sweeps_are_config_errors() {
    for (bad, needle) in [
        (
            SWEEP.replace("\"data.noise_sigma_m\"", "\"data.noise_sigmaa\""),
            "noise_sigmaa",
        ),
        (SWEEP.replace("[0.0005, 0.002]", "0.001"), "non-empty list"),
        (
            SWEEP.replace("seeds = [4, 9]", "seeds = [4, 9]\nrepeat = 2"),
            "repeat",
        ),
    ] {
        let e = Sweep::from_toml(&bad).expect_err("bad sweep");
        assert!(e.to_string().contains(needle), "{e}");
    }
}
