//! Configuration: one serde enum per stage slot, every variant wrapping a params struct.

use crate::repairs::RepairsConfig;
use crate::runner::RunnerParams;
use kinetree_clustering::{
    Dbscan, DbscanParams, Hierarchical, HierarchicalParams, Spectral, SpectralParams,
};
use kinetree_core::model::PositionLimits;
use kinetree_core::{Clustering, Dissimilarity, DofTester, Error, PoseEstimator, Result};
use kinetree_dissimilarity::{
    DistanceStd, DistanceVariance, FTest, FTestParams, LogPValue, LogPValueParams, SpreadParams,
};
use kinetree_dof::{Chi2Rank, Chi2RankParams, SvdRank, SvdRankParams};
use kinetree_pose::{KabschParams, KabschPoses};
use kinetree_synth::RandomParams;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Dissimilarity slot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DissimilarityConfig {
    /// The paper's F-test q.
    FTest(FTestParams),
    /// `-log10` of the F-test p-value (does not saturate).
    LogPValue(LogPValueParams),
    /// Distance std-dev.
    DistanceStd(SpreadParams),
    /// Distance variance.
    DistanceVariance(SpreadParams),
}

/// The default is the paper's `f_test`: `log_p_value` got every point right slightly more
/// often on 200 mechanisms with keypoints in general position (171 against 166) but lost a
/// 4-joint chain that `f_test` gets right (`tests/tests/discover.rs`), a trade too small to
/// leave the paper's measure (`docs/decisions.md`, `dissimilarity default`).
impl Default for DissimilarityConfig {
    fn default() -> Self {
        Self::FTest(FTestParams::default())
    }
}

impl DissimilarityConfig {
    /// Builds the stage.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn build(&self) -> Result<Box<dyn Dissimilarity>> {
        Ok(match self {
            Self::FTest(p) => Box::new(FTest::new(*p)?),
            Self::LogPValue(p) => Box::new(LogPValue::new(*p)?),
            Self::DistanceStd(p) => Box::new(DistanceStd::new(*p)?),
            Self::DistanceVariance(p) => Box::new(DistanceVariance::new(*p)?),
        })
    }
}

/// Clustering slot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ClusteringConfig {
    /// Agglomerative clustering (kodama).
    Hierarchical(HierarchicalParams),
    /// DBSCAN on the matrix.
    Dbscan(DbscanParams),
    /// Spectral clustering (normalised Laplacian, eigengap, k-means).
    Spectral(SpectralParams),
    /// A Gaussian mixture on the spectral embedding (linfa-clustering), as many components
    /// as the eigengap finds.
    #[cfg(feature = "linfa")]
    SpectralGmm(kinetree_clustering::SpectralGmmParams),
    /// DBSCAN on the spectral embedding (linfa-clustering), which finds the number of bodies
    /// itself.
    #[cfg(feature = "linfa")]
    SpectralDbscan(kinetree_clustering::SpectralDbscanParams),
}

impl Default for ClusteringConfig {
    fn default() -> Self {
        Self::Hierarchical(HierarchicalParams::default())
    }
}

impl ClusteringConfig {
    /// Builds the stage.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn build(&self) -> Result<Box<dyn Clustering>> {
        Ok(match self {
            Self::Hierarchical(p) => Box::new(Hierarchical::new(*p)?),
            Self::Dbscan(p) => Box::new(Dbscan::new(*p)?),
            Self::Spectral(p) => Box::new(Spectral::new(*p)?),
            #[cfg(feature = "linfa")]
            Self::SpectralGmm(p) => Box::new(kinetree_clustering::SpectralGmm::new(*p)?),
            #[cfg(feature = "linfa")]
            Self::SpectralDbscan(p) => Box::new(kinetree_clustering::SpectralDbscan::new(*p)?),
        })
    }
}

/// Pose slot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PoseConfig {
    /// Kabsch-Umeyama against reference shapes.
    Kabsch(KabschParams),
}

impl Default for PoseConfig {
    fn default() -> Self {
        Self::Kabsch(KabschParams::default())
    }
}

