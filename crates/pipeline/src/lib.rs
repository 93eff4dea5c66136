//! The kinetree pipeline: config enums -> stages, the run, experiments and reports.
//!
//! This is the only crate that knows every stage. Adding a stage: write its file and trait
//! impl in its crate, add a variant to the slot's enum in [`config`], a match arm in its
//! `build`, and a line in the conformance tests.

mod assemble;
pub mod config;
pub mod conformance;
pub mod duplicates;
pub mod experiment;
pub mod outliers;
pub mod repairs;
pub mod report;
mod run;
pub mod runner;
pub mod sampling;
pub mod sweep;
pub mod unseen;

pub use config::{ExperimentConfig, PAPER_EXPERIMENT_TOML, PipelineConfig};
pub use experiment::{ExperimentOutcome, load_data, run_experiment, write_results};
pub use repairs::RepairsConfig;
pub use run::{Discovery, Grouping, Pipeline};
pub use runner::{DiscoveryObserver, RepairTime, RunnerParams, StageTime, StageTimes};
