//! Every TOML file under experiments/ parses (unknown keys are errors) and runs, so configs
//! cannot rot: experiment configs (with an `[experiment]` table) end to end, every value of a
//! sweep's grid in at least one run, pipeline configs (such as experiments/real/pipeline.toml)
//! by building their pipeline.

use kinetree_pipeline::sweep::{Sweep, SweepOptions, run_sweep, runs_csv};
use kinetree_pipeline::{ExperimentConfig, Pipeline, run_experiment};
use rayon::prelude::*;
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
    // The experiments to run end to end: (file, grid point, config).
    let mut runs: Vec<(&PathBuf, usize, ExperimentConfig)> = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).expect("read");
        let value: toml::Table =
            toml::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        // A sweep has a [sweep] table or a list where one value is expected.
        if kinetree_pipeline::sweep::is_sweep(&text) {
            // Every grid point builds its pipeline; with the first seed, the points that bring
            // a grid value no earlier run had run end to end, so every value of every key runs
            // once without the whole product (the ablation grid alone has 240 points).
            let sweep = Sweep::from_toml(&text).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            let seed = sweep.seeds().first().copied().unwrap_or(0);
            let mut ran: Vec<(usize, &toml::Value)> = Vec::new();
            for (p, values) in sweep.points.iter().enumerate() {
                let cfg = sweep.config(p, seed).expect("valid point");
                Pipeline::from_config(&cfg.pipeline)
                    .unwrap_or_else(|e| panic!("{} point {p}: {e}", f.display()));
                let new: Vec<(usize, &toml::Value)> = values
                    .iter()
                    .enumerate()
                    .filter(|kv| !ran.contains(kv))
                    .collect();
                if new.is_empty() && p > 0 {
                    continue;
                }
                runs.push((f, p, cfg));
                ran.extend(new);
            }
            experiments += 1;
        } else if value.contains_key("experiment") {
            let cfg = ExperimentConfig::from_toml(&text)
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            runs.push((f, 0, cfg));
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
    // The runs are independent: run them side by side, as a sweep does.
    runs.par_iter().for_each(|(f, p, cfg)| {
        let out = run_experiment(cfg, f.parent().expect("dir"))
            .unwrap_or_else(|e| panic!("{} point {p}: {e}", f.display()));
        assert!(!out.discovery.model.bodies.is_empty(), "{}", f.display());
    });
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
    let run_all = || {
        run_sweep(
            &sweep,
            Path::new("."),
            &dir,
            &|_, _| {},
            SweepOptions::default(),
        )
        .expect("runs")
    };
    let runs = run_all();
    assert_eq!(runs.len(), 8);
    assert!(runs.iter().all(|r| r.error.is_none() && r.ari.is_some()));
    // The identifiable ARI leaves out points without an identifiable owner: never below 1
    // where every point is on its body.
    for r in &runs {
        let (plain, identifiable) = (r.ari.expect("ari"), r.identifiable_ari.expect("id ari"));
        assert!(plain < 1.0 - 1e-12 || identifiable > 1.0 - 1e-12, "{r:?}");
    }
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
    let again = run_all();
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

/// Lists written in the config fields themselves are grid axes, with no `[sweep]` table.
const INLINE: &str = r#"
[experiment]
name = "inline-sweep"

[data]
kind = "random"
n_joints = 2
n_frames = 120
seed = 5
noise_sigma_m = [0.0005, 0.002]

[pipeline]
dof = [{ kind = "chi2_rank" }, { kind = "svd_rank" }]
"#;

#[test]
fn list_valued_fields_expand_to_a_grid() {
    assert!(kinetree_pipeline::sweep::is_sweep(INLINE));
    assert!(!kinetree_pipeline::sweep::is_sweep(
        &INLINE.replace("[0.0005, 0.002]", "0.001").replace(
            "[{ kind = \"chi2_rank\" }, { kind = \"svd_rank\" }]",
            "{ kind = \"svd_rank\" }"
        )
    ));
    let sweep = Sweep::from_toml(INLINE).expect("parses");
    assert_eq!(
        sweep.keys,
        vec!["data.noise_sigma_m".to_string(), "pipeline.dof".to_string()]
    );
    assert_eq!(sweep.points.len(), 4);
    // No [sweep] table: every point runs once with the config's own seed.
    assert_eq!(sweep.seeds(), vec![5]);
    let cfg = sweep.config(3, 5).expect("config");
    let text = toml::to_string(&cfg).expect("toml");
    assert!(
        text.contains("seed = 5") && text.contains("noise_sigma_m = 0.002"),
        "{text}"
    );
    assert!(text.contains("svd_rank"), "{text}");
    let runs = sweep.run(Path::new("."), &|_, _| {});
    assert_eq!(runs.len(), 4);
    assert!(runs.iter().all(|r| r.error.is_none() && r.ari.is_some()));
    // The identifiable ARI leaves out points without an identifiable owner: never below 1
    // where every point is on its body.
    for r in &runs {
        let (plain, identifiable) = (r.ari.expect("ari"), r.identifiable_ari.expect("id ari"));
        assert!(plain < 1.0 - 1e-12 || identifiable > 1.0 - 1e-12, "{r:?}");
    }
    // Lists also combine with [sweep.grid] and seeds.
    let both = INLINE.replace(
        "[data]",
        "[sweep]\nseeds = 2\n[sweep.grid]\n\"data.n_joints\" = [1, 2, 3]\n\n[data]",
    );
    let sweep = Sweep::from_toml(&both).expect("parses");
    assert_eq!(sweep.points.len(), 12);
    assert_eq!(sweep.seeds(), vec![0, 1]);
}

#[test]
fn bad_list_valued_fields_are_config_errors() {
    for (bad, needle) in [
        // Not a value of the field's type.
        (
            INLINE.replace("[0.0005, 0.002]", "[\"small\", \"large\"]"),
            "data.noise_sigma_m",
        ),
        // An empty list is no grid.
        (
            INLINE.replace("[0.0005, 0.002]", "[]"),
            "data.noise_sigma_m",
        ),
        // Given twice.
        (
            INLINE.replace(
                "[data]",
                "[sweep.grid]\n\"data.noise_sigma_m\" = [0.001]\n\n[data]",
            ),
            "given once",
        ),
        // An unknown key is still an error.
        (INLINE.replace("seed = 5", "seeds = 5"), "seeds"),
    ] {
        assert!(kinetree_pipeline::sweep::is_sweep(&bad), "{bad}");
        let e = Sweep::from_toml(&bad).expect_err("bad sweep");
        assert!(e.to_string().contains(needle), "{needle}: {e}");
    }
}