impl PoseConfig {
    /// Builds the stage.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn build(&self) -> Result<Box<dyn PoseEstimator>> {
        Ok(match self {
            Self::Kabsch(p) => Box::new(KabschPoses::new(*p)?),
        })
    }
}

/// DoF-tester slot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DofConfig {
    /// The paper's SVD ranks with noise-derived thresholds.
    SvdRank(SvdRankParams),
    /// The same tests decided by chi-square with full per-frame covariances.
    Chi2Rank(Chi2RankParams),
}

/// The default is `chi2_rank` with its reference-free pivot test: it found every joint with
/// its type on 190 of 200 mechanisms with keypoints in general position, against 165 for the
/// paper's `svd_rank`, whose worst-axis whitening hides the rotation of slender bodies
/// (`docs/decisions.md`, `dof default`). Its decisions pass the invariance tests (camera
/// motion, units, time reversal). The paper experiment names `svd_rank` explicitly.
impl Default for DofConfig {
    fn default() -> Self {
        Self::Chi2Rank(Chi2RankParams::default())
    }
}

impl DofConfig {
    /// Builds the stage.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn build(&self) -> Result<Box<dyn DofTester>> {
        Ok(match self {
            Self::SvdRank(p) => Box::new(SvdRank::new(*p)?),
            Self::Chi2Rank(p) => Box::new(Chi2Rank::new(*p)?),
        })
    }
}

/// How the noise level is estimated from the data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum NoiseEstimator {
    /// The mode of the pairs' distance variances, refined inside the bodies found
    /// ([`kinetree_dissimilarity::estimate_noise_sigma`]): within a few % on rigid bodies.
    #[default]
    Mode,
    /// Each point's second most rigid pair
    /// ([`kinetree_dissimilarity::estimate_noise_sigma_nearest_rigid`]): for markers on skin,
    /// rigid to 1-5 mm; not refined.
    NearestRigid,
}

/// The default of the `halves` slot: average-linkage hierarchical clustering cut into two
/// clusters.
fn default_halves() -> ClusteringConfig {
    ClusteringConfig::Hierarchical(HierarchicalParams {
        n_clusters: Some(2),
        ..HierarchicalParams::default()
    })
}

/// Refuses the key `hinged_bodies`, naming the keys that replaced it.
fn replaced_hinged_bodies<'de, D: serde::Deserializer<'de>>(
    _: D,
) -> std::result::Result<(), D::Error> {
    Err(serde::de::Error::custom(
        "`pipeline.hinged_bodies` was replaced by `pipeline.repairs.hinges.enabled` and \
         `pipeline.repairs.hinge_groups.enabled`",
    ))
}

