//! Clusterers on the spectral embedding from linfa-clustering: a Gaussian mixture with as many
//! components as the eigengap finds, and DBSCAN, which finds the number of bodies itself.
//! Both share the affinity, the eigenvectors and the row-normalised embedding of
//! [`crate::Spectral`].

use crate::spectral::{Embedding, EmbeddingParams, check_embedding, cluster_embedding};
use kinetree_core::{Clustering, ClusteringInput, Error, MIN_BODY_POINTS, Result, Segmentation};
use linfa::prelude::{Fit, Transformer};
use rand_xoshiro::rand_core::SeedableRng;
use serde::{Deserialize, Serialize};

/// Parameters of [`SpectralGmm`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SpectralGmmParams {
    /// The embedding (`[pipeline.clustering.embedding]`; as [`crate::SpectralParams`]):
    /// `n_clusters` sets the components instead of the eigengap.
    pub embedding: EmbeddingParams,
    /// Clusters with fewer points are discarded (at least 3, the minimum for a pose).
    pub min_points: usize,
    /// Added to the diagonal of every covariance (default 1e-6: the rows of one body nearly
    /// coincide, and their covariance alone would be singular).
    pub reg_covariance: f64,
    /// Most EM iterations (default 100); a mixture that has not converged by then is an
    /// error.
    pub max_iterations: usize,
    /// EM stops when the mean log-likelihood gains less than this (default 1e-3).
    pub tolerance: f64,
}

impl Default for SpectralGmmParams {
    fn default() -> Self {
        Self {
            embedding: EmbeddingParams::default(),
            min_points: MIN_BODY_POINTS,
            reg_covariance: 1e-6,
            max_iterations: 100,
            tolerance: 1e-3,
        }
    }
}

impl SpectralGmmParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        check_embedding(&self.embedding, self.min_points)?;
        let bad = |name: &str, v: f64| Error::InvalidParameter {
            name: name.into(),
            message: format!("must be finite and positive, got {v}"),
        };
        if !(self.reg_covariance.is_finite() && self.reg_covariance > 0.0) {
            return Err(bad("reg_covariance", self.reg_covariance));
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(bad("tolerance", self.tolerance));
        }
        kinetree_core::limits::check_count("max_iterations", self.max_iterations, 1, 1_000_000)
    }
}

/// A Gaussian mixture (linfa-clustering's `GaussianMixtureModel`, full covariances, k-means
/// start) on the spectral embedding, with as many components as the eigengap finds bodies
/// (or `n_clusters`); each point goes to its most responsible component. Seeded from the
/// input seed.
#[derive(Debug, Clone)]
pub struct SpectralGmm {
    params: SpectralGmmParams,
}

impl SpectralGmm {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SpectralGmmParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }

    /// The mixture's labels of the embedded rows (`None` for a row no component explains
    /// with a finite responsibility).
    fn labels(&self, e: &Embedding, seed: u64) -> Result<Vec<Option<usize>>> {
        let n = e.keep.len();
        let k = e.dim.min(n);
        if k <= 1 {
            return Ok(vec![Some(0); n]);
        }
        let data = linfa::DatasetBase::from(e.records()?);
        let gmm = linfa_clustering::GaussianMixtureModel::params(k)
            .with_rng(rand_xoshiro::Xoshiro256Plus::seed_from_u64(seed))
            .reg_covariance(self.params.reg_covariance)
            .tolerance(self.params.tolerance)
            .max_n_iterations(self.params.max_iterations as u64)
            .fit(&data)
            .map_err(|err| Error::Numerical(format!("spectral_gmm: the mixture failed: {err}")))?;
        // Responsibilities rather than `predict`, whose argmax panics on NaN.
        let resp = gmm.predict_proba(data.records());
        Ok(resp
            .rows()
            .into_iter()
            .map(|r| {
                r.iter()
                    .enumerate()
                    .filter(|(_, p)| p.is_finite())
                    .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
                    .map(|(c, _)| c)
            })
            .collect())
    }
}

impl Clustering for SpectralGmm {
    fn name(&self) -> &str {
        "spectral_gmm"
    }

    fn cluster(&self, input: &ClusteringInput<'_>) -> Result<Segmentation> {
        cluster_embedding(
            input.dissimilarity,
            &self.params.embedding,
            self.params.min_points,
            |e| self.labels(e, input.seed),
        )
    }
}

