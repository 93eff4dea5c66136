//! Running the pipeline on tracks: the stages, built from config or supplied, and the runner
//! that applies the repairs ([`crate::runner`]).

use crate::config::{NoiseEstimator, PipelineConfig};
use crate::runner::{DiscoveryObserver, Runner, RunnerParams};
use kinetree_core::model::NoiseSource;
use kinetree_core::{
    BodyPoses, Clustering, Dissimilarity, DissimilarityMatrix, DofTester, Error, Model, PairStats,
    PoseEstimator, Repair, Result, Segmentation, TraceEntry, Tracks, Warning,
};
use kinetree_dissimilarity::{
    estimate_noise_sigma, estimate_noise_sigma_nearest_rigid, pair_stats,
};

/// The stages and repairs, built from a [`PipelineConfig`] or supplied by the caller.
#[derive(Debug)]
pub struct Pipeline {
    /// Dissimilarity measure.
    pub dissimilarity: Box<dyn Dissimilarity>,
    /// Clustering method.
    pub clustering: Box<dyn Clustering>,
    /// The clusterer that cuts a group of points in two, for the repairs that split bodies
    /// or groups ([`PipelineConfig::halves`]).
    pub halves: Box<dyn Clustering>,
    /// Pose estimator.
    pub pose: Box<dyn PoseEstimator>,
    /// DoF tester.
    pub dof: Box<dyn DofTester>,
    /// The repairs, in the order the runner asks them within each phase.
    pub repairs: Vec<Box<dyn Repair>>,
    /// The runner's limits.
    pub runner: RunnerParams,
    /// When a joint position is reported unknown, and when positions are smoothed; written
    /// into the model.
    pub positions: kinetree_core::model::PositionLimits,
    /// The spanning tree's preferences ([`PipelineConfig::tree`]).
    pub tree: kinetree_core::TreeCosts,
    /// Per-coordinate noise, metres; estimated when `None`.
    pub noise_sigma_m: Option<f64>,
    /// How the noise is estimated when `noise_sigma_m` is `None`.
    pub noise_estimator: NoiseEstimator,
    /// Seed for the stages.
    pub seed: u64,
    /// Memory a run may use, GiB ([`PipelineConfig::max_memory_gib`]).
    pub max_memory_gib: f64,
    /// Estimated minutes of work a run may take ([`PipelineConfig::max_minutes`]).
    pub max_minutes: f64,
    /// Which samples are impossible ([`PipelineConfig::outliers`]).
    pub outliers: crate::outliers::OutlierParams,
    /// Which points repeat another's track ([`PipelineConfig::duplicates`]).
    pub duplicates: crate::duplicates::DuplicateParams,
    /// When the discovery runs on a sample of the points ([`PipelineConfig::sampling`]).
    pub sampling: crate::sampling::SamplingParams,
    /// When a link too little seen to pose is put into the tree
    /// ([`PipelineConfig::unseen_links`]).
    pub unseen_links: crate::unseen::UnseenLinksParams,
}

/// Everything a run produces: the model and the intermediate results behind it.
#[derive(Debug, Clone)]
pub struct Discovery {
    /// The model (bodies renumbered in tree order), with the repairs' trace.
    pub model: Model,
    /// Pair statistics.
    pub stats: PairStats,
    /// The dissimilarity matrix used for the final segmentation.
    pub dissimilarity: DissimilarityMatrix,
    /// Final segmentation, in the model's body numbering (body `k` is the model's body `k`;
    /// bodies the model puts in for links too little seen to pose, `unseen_link`, come after
    /// the segmentation's, and the keypoints given to them are on their neighbours or on
    /// none here).
    pub segmentation: Segmentation,
    /// Poses per body of the segmentation, in the model's body numbering.
    pub poses: BodyPoses,
    /// The points the pair statistics and the dissimilarity are over, ascending, when the
    /// tracks had more than `[pipeline.sampling] max_points` (their entry `k` is this
    /// list's point `k`); `None` when they are over every point.
    pub sampled: Option<Vec<usize>>,
}

/// Stage 1's results ([`Pipeline::group`]): what [`Pipeline::run`] builds the bodies from.
#[derive(Debug, Clone)]
pub struct Grouping {
    /// Pair statistics.
    pub stats: PairStats,
    /// Per-coordinate noise, metres (given, or estimated and refined).
    pub noise_sigma_m: f64,
    /// Whether the noise level was given or estimated.
    pub noise_source: NoiseSource,
    /// The noise estimator's first estimate, when it may be refined.
    pub first_noise_estimate_m: Option<f64>,
    /// The dissimilarity matrix at that noise level.
    pub dissimilarity: DissimilarityMatrix,
    /// The clustering's bodies (before any pose, split or point move).
    pub segmentation: Segmentation,
    /// Warnings so far: points never visible or never paired, inferred pairs, the noise
    /// estimate, discarded clusters.
    pub warnings: Vec<Warning>,
    /// The grouping repairs' changes.
    pub trace: Vec<TraceEntry>,
}