/// The whole pipeline's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineConfig {
    /// Per-coordinate noise std-dev in metres; estimated from the data when absent.
    pub noise_sigma_m: Option<f64>,
    /// How the noise level is estimated when `noise_sigma_m` is absent.
    pub noise_estimator: NoiseEstimator,
    /// Seed for any random choice of any stage.
    pub seed: u64,
    /// Dissimilarity measure.
    pub dissimilarity: DissimilarityConfig,
    /// Clustering method.
    pub clustering: ClusteringConfig,
    /// The clusterer that cuts a group of points in two, for the repairs `split`, `regroup`
    /// and `hinge_groups` (run on the group's own sub-matrix with seed 0). It must return two
    /// clusters: `n_clusters = 2`. Default: average-linkage hierarchical.
    pub halves: ClusteringConfig,
    /// Pose estimator.
    pub pose: PoseConfig,
    /// DoF tester.
    pub dof: DofConfig,
    /// The repairs (`[pipeline.repairs.<name>]`), each with `enabled` and its thresholds.
    pub repairs: RepairsConfig,
    /// The runner's limits.
    pub runner: RunnerParams,
    /// When the whole-tree fit reports a joint position unknown, and when it smooths one
    /// (`[pipeline.positions]`; the model carries them for later observations).
    pub positions: PositionLimits,
    /// How the spanning tree weighs pairs beyond their DoF test (the bodies' distance, the
    /// exact ties' fit margin) and when it hangs a subject moving past the static body by
    /// the subject's own root (`[pipeline.tree]`).
    pub tree: kinetree_core::TreeCosts,
    /// Which samples are impossible and dropped before anything else (`[pipeline.outliers]`).
    pub outliers: crate::outliers::OutlierParams,
    /// Which points repeat another's track and are left out next (`[pipeline.duplicates]`).
    pub duplicates: crate::duplicates::DuplicateParams,
    /// When a discovery runs on a sample of the points and assigns the others to its bodies
    /// afterwards (`[pipeline.sampling]`: tracks with more than 500 points).
    pub sampling: crate::sampling::SamplingParams,
    /// When a multi-DoF or universal joint becomes two hinges through a link too little seen
    /// to pose, put into the tree as a body (`[pipeline.unseen_links]`).
    pub unseen_links: crate::unseen::UnseenLinksParams,
    /// Memory a run may use, GiB (default
    /// [`kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB`]): a discovery or a simulation whose
    /// estimate exceeds it is refused before it allocates.
    pub max_memory_gib: f64,
    /// Estimated minutes of work a run may take (default
    /// [`kinetree_core::limits::DEFAULT_MAX_MINUTES`]): a discovery whose pair statistics, or
    /// whose bodies and model phases once the clustering has found its bodies, are estimated
    /// to take longer is refused before they start.
    pub max_minutes: f64,
    /// Replaced by `repairs.hinges.enabled` and `repairs.hinge_groups.enabled`: setting it
    /// is an error that names them.
    #[serde(default, skip_serializing, deserialize_with = "replaced_hinged_bodies")]
    pub hinged_bodies: (),
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            noise_sigma_m: None,
            noise_estimator: NoiseEstimator::default(),
            seed: 0,
            dissimilarity: DissimilarityConfig::default(),
            clustering: ClusteringConfig::default(),
            halves: default_halves(),
            pose: PoseConfig::default(),
            dof: DofConfig::default(),
            repairs: RepairsConfig::default(),
            runner: RunnerParams::default(),
            positions: PositionLimits::default(),
            tree: kinetree_core::TreeCosts::default(),
            outliers: crate::outliers::OutlierParams::default(),
            duplicates: crate::duplicates::DuplicateParams::default(),
            sampling: crate::sampling::SamplingParams::default(),
            unseen_links: crate::unseen::UnseenLinksParams::default(),
            max_memory_gib: kinetree_core::limits::DEFAULT_MAX_MEMORY_GIB,
            max_minutes: kinetree_core::limits::DEFAULT_MAX_MINUTES,
            hinged_bodies: (),
        }
    }
}

/// The pipeline for motion-capture markers on skin (the `[pipeline]` table's contents):
/// the noise level from each marker's most rigid partners, the distance std-dev cut at three
/// noise std-devs as dissimilarity, 3 mm / 0.02 rad of joint model error in the DoF test, no
/// hidden hinges (skin moving over a segment turns its markers with the neighbour's motion;
/// `docs/decisions.md`, `dof.hidden_hinge_ratio`) and no unseen links (every segment of a
/// person carries markers, and skin moving over a hip can let a ball joint pass for two
/// hinges far apart; `docs/decisions.md`, `[pipeline.unseen_links]`), and no bound on the
/// re-prediction of a model `retest` rebuilds (multi-DoF joints absorb the skin's motion, so
/// a worse tree re-predicts the markers better; `docs/decisions.md`,
/// `retest.max_rms_growth`), and ball and multi-DoF pairs ranked for the tree by how well a
/// ball joint fits them and how near its centre lies to both bodies rather than by their DoF
/// (`[pipeline.tree] ball_fit_from_dof`), and a lone marker that borrows the markers rigid
/// with it from the segment below (`[pipeline.repairs.ball_groups] borrow`: sparse marker
/// sets leave a thigh one marker and put its knee marker on the shank), counting a marker as
/// explained by a body, and so not grouped, only within 2 std-devs and a slack of 1 (soft
/// tissue leaves a three-marker body's poses loose enough to explain a foot's marker), in
/// `balls` as in `ball_groups` (`balls` poses the bodies `ball_groups` makes, on a parent
/// that explains none of their markers; judged more loosely, the parent `ball_groups` chose
/// is refused and the body is dropped unposed), and markers shared by two segments judged
/// rigid up to the segments' own looseness, at most the DoF test's 3 mm
/// (`[pipeline.repairs.share_points] model_error_m`: skin markers on a joint's axis are no
/// more rigid with the next segment than a segment's markers are with each other).
/// `experiments/real/README.md` gives the measurements behind each setting.
pub const MOTION_CAPTURE_TOML: &str = r#"noise_estimator = "nearest_rigid"

