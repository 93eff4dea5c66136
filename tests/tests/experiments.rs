//! Every TOML file under experiments/ parses (unknown keys are errors) and runs, so configs
//! cannot rot: experiment configs (with an `[experiment]` table) end to end, pipeline configs
//! (such as experiments/real/pipeline.toml) by building their pipeline.

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
        if value.contains_key("experiment") {
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
