//! Core data types, stage traits and the error type of kinetree.
//!
//! No algorithms live here; the stage crates implement the stage traits (re-exported here), and
//! `kinetree-pipeline` wires them together.

mod error;
pub mod geom;
pub mod limits;
pub mod memo;
pub mod model;
mod pairs;
mod poses;
mod repair;
mod segmentation;
mod stage;
pub mod stats;
mod tracks;
mod tree;
mod warning;

pub use error::{Error, Result};
pub use model::Model;
pub use nalgebra;
pub use pairs::{DissimilarityMatrix, PairStats, condensed_index, n_pairs};
pub use poses::{BodyPoses, BodyTrack, JointKind, PairDof, PoseQuality, RankTest};
pub use repair::{
    Constraints, Draft, Edit, FittedPoses, ModelDraft, ModelMaker, Proposal, Repair, RepairContext,
    RepairLimit, RepairPhase, StageSlots, TraceEntry,
};
pub use segmentation::{MIN_BODY_POINTS, Segmentation, inverse_permutation};
pub use stage::{
    Clustering, ClusteringInput, Dissimilarity, DissimilarityInput, DofInput, DofTester,
    PoseEstimator, PoseInput,
};
pub use tracks::{MAX_COORDINATE, MIN_FRAMES, MIN_POINTS, Tracks};
pub use tree::TreeCosts;
pub use warning::{NotIdentifiableBasis, Warning};