[dissimilarity]
kind = "distance_std"
cut_in_noise_std = 3.0

[dof]
kind = "chi2_rank"
model_error_m = 0.003
model_error_rad = 0.02
hidden_hinge_ratio = 0.0

[unseen_links]
enabled = false

[repairs.retest]
max_rms_growth = 1e6

[repairs.ball_groups]
borrow = true
explained_bound_in_std = 2.0
explained_slack = 1.0

[repairs.balls]
explained_bound_in_std = 2.0
explained_slack = 1.0

[repairs.share_points]
model_error_m = 0.003

[tree]
ball_fit_from_dof = 3
"#;

impl PipelineConfig {
    /// The pipeline for motion-capture markers on skin ([`MOTION_CAPTURE_TOML`]), which
    /// `kinetree discover` takes for C3D and TRC files unless told otherwise.
    pub fn motion_capture() -> Self {
        pipeline_from_toml(MOTION_CAPTURE_TOML).expect("the motion-capture preset parses")
    }

    /// Checks what the stages' and repairs' constructors do not: the noise level, the
    /// `halves` slot's cluster count, the repairs', runner's, tree's and positions' ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the key.
    pub fn validate(&self) -> Result<()> {
        if let Some(s) = self.noise_sigma_m
            && !(s.is_finite() && s > 0.0)
        {
            return Err(Error::InvalidParameter {
                name: "pipeline.noise_sigma_m".into(),
                message: format!("must be finite and positive, got {s}"),
            });
        }
        let halves = match &self.halves {
            ClusteringConfig::Hierarchical(p) => p.n_clusters,
            ClusteringConfig::Dbscan(p) => p.n_clusters,
            ClusteringConfig::Spectral(p) => p.n_clusters,
            #[cfg(feature = "linfa")]
            ClusteringConfig::SpectralGmm(p) => p.embedding.n_clusters,
            #[cfg(feature = "linfa")]
            ClusteringConfig::SpectralDbscan(_) => {
                return Err(Error::InvalidParameter {
                    name: "pipeline.halves.kind".into(),
                    message: "spectral_dbscan finds its own number of clusters; the slot needs \
                              one that cuts a group in two (n_clusters = 2)"
                        .into(),
                });
            }
        };
        if halves != Some(2) {
            return Err(Error::InvalidParameter {
                name: "pipeline.halves.n_clusters".into(),
                message: format!("must be 2 (the slot cuts groups in two), got {halves:?}"),
            });
        }
        self.repairs.validate()?;
        self.runner.validate()?;
        kinetree_core::limits::validate_limit("pipeline.max_memory_gib", self.max_memory_gib)?;
        kinetree_core::limits::validate_minutes("pipeline.max_minutes", self.max_minutes)?;
        self.outliers.validate()?;
        self.duplicates.validate()?;
        self.sampling.validate()?;
        self.unseen_links.validate()?;
        self.tree.validate("pipeline.tree")?;
        self.positions.validate("pipeline.positions")
    }

    /// The config with the hinge repairs (`hinges` and `hinge_groups`) on or off.
    pub fn with_hinges(mut self, on: bool) -> Self {
        self.repairs.hinges.enabled = on;
        self.repairs.hinge_groups.enabled = on;
        self
    }