/// Parameters of [`SpectralDbscan`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SpectralDbscanParams {
    /// The embedding (`[pipeline.clustering.embedding]`; as [`crate::SpectralParams`]):
    /// `n_clusters` sets its dimension instead of the eigengap (DBSCAN still finds the number
    /// of bodies itself).
    pub embedding: EmbeddingParams,
    /// Clusters with fewer points are discarded (at least 3, the minimum for a pose).
    pub min_points: usize,
    /// Neighbourhood radius in the embedding, whose rows have unit length (default 0.3: the
    /// rows of one body nearly coincide, those of two bodies are nearly orthogonal, about
    /// 1.4 apart).
    pub eps: f64,
    /// Rows within `eps` (the row itself included) that make a core row (default 3, at least
    /// 2).
    pub core_points: usize,
}

impl Default for SpectralDbscanParams {
    fn default() -> Self {
        Self {
            embedding: EmbeddingParams::default(),
            min_points: MIN_BODY_POINTS,
            eps: 0.3,
            core_points: 3,
        }
    }
}

impl SpectralDbscanParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        check_embedding(&self.embedding, self.min_points)?;
        if !(self.eps.is_finite() && self.eps > 0.0 && self.eps <= 2.0) {
            return Err(Error::InvalidParameter {
                name: "eps".into(),
                message: format!(
                    "must be in (0, 2] (rows have unit length), got {}",
                    self.eps
                ),
            });
        }
        kinetree_core::limits::check_count("core_points", self.core_points, 2, 1_000_000)
    }
}

/// DBSCAN (linfa-clustering's `Dbscan`, a k-d tree, strict `distance < eps`) on the spectral
/// embedding's rows; the number of bodies is the number of dense groups DBSCAN finds, and its
/// noise rows stay unassigned. No random choice: the seed is not used.
#[derive(Debug, Clone)]
pub struct SpectralDbscan {
    params: SpectralDbscanParams,
}

impl SpectralDbscan {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SpectralDbscanParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Clustering for SpectralDbscan {
    fn name(&self) -> &str {
        "spectral_dbscan"
    }

    fn cluster(&self, input: &ClusteringInput<'_>) -> Result<Segmentation> {
        cluster_embedding(
            input.dissimilarity,
            &self.params.embedding,
            self.params.min_points,
            |e| {
                let labels = linfa_clustering::Dbscan::params(self.params.core_points)
                    .tolerance(self.params.eps)
                    .transform(&e.records()?)
                    .map_err(|err| Error::InvalidParameter {
                        name: "spectral_dbscan".into(),
                        message: err.to_string(),
                    })?;
                Ok(labels.to_vec())
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{blocks, same_partition};

    #[test]
    fn both_find_the_blocks_and_depend_only_on_the_seed() {
        let gmm = SpectralGmm::new(SpectralGmmParams::default()).expect("params");
        let dbscan = SpectralDbscan::new(SpectralDbscanParams::default()).expect("params");
        for sizes in [
            vec![3, 5, 8, 13, 21, 40],
            vec![3, 10, 30, 60, 80, 90, 100, 70, 57],
        ] {
            let (m, truth) = blocks(&sizes);
            for stage in [&gmm as &dyn Clustering, &dbscan] {
                let run = |seed| {
                    stage
                        .cluster(&ClusteringInput {
                            dissimilarity: &m,
                            seed,
                            pair_frames: None,
                        })
                        .expect("clusters")
                };
                let seg = run(1);
                assert_eq!(seg.n_bodies(), sizes.len(), "{} {sizes:?}", stage.name());
                assert!(same_partition(&seg, &truth), "{} {sizes:?}", stage.name());
                assert_eq!(seg, run(1), "{}: same seed, same result", stage.name());
            }
        }
    }

    #[test]
    fn invalid_parameters_are_typed_errors() {
        let gmm = [
            SpectralGmmParams {
                reg_covariance: 0.0,
                ..Default::default()
            },
            SpectralGmmParams {
                max_iterations: 0,
                ..Default::default()
            },
            SpectralGmmParams {
                embedding: EmbeddingParams {
                    width: f64::NAN,
                    ..Default::default()
                },
                ..Default::default()
            },
        ];
        for p in gmm {
            assert!(
                matches!(SpectralGmm::new(p), Err(Error::InvalidParameter { .. })),
                "{p:?}"
            );
        }
        let dbscan = [
            SpectralDbscanParams {
                eps: 0.0,
                ..Default::default()
            },
            SpectralDbscanParams {
                core_points: 1,
                ..Default::default()
            },
            SpectralDbscanParams {
                min_points: 2,
                ..Default::default()
            },
        ];
        for p in dbscan {
            assert!(
                matches!(SpectralDbscan::new(p), Err(Error::InvalidParameter { .. })),
                "{p:?}"
            );
        }
    }
}
