//! The four stage traits. Each is object-safe, `Send + Sync`, and returns [`Result`].
//!
//! A stage that needs more input gets a field on its input struct, never a type parameter, so
//! `Box<dyn Stage>` keeps working as the framework grows.

use crate::{BodyPoses, DissimilarityMatrix, PairDof, PairStats, Result, Segmentation, Tracks};

/// Input of a [`Dissimilarity`] stage.
#[derive(Debug, Clone, Copy)]
pub struct DissimilarityInput<'a> {
    /// The tracks.
    pub tracks: &'a Tracks,
    /// Pairwise distance statistics of `tracks`.
    pub stats: &'a PairStats,
    /// Per-coordinate noise std-dev in metres (a distance then has variance about
    /// `2 * noise_sigma_m^2`).
    pub noise_sigma_m: f64,
}

/// Turns pairwise distance statistics into a dissimilarity between points.
pub trait Dissimilarity: Send + Sync + std::fmt::Debug {
    /// Short name used in configs and reports.
    fn name(&self) -> &str;
    /// Computes the dissimilarity of every pair; NaN for pairs with no value.
    ///
    /// # Errors
    /// When the input cannot be used (for example a non-positive noise level).
    fn compute(&self, input: &DissimilarityInput<'_>) -> Result<DissimilarityMatrix>;
}

/// Input of a [`Clustering`] stage.
#[derive(Debug, Clone, Copy)]
pub struct ClusteringInput<'a> {
    /// The dissimilarity matrix (NaN for unknown pairs).
    pub dissimilarity: &'a DissimilarityMatrix,
    /// Seed for any random choice.
    pub seed: u64,
    /// Frames in which each pair was seen together, condensed like the matrix
    /// ([`crate::PairStats::count`]): how much evidence stands behind each value. A clusterer
    /// may weigh pairs by it; `None` when unknown (a matrix not built from pair statistics).
    pub pair_frames: Option<&'a [u32]>,
}

/// Groups points into rigid bodies.
pub trait Clustering: Send + Sync + std::fmt::Debug {
    /// Short name used in configs and reports.
    fn name(&self) -> &str;
    /// Assigns every point to a body or discards it (clusters of fewer than three points).
    ///
    /// # Errors
    /// On invalid input (for example a NaN the method cannot handle).
    fn cluster(&self, input: &ClusteringInput<'_>) -> Result<Segmentation>;
}

/// Input of a [`PoseEstimator`] stage.
#[derive(Debug, Clone, Copy)]
pub struct PoseInput<'a> {
    /// The tracks.
    pub tracks: &'a Tracks,
    /// Which point belongs to which body.
    pub segmentation: &'a Segmentation,
    /// Per-coordinate noise std-dev in metres (used to judge degenerate point sets).
    pub noise_sigma_m: f64,
}

/// Estimates every body's pose in every frame.
pub trait PoseEstimator: Send + Sync + std::fmt::Debug {
    /// Short name used in configs and reports.
    fn name(&self) -> &str;
    /// One [`crate::BodyTrack`] per body of the segmentation.
    ///
    /// # Errors
    /// On inconsistent input (segmentation and tracks of different sizes).
    fn estimate(&self, input: &PoseInput<'_>) -> Result<BodyPoses>;
}

/// Input of a [`DofTester`] stage.
#[derive(Debug, Clone, Copy)]
pub struct DofInput<'a> {
    /// Body poses.
    pub poses: &'a BodyPoses,
    /// Per-coordinate noise std-dev in metres.
    pub noise_sigma_m: f64,
}

/// Tests the relative motion of pairs of frames for their degrees of freedom.
pub trait DofTester: Send + Sync + std::fmt::Debug {
    /// Short name used in configs and reports.
    fn name(&self) -> &str;
    /// Tests body `b` relative to frame `a` (the camera when `None`). The result must depend
    /// only on the two bodies' tracks, the noise level and the tester's own parameters: the
    /// runner answers a test it has made before on the same inputs from its memo
    /// ([`crate::memo`]).
    ///
    /// # Errors
    /// [`crate::Error::Degenerate`] when the two are never registered in the same frame.
    fn test_pair(&self, input: &DofInput<'_>, a: Option<usize>, b: usize) -> Result<PairDof>;
    /// The rotation, radians (std-dev per body), that the tests allow each body beyond its
    /// pose noise: a real joint's play or the skin under markers. With an allowance, a hinge
    /// whose child turns off its axis by more than noise explains is reported as not
    /// identifiable from a ball or universal joint. Zero (the default) for ideal joints.
    fn model_error_rad(&self) -> f64 {
        0.0
    }
}