    /// The config with the ball-joint repairs (`balls` and `ball_groups`) on or off.
    pub fn with_balls(mut self, on: bool) -> Self {
        self.repairs.balls.enabled = on;
        self.repairs.ball_groups.enabled = on;
        self
    }
}

/// Where an experiment's data come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DataConfig {
    /// The paper's 2-DoF arm ([`kinetree_synth::paper_arm`]).
    PaperArm(PaperArmData),
    /// A random mechanism ([`kinetree_synth::random_scenario`]).
    Random(RandomParams),
    /// A human-like skeleton of ball joints and hinges ([`kinetree_synth::skeleton_scenario`]).
    Skeleton(kinetree_synth::SkeletonParams),
    /// An arm with a parallel or angular gripper ([`kinetree_synth::gripper_scenario`]).
    Gripper(kinetree_synth::GripperParams),
    /// A human-like hand of 16 links ([`kinetree_synth::hand_scenario`]).
    Hand(kinetree_synth::HandParams),
    /// An arm with one link mostly hidden ([`kinetree_synth::hidden_link_arm`]).
    HiddenLink(kinetree_synth::HiddenLinkParams),
    /// An arm of slender rods ([`kinetree_synth::slender_arm`]).
    SlenderArm(kinetree_synth::SlenderArmParams),
    /// The scale scenario that speed is measured on, with any number of keypoints and
    /// frames ([`kinetree_synth::scale_scenario`]).
    Scale(kinetree_synth::ScaleParams),
    /// A tracks file (`.npy`, `.npz`, `.csv`, `.c3d` or `.trc`), relative to the config file.
    File(FileData),
}

/// Whether `path` is a motion-capture file (`.c3d` or `.trc`, any case), for which
/// `kinetree discover` and experiments without a `[pipeline]` take the motion-capture
/// settings.
pub fn is_motion_capture_file(path: &std::path::Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("c3d") || e.eq_ignore_ascii_case("trc"))
}

impl DataConfig {
    /// Whether the data are a motion-capture file ([`is_motion_capture_file`]).
    pub fn is_motion_capture_file(&self) -> bool {
        matches!(self, Self::File(f) if is_motion_capture_file(&f.path))
    }
}

/// A simulation named as `kinetree simulate` and the Python package's `simulate` take it: a
/// mechanism by name and the options of both kinds.
#[derive(Debug, Clone, PartialEq)]
pub struct SimulationRequest {
    /// `paper-arm`, `random`, `skeleton`, `skeleton-universal` (its wrists and ankles
    /// universal joints), `skeleton-floating` (its pelvis moving freely, nothing static),
    /// `skeleton-clinical` (the floating skeleton with a clinical marker set: two markers a
    /// limb segment, four on the pelvis, torso and head, two on each elbow, knee, wrist and
    /// ankle axis),
    /// `gripper-parallel` or `gripper-angular` (an arm whose two fingers slide along, or turn
    /// about, one axis), `hand` (a palm with four fingers and a thumb), `hand-knuckles` (the
    /// same with a knuckle body between two hinges at each finger's base), `hidden-link` (an
    /// arm whose wrist link is seen in part of the frames), `slender-planar` or `slender`
    /// (an arm of rods a few millimetres thick turning about parallel, or random, axes), or
    /// `scale` (a base and four links R-R-P-R with any number of keypoints inside them, the
    /// scenario speed is measured on).
    pub mechanism: String,
    /// Seed of every random choice.
    pub seed: u64,
    /// Number of joints (random mechanisms and slender arms).
    pub joints: usize,
    /// Bodies attached as a tree rather than a chain (random mechanisms).
    pub tree: bool,
    /// Probability that a joint is prismatic (random mechanisms).
    pub prismatic_fraction: f64,
    /// Probability that a joint that is not prismatic is a ball joint (random mechanisms).
    pub spherical_fraction: f64,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Extra random occlusion fraction.
    pub dropout: f64,
    /// Number of frames; `None` for the mechanism's default (100 for the paper arm, 200 for
    /// random mechanisms).
    pub n_frames: Option<usize>,
    /// Number of keypoints of the scale scenario; `None` for its default (1000).
    pub n_points: Option<usize>,
    /// Skin markers' soft-tissue drift, metres (skeletons; `None` for none):
    /// [`kinetree_synth::SkeletonParams::soft_tissue_m`].
    pub soft_tissue_m: Option<f64>,
}

