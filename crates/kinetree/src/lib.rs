//! # kinetree
//!
//! kinetree discovers the kinematic structure of an articulated mechanism (a robot arm, a
//! gantry, a hand, a door, a human body) from tracked 3D keypoints alone: how many rigid
//! bodies there are, which keypoint belongs to which, every body's pose over time, the joints
//! between bodies with their type and axis, the kinematic tree, and the joint positions over
//! time.
//!
//! This crate is the front door: it re-exports what a library user needs. The work is done
//! in the stage crates (`kinetree-dissimilarity`, `kinetree-clustering`, `kinetree-pose`,
//! `kinetree-dof`, `kinetree-structure`) and wired by `kinetree-pipeline`, whose plotting
//! feature this crate leaves off.
//!
//! ## Discovering a model
//!
//! ```
//! use kinetree::{Pipeline, PipelineConfig};
//!
//! // The paper's 2-DoF arm, simulated at 1 mm of noise.
//! let data = kinetree::synth::simulate(&kinetree::synth::paper_arm(0))?;
//! let pipeline = Pipeline::from_config(&PipelineConfig::default())?;
//! let discovery = pipeline.run(&data.tracks)?;
//! let model = &discovery.model;
//! assert_eq!(model.bodies.len(), 3); // the base and two links
//! assert!(model.joints.iter().all(|j| j.joint_type == kinetree::JointType::Revolute));
//! // Every change a repair made is in the trace.
//! for entry in &model.trace {
//!     println!("{} ({:?}): {}", entry.repair, entry.phase, entry.summary);
//! }
//! # Ok::<(), kinetree::Error>(())
//! ```
//!
//! Tracks come from files with [`read_tracks`] (`.npy`, `.csv`, `.c3d`), and configs from
//! TOML with [`config::pipeline_from_toml`]; every key is documented on
//! [`PipelineConfig`] and its parts, and unknown keys are errors.
//!
//! ## Stages and repairs
//!
//! Discovery runs four stages, each a trait object in a [`Pipeline`] field:
//! [`Dissimilarity`], [`Clustering`], [`PoseEstimator`] and [`DofTester`]. After them, the
//! runner asks the [`Repair`]s (`Pipeline::repairs`), phase by phase, for edits to the draft.
//! Each trait is object-safe and returns [`Result`]. A minimal custom stage of each kind:
//!
//! ```
//! use kinetree::{
//!     Clustering, ClusteringInput, Dissimilarity, DissimilarityInput, DissimilarityMatrix,
//!     Pipeline, PipelineConfig, Result, Segmentation,
//! };
//!
//! /// The distance's standard deviation, in noise units.
//! #[derive(Debug)]
//! struct SpreadInSigma;
//!
//! impl Dissimilarity for SpreadInSigma {
//!     fn name(&self) -> &str {
//!         "spread_in_sigma"
//!     }
//!     fn compute(&self, input: &DissimilarityInput<'_>) -> Result<DissimilarityMatrix> {
//!         let values = input
//!             .stats
//!             .var_m2
//!             .iter()
//!             .zip(&input.stats.count)
//!             .map(|(v, &n)| if n >= 2 { v.max(0.0).sqrt() / input.noise_sigma_m } else { f64::NAN })
//!             .collect();
//!         Ok(DissimilarityMatrix {
//!             n_points: input.stats.n_points,
//!             values,
//!             suggested_cut: 3.0,
//!             measure: self.name().into(),
//!         })
//!     }
//! }
//!
//! /// Every point in one body.
//! #[derive(Debug)]
//! struct OneBody;
//!
//! impl Clustering for OneBody {
//!     fn name(&self) -> &str {
//!         "one_body"
//!     }
//!     fn cluster(&self, input: &ClusteringInput<'_>) -> Result<Segmentation> {
//!         Ok(Segmentation::from_raw(&vec![Some(0); input.dissimilarity.n_points], 1))
//!     }
//! }
//!
//! // The point-by-point check after the clustering is off, so the clusterer's bodies stand.
//! let mut config = PipelineConfig::default();
//! config.runner.point_check = false;
//! let mut pipeline = Pipeline::from_config(&config)?;
//! pipeline.dissimilarity = Box::new(SpreadInSigma);
//! pipeline.clustering = Box::new(OneBody);
//! let data = kinetree::synth::simulate(&kinetree::synth::paper_arm(0))?;
//! let grouping = pipeline.group(&data.tracks)?;
//! assert_eq!(grouping.segmentation.n_bodies(), 1);
//! # Ok::<(), kinetree::Error>(())
//! ```
//!
//! ```
//! use kinetree::{
//!     BodyPoses, DofInput, DofTester, Error, PairDof, Pipeline, PipelineConfig, PoseEstimator,
//!     PoseInput, Result,
//! };
//! use std::sync::Arc;
//! use std::sync::atomic::{AtomicUsize, Ordering};
//!
//! /// The default Kabsch poses, counted.
//! #[derive(Debug)]
//! struct Counted(Box<dyn PoseEstimator>, Arc<AtomicUsize>);
//!
//! impl PoseEstimator for Counted {
//!     fn name(&self) -> &str {
//!         "counted_kabsch"
//!     }
//!     fn estimate(&self, input: &PoseInput<'_>) -> Result<BodyPoses> {
//!         self.1.fetch_add(1, Ordering::Relaxed);
//!         self.0.estimate(input)
//!     }
//! }
//!
//! /// Refuses every pair: no joint can be tested.
//! #[derive(Debug)]
//! struct NoTests;
//!
//! impl DofTester for NoTests {
//!     fn name(&self) -> &str {
//!         "no_tests"
//!     }
//!     fn test_pair(&self, _: &DofInput<'_>, _: Option<usize>, _: usize) -> Result<PairDof> {
//!         Err(Error::Degenerate("this tester tests nothing".into()))
//!     }
//! }
//!
//! let calls = Arc::new(AtomicUsize::new(0));
//! let mut pipeline = Pipeline::from_config(&PipelineConfig::default())?;
//! pipeline.pose = Box::new(Counted(PipelineConfig::default().pose.build()?, calls.clone()));
//! pipeline.dof = Box::new(NoTests);
//! let data = kinetree::synth::simulate(&kinetree::synth::paper_arm(0))?;
//! let model = pipeline.run(&data.tracks)?.model;
//! // Without pair tests there is nothing to join the bodies by.
//! assert!(model.pairs.is_empty() && model.joints.is_empty());
//! assert!(calls.load(Ordering::Relaxed) > 0);
//! # Ok::<(), kinetree::Error>(())
//! ```
//!
//! A repair (see [`Repair`] for the phases and edits):
//!
//! ```
//! use kinetree::{Draft, Pipeline, PipelineConfig, Proposal, Repair, RepairContext, RepairPhase, Result};
//!
//! /// Counts the bodies after every pose estimate; proposes nothing.
//! #[derive(Debug, Default)]
//! struct Watch(std::sync::Mutex<Vec<usize>>);
//!
//! impl Repair for Watch {
//!     fn name(&self) -> &str {
//!         "watch"
//!     }
//!     fn phase(&self) -> RepairPhase {
//!         RepairPhase::Bodies
//!     }
//!     fn propose(&self, _: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
//!         if let Ok(mut seen) = self.0.lock() {
//!             seen.push(draft.segmentation.n_bodies());
//!         }
//!         Ok(None)
//!     }
//! }
//!
//! let mut pipeline = Pipeline::from_config(&PipelineConfig::default())?;
//! pipeline.repairs.insert(0, Box::new(Watch::default()));
//! let data = kinetree::synth::simulate(&kinetree::synth::paper_arm(0))?;
//! let model = pipeline.run(&data.tracks)?.model;
//! assert_eq!(model.bodies.len(), 3);
//! # Ok::<(), kinetree::Error>(())
//! ```
//!
//! Built-in repairs are turned off or retuned from TOML, under `[pipeline.repairs.<name>]`;
//! see [`RepairsConfig`].

pub use kinetree_core::model::{Body, Joint, JointType};
pub use kinetree_core::{
    BodyPoses, Clustering, ClusteringInput, Constraints, Dissimilarity, DissimilarityInput,
    DissimilarityMatrix, DofInput, DofTester, Draft, Edit, Error, Model, ModelDraft, ModelMaker,
    PairDof, PairStats, PoseEstimator, PoseInput, Proposal, Repair, RepairContext, RepairLimit,
    RepairPhase, Result, Segmentation, StageSlots, TraceEntry, Tracks, Warning,
};
pub use kinetree_io::{read_model, read_tracks, write_json};
pub use kinetree_pipeline::{
    Discovery, Grouping, Pipeline, PipelineConfig, RepairsConfig, RunnerParams, config, repairs,
};

/// Simulated mechanisms, for trying the pipeline and for tests.
pub mod synth {
    pub use kinetree_synth::{
        GroundTruth, RandomParams, Scenario, SynthData, paper_arm, random_scenario, simulate,
    };
}