impl Pipeline {
    /// Builds every stage and repair from a config.
    ///
    /// # Errors
    /// When a stage's or repair's parameters are invalid or the noise level is not positive.
    pub fn from_config(c: &PipelineConfig) -> Result<Self> {
        c.validate()?;
        // A stage names its own parameter (`cut`); the error names its section too.
        let within = |section: &'static str| {
            move |e: Error| match e {
                Error::InvalidParameter { name, message } if !name.starts_with("pipeline.") => {
                    Error::InvalidParameter {
                        name: format!("pipeline.{section}.{name}"),
                        message,
                    }
                }
                other => other,
            }
        };
        Ok(Self {
            dissimilarity: c.dissimilarity.build().map_err(within("dissimilarity"))?,
            clustering: c.clustering.build().map_err(within("clustering"))?,
            halves: c.halves.build().map_err(within("halves"))?,
            pose: c.pose.build().map_err(within("pose"))?,
            dof: c.dof.build().map_err(within("dof"))?,
            repairs: c.repairs.build()?,
            runner: c.runner,
            positions: c.positions,
            tree: c.tree,
            noise_sigma_m: c.noise_sigma_m,
            noise_estimator: c.noise_estimator,
            seed: c.seed,
            max_memory_gib: c.max_memory_gib,
            max_minutes: c.max_minutes,
            outliers: c.outliers,
            duplicates: c.duplicates,
            sampling: c.sampling,
            unseen_links: c.unseen_links,
        })
    }

    /// Stage 1 alone: the pair statistics, the noise level (given, or estimated and then
    /// refined by the grouping repairs), the dissimilarity matrix and the clustering.
    /// [`Pipeline::run`] starts from exactly this; a caller who only needs the bodies or the
    /// noise level is spared the poses, tests and whole-tree fits.
    ///
    /// # Errors
    /// As [`Pipeline::run`]'s first stage: bad tracks, a failing stage, no noise estimate.
    pub fn group(&self, tracks: &Tracks) -> Result<Grouping> {
        let (cleaned, warnings) = self.without_impossible_samples(tracks)?;
        self.group_clean(cleaned.as_ref().unwrap_or(tracks), warnings, &())
    }

    /// The tracks without their impossible samples ([`PipelineConfig::outliers`]) and
    /// duplicate points ([`PipelineConfig::duplicates`]; `None` when nothing was dropped),
    /// and the warnings: the reader's, then those saying so.
    fn without_impossible_samples(
        &self,
        tracks: &Tracks,
    ) -> Result<(Option<Tracks>, Vec<Warning>)> {
        // The reader's warnings come first.
        let mut warnings = tracks.warnings().to_vec();
        let mut cleaned = match self.outliers.clean(tracks)? {
            Some((cleaned, warning)) => {
                warnings.push(warning);
                Some(cleaned)
            }
            None => None,
        };
        if let Some((deduplicated, warning)) =
            self.duplicates.clean(cleaned.as_ref().unwrap_or(tracks))?
        {
            warnings.push(warning);
            cleaned = Some(deduplicated);
        }
        Ok((cleaned, warnings))
    }

    fn group_clean(
        &self,
        tracks: &Tracks,
        mut warnings: Vec<Warning>,
        observer: &dyn DiscoveryObserver,
    ) -> Result<Grouping> {
        let n = tracks.n_points();
        kinetree_core::limits::check_memory(
            &format!("discovering {} frames x {n} points", tracks.n_frames()),
            kinetree_core::limits::discovery_bytes(tracks.n_frames() as u64, n as u64),
            self.max_memory_gib,
        )?;
        kinetree_core::limits::check_work(
            &format!(
                "pair statistics of {} frames x {n} points",
                tracks.n_frames()
            ),
            kinetree_core::limits::pairs_seconds(tracks.n_frames() as u64, n as u64),
            self.max_minutes,
            "",
        )?;
        let visible: Vec<usize> = tracks.visible_counts();
        let duplicated = duplicated_points(&warnings);
        for (i, &v) in visible.iter().enumerate() {
            if v == 0 && !duplicated.contains(&i) {
                warnings.push(Warning::PointNeverVisible { point: i });
            }
        }
        observer.stage("pair statistics");
        let stats = pair_stats(tracks);
        let mut paired = vec![false; n];
        for i in 0..n {
            for j in i + 1..n {
                if stats.count(i, j) >= 2 {
                    paired[i] = true;
                    paired[j] = true;
                }
            }
        }
        for (i, &p) in paired.iter().enumerate() {
            if !p && visible[i] > 0 {
                warnings.push(Warning::PointUnpaired { point: i });
            }
        }
        let unknown_among_paired = (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .filter(|&(i, j)| paired[i] && paired[j] && stats.count(i, j) < 2)
            .count();
        if unknown_among_paired > 0 {
            warnings.push(Warning::PairsInferred {
                count: unknown_among_paired,
            });
        }
        observer.stage("noise level");
        let (mut sigma, noise_source) = match (self.noise_sigma_m, self.noise_estimator) {
            (Some(s), _) => (s, NoiseSource::Given),
            (None, NoiseEstimator::Mode) => (estimate_noise_sigma(&stats)?, NoiseSource::Estimated),
            (None, NoiseEstimator::NearestRigid) => (
                estimate_noise_sigma_nearest_rigid(&stats)?,
                NoiseSource::Estimated,
            ),
        };
        // An estimate cannot go below the rounding of the coordinates to the file's grid
        // (a uniform error of a step's width: std-dev step / sqrt 12).
        let rounding = tracks
            .precision_m()
            .filter(|_| noise_source == NoiseSource::Estimated)
            .map(|step| (step, step / 12f64.sqrt()));
        if let Some((step, floor)) = rounding
            && sigma < floor
        {
            sigma = floor;
            warnings.push(Warning::NoiseAtPrecision {
                sigma_m: floor,
                precision_m: step,
            });
        }
        let first_guess = (noise_source == NoiseSource::Estimated
            && self.noise_estimator == NoiseEstimator::Mode)
            .then_some(sigma);
        observer.stage("clustering");
        let (s, dmat, seg, trace) =
            crate::runner::grouping(self, tracks, &stats, sigma, first_guess, observer)?;
        sigma = rounding.map_or(s, |(_, floor)| s.max(floor));
        if noise_source == NoiseSource::Estimated {
            warnings.push(Warning::NoiseEstimated { sigma_m: sigma });
        }
        for g in &seg.discarded_groups {
            warnings.push(Warning::ClusterDiscarded { points: g.clone() });
        }
        Ok(Grouping {
            stats,
            noise_sigma_m: sigma,
            noise_source,
            first_noise_estimate_m: first_guess,
            dissimilarity: dmat,
            segmentation: seg,
            warnings,
            trace,
        })
    }

    /// Discovers the model of `tracks`: [`Pipeline::group`], then the runner's phases (the
    /// bodies' poses and repairs, the pair tests, the tree, the whole-tree fit, and passes
    /// of point repairs). The model's `trace` lists every change a repair made.
    ///
    /// # Errors
    /// [`Error::Degenerate`] when no body can be found or registered, and any stage's or
    /// repair's error.
    pub fn run(&self, tracks: &Tracks) -> Result<Discovery> {
        self.run_with_progress(tracks, &|_| {})
    }

    /// [`Pipeline::run`], calling `progress` with every trace entry as the runner makes it
    /// (the grouping's once the grouping is done). The entries are the model's `trace`, in
    /// the same order.
    ///
    /// # Errors
    /// As [`Pipeline::run`].
    pub fn run_with_progress(
        &self,
        tracks: &Tracks,
        progress: crate::runner::Progress<'_>,
    ) -> Result<Discovery> {
        self.run_observed(tracks, &crate::runner::TraceOnly(progress))
    }

    /// [`Pipeline::run`], telling `observer` each stage as it starts and every trace entry
    /// as it is made (the grouping's once the grouping is done): for a progress display.
    ///
    /// # Errors
    /// As [`Pipeline::run`].
    pub fn run_observed(
        &self,
        tracks: &Tracks,
        observer: &dyn DiscoveryObserver,
    ) -> Result<Discovery> {
        let (cleaned, warnings) = self.without_impossible_samples(tracks)?;
        let tracks = cleaned.as_ref().unwrap_or(tracks);
        let mut d = match crate::sampling::discover_sampled(self, tracks, &warnings, observer)? {
            Some(d) => d,
            None => self.discover_clean(tracks, warnings, observer)?,
        };
        if self.unseen_links.enabled {
            observer.stage("unseen links");
            crate::unseen::put_unseen_links(self, &mut d.model, tracks)?;
            d.model.validate()?;
        }
        Ok(d)
    }

    /// The discovery of `tracks`, their impossible samples dropped, on every point;
    /// `warnings` come first in the model's.
    pub(crate) fn discover_clean(
        &self,
        tracks: &Tracks,
        warnings: Vec<Warning>,
        observer: &dyn DiscoveryObserver,
    ) -> Result<Discovery> {
        let g = self.group_clean(tracks, warnings, observer)?;
        for e in &g.trace {
            observer.trace(e);
        }
        let runner = Runner::new(
            self,
            tracks,
            &g.stats,
            &g.dissimilarity,
            g.noise_sigma_m,
            g.noise_source,
            g.first_noise_estimate_m,
            g.trace,
            observer,
        );
        let (draft, trace) = runner.run(g.segmentation, g.warnings)?;
        let (Some(found), Some(poses)) = (draft.model, draft.poses) else {
            return Err(Error::Degenerate("the run ended without a model".into()));
        };
        let mut model = found.model;
        model.trace = trace;
        // The model must be one `kinetree_io::read_model` accepts back.
        model.validate()?;
        Ok(Discovery {
            model,
            stats: g.stats,
            dissimilarity: g.dissimilarity,
            segmentation: draft.segmentation,
            poses,
            sampled: None,
        })
    }
}

/// The points a [`Warning::PointsDuplicated`] among `warnings` left out: they are not
/// reported again as never visible.
pub(crate) fn duplicated_points(warnings: &[Warning]) -> Vec<usize> {
    warnings
        .iter()
        .flat_map(|w| match w {
            Warning::PointsDuplicated { points, .. } => points.as_slice(),
            _ => &[],
        })
        .copied()
        .collect()
}