/// Frames of a random mechanism's simulation when none are asked for.
pub const DEFAULT_RANDOM_FRAMES: usize = 200;

impl SimulationRequest {
    /// The experiment data of the request.
    ///
    /// # Errors
    /// [`Error::Config`] for an unknown mechanism; [`Error::InvalidParameter`] naming
    /// `data.n_points` when a mechanism other than `scale` is given a number of keypoints,
    /// or `data.soft_tissue_m` when a mechanism other than a skeleton is given soft tissue.
    pub fn data(&self) -> Result<DataConfig> {
        if self.soft_tissue_m.is_some() && !self.mechanism.starts_with("skeleton") {
            return Err(Error::InvalidParameter {
                name: "data.soft_tissue_m".into(),
                message: format!(
                    "only the skeletons carry soft tissue, not `{}`",
                    self.mechanism
                ),
            });
        }
        if self.n_points.is_some() && self.mechanism != "scale" {
            return Err(Error::InvalidParameter {
                name: "data.n_points".into(),
                message: format!(
                    "only the scale mechanism takes a number of keypoints, not `{}`",
                    self.mechanism
                ),
            });
        }
        Ok(match self.mechanism.as_str() {
            "paper-arm" => DataConfig::PaperArm(PaperArmData {
                seed: self.seed,
                noise_sigma_m: self.noise_sigma_m,
                dropout: self.dropout,
                n_frames: self.n_frames.unwrap_or(PaperArmData::default().n_frames),
            }),
            "random" => DataConfig::Random(RandomParams {
                n_joints: self.joints,
                prismatic_fraction: self.prismatic_fraction,
                spherical_fraction: self.spherical_fraction,
                tree: self.tree,
                n_frames: self.n_frames.unwrap_or(DEFAULT_RANDOM_FRAMES),
                noise_sigma_m: self.noise_sigma_m,
                dropout: self.dropout,
                seed: self.seed,
                ..RandomParams::default()
            }),
            "skeleton" | "skeleton-universal" | "skeleton-floating" | "skeleton-clinical" => {
                DataConfig::Skeleton(kinetree_synth::SkeletonParams {
                    n_frames: self
                        .n_frames
                        .unwrap_or(kinetree_synth::SkeletonParams::default().n_frames),
                    noise_sigma_m: self.noise_sigma_m,
                    dropout: self.dropout,
                    seed: self.seed,
                    universal_wrists_and_ankles: self.mechanism == "skeleton-universal",
                    floating_pelvis: matches!(
                        self.mechanism.as_str(),
                        "skeleton-floating" | "skeleton-clinical"
                    ),
                    clinical_markers: self.mechanism == "skeleton-clinical",
                    soft_tissue_m: self.soft_tissue_m.unwrap_or(0.0),
                    ..kinetree_synth::SkeletonParams::default()
                })
            }
            "gripper-parallel" | "gripper-angular" => {
                DataConfig::Gripper(kinetree_synth::GripperParams {
                    gripper: if self.mechanism == "gripper-parallel" {
                        kinetree_synth::GripperKind::Parallel
                    } else {
                        kinetree_synth::GripperKind::Angular
                    },
                    n_frames: self
                        .n_frames
                        .unwrap_or(kinetree_synth::GripperParams::default().n_frames),
                    noise_sigma_m: self.noise_sigma_m,
                    dropout: self.dropout,
                    seed: self.seed,
                    ..kinetree_synth::GripperParams::default()
                })
            }
            "hand" | "hand-knuckles" => DataConfig::Hand(kinetree_synth::HandParams {
                knuckle_bodies: self.mechanism == "hand-knuckles",
                n_frames: self
                    .n_frames
                    .unwrap_or(kinetree_synth::HandParams::default().n_frames),
                noise_sigma_m: self.noise_sigma_m,
                dropout: self.dropout,
                seed: self.seed,
                ..kinetree_synth::HandParams::default()
            }),
            "hidden-link" => DataConfig::HiddenLink(kinetree_synth::HiddenLinkParams {
                n_frames: self
                    .n_frames
                    .unwrap_or(kinetree_synth::HiddenLinkParams::default().n_frames),
                noise_sigma_m: self.noise_sigma_m,
                dropout: self.dropout,
                seed: self.seed,
                ..kinetree_synth::HiddenLinkParams::default()
            }),
            "slender-planar" | "slender" => {
                DataConfig::SlenderArm(kinetree_synth::SlenderArmParams {
                    n_joints: self.joints,
                    planar: self.mechanism == "slender-planar",
                    n_frames: self
                        .n_frames
                        .unwrap_or(kinetree_synth::SlenderArmParams::default().n_frames),
                    noise_sigma_m: self.noise_sigma_m,
                    dropout: self.dropout,
                    seed: self.seed,
                    ..kinetree_synth::SlenderArmParams::default()
                })
            }
            "scale" => DataConfig::Scale(kinetree_synth::ScaleParams {
                n_points: self
                    .n_points
                    .unwrap_or(kinetree_synth::ScaleParams::default().n_points),
                n_frames: self
                    .n_frames
                    .unwrap_or(kinetree_synth::ScaleParams::default().n_frames),
                noise_sigma_m: self.noise_sigma_m,
                dropout: self.dropout,
                seed: self.seed,
            }),
            other => {
                return Err(Error::Config(format!(
                    "unknown mechanism `{other}`; use paper-arm, random, skeleton, \
                     skeleton-universal, skeleton-floating, skeleton-clinical, gripper-parallel, gripper-angular, \
                     hand, hand-knuckles, hidden-link, slender-planar, slender or scale"
                )));
            }
        })
    }
}

/// Parameters of the paper-arm data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PaperArmData {
    /// Seed of the noise.
    pub seed: u64,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Extra random occlusion.
    pub dropout: f64,
    /// Number of frames.
    pub n_frames: usize,
}

impl Default for PaperArmData {
    fn default() -> Self {
        Self {
            seed: 0,
            noise_sigma_m: 0.001,
            dropout: 0.0,
            n_frames: 100,
        }
    }
}

/// A tracks file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileData {
    /// Path of the `.npy`, `.npz`, `.csv` or `.c3d` file.
    pub path: PathBuf,
    /// `.npz`: the tracks array's name (default `tracks`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tracks_key: Option<String>,
    /// `.npz`: the name of a `(T, N)` array true where a sample is visible (default
    /// `visibility` when the archive has one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub visibility_key: Option<String>,
    /// `.npz`: the name of a `(T, N)` array true where a sample is occluded (default
    /// `occluded` when the archive has one and no visibility array).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub occluded_key: Option<String>,
}

/// Experiment metadata.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentMeta {
    /// Name; results go to `results/<name>/`.
    pub name: String,
    /// One-line description.
    #[serde(default)]
    pub description: String,
}

impl ExperimentMeta {
    /// Checks that `name` is one plain folder name, so the results stay under `--results`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming `experiment.name` when it is empty, `.` or `..`,
    /// or holds a path separator or a control character.
    pub fn validate(&self) -> Result<()> {
        let n = &self.name;
        let bad = n.is_empty()
            || n == "."
            || n == ".."
            || n.chars().any(|c| c == '/' || c == '\\' || c.is_control());
        if bad {
            return Err(Error::InvalidParameter {
                name: "experiment.name".into(),
                message: format!(
                    "{n:?} must be one folder name (no `/`, `\\`, `..` or control characters): \
                     results go to <results>/<name>/"
                ),
            });
        }
        Ok(())
    }
}

/// An experiment config file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentConfig {
    /// Metadata.
    pub experiment: ExperimentMeta,
    /// Data source.
    pub data: DataConfig,
    /// Pipeline. Absent: the defaults, or the motion-capture settings
    /// ([`PipelineConfig::motion_capture`]) for a C3D or TRC file, as `kinetree discover`
    /// takes them.
    #[serde(default)]
    pub pipeline: PipelineConfig,
}

impl ExperimentConfig {
    /// Parses a TOML config; unknown keys are errors. Without a `[pipeline]` table, a C3D or
    /// TRC file's experiment takes the motion-capture settings.
    ///
    /// # Errors
    /// [`Error::Config`] with the parser's message (line and key).
    pub fn from_toml(text: &str) -> Result<Self> {
        let mut cfg: Self = parse_naming_key(text, "")?;
        cfg.experiment.validate()?;
        let has_pipeline = text
            .parse::<toml::Table>()
            .is_ok_and(|t| t.contains_key("pipeline"));
        if !has_pipeline && cfg.data.is_motion_capture_file() {
            cfg.pipeline = PipelineConfig::motion_capture();
        }
        Ok(cfg)
    }

    /// The config with every default filled in, as TOML.
    ///
    /// # Errors
    /// [`Error::Config`] if serialisation fails.
    pub fn resolved_toml(&self) -> Result<String> {
        toml::to_string(self).map_err(|e| Error::Config(e.to_string()))
    }
}

/// The paper experiment's config, compiled in: what `kinetree run` uses with no argument.
pub const PAPER_EXPERIMENT_TOML: &str =
    include_str!("../../../experiments/paper-table1/table1.toml");

/// Parses a pipeline config from TOML: the contents of an experiment's `[pipeline]` table, or
/// text with the `[pipeline]` table itself (as the README shows it, or a whole experiment
/// config, whose `[experiment]` and `[data]` are then ignored).
///
/// # Errors
/// [`Error::Config`] with the parser's message; unknown keys are errors.
pub fn pipeline_from_toml(text: &str) -> Result<PipelineConfig> {
    if let Ok(table) = text.parse::<toml::Table>()
        && let Some(toml::Value::Table(inner)) = table.get("pipeline")
        && table
            .keys()
            .all(|k| matches!(k.as_str(), "pipeline" | "experiment" | "data"))
    {
        let inner = toml::to_string(inner).map_err(|e| Error::Config(e.to_string()))?;
        return parse_naming_key(&inner, "pipeline.");
    }
    parse_naming_key(text, "pipeline.")
}

/// Parses TOML into `T`; an error names the dotted key it is about (found by
/// `serde_path_to_error`, prefixed with `prefix`) before the parser's message (line and key).
fn parse_naming_key<T: serde::de::DeserializeOwned>(text: &str, prefix: &str) -> Result<T> {
    toml::from_str(text).map_err(|e| {
        let path = toml::from_str::<toml::Value>(text)
            .ok()
            .and_then(|v| serde_path_to_error::deserialize::<_, T>(v).err())
            .map(|pe| pe.path().to_string())
            .filter(|p| p != ".");
        match path {
            Some(p) => Error::Config(format!("in `{prefix}{p}`: {e}")),
            None => Error::Config(e.to_string()),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_motion_capture_file_without_a_pipeline_takes_the_motion_capture_settings() {
        let exp = |path: &str, pipeline: &str| {
            ExperimentConfig::from_toml(&format!(
                "[experiment]\nname = \"x\"\n[data]\nkind = \"file\"\npath = \"{path}\"\n{pipeline}"
            ))
            .expect("config")
            .pipeline
        };
        let mocap = PipelineConfig::motion_capture();
        assert_eq!(exp("walk.c3d", ""), mocap);
        assert_eq!(exp("walk.TRC", ""), mocap);
        assert_eq!(exp("walk.npy", ""), PipelineConfig::default());
        // An explicit table, even an empty one, is taken as written.
        assert_eq!(exp("walk.c3d", "[pipeline]\n"), PipelineConfig::default());
    }
}
