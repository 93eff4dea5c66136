//! Dissimilarity measures: the paper's F-test q, its -log10 p-value, and the distance
//! std-dev and variance.

use kinetree_core::{
    Dissimilarity, DissimilarityInput, DissimilarityMatrix, Error, PairStats, Result,
};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

fn check_sigma(sigma: f64) -> Result<f64> {
    if sigma.is_finite() && sigma > 0.0 {
        Ok(2.0 * sigma * sigma)
    } else {
        Err(Error::InvalidParameter {
            name: "noise_sigma_m".into(),
            message: format!("per-coordinate noise must be finite and positive, got {sigma}"),
        })
    }
}

/// Parameters of [`FTest`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FTestParams {
    /// Average q above which two groups of points stop looking rigid (default cut for the
    /// clusterer). Under the null hypothesis q is uniform on [0, 1] (mean 0.5); moving pairs
    /// approach 1.
    pub cut: f64,
}

impl Default for FTestParams {
    fn default() -> Self {
        Self { cut: 0.8 }
    }
}

impl FTestParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] when `cut` is not in (0.5, 1).
    pub fn validate(&self) -> Result<()> {
        if !(self.cut > 0.5 && self.cut < 1.0) {
            return Err(Error::InvalidParameter {
                name: "cut".into(),
                message: format!("must lie in (0.5, 1), got {}", self.cut),
            });
        }
        Ok(())
    }
}

/// The paper's one-sided F-test dissimilarity (Sec. III-A):
/// `q_ij = CDF_{F(T_ij - 1, T_ij - 1)}(s_ij^2 / sigma_d^2)` with `sigma_d^2 = 2 sigma^2` the
/// variance of a distance under per-coordinate noise `sigma`.
///
/// q is about uniform on [0, 1] for a rigid pair and tends to 1 for a moving one. Pairs seen
/// together in fewer than two frames get NaN (unknown).
///
/// Complexity: O(N^2) CDF evaluations (about 0.4 us each).
///
/// Reference: the paper in `shared/paper`; F-test as in any statistics text.
#[derive(Debug, Clone)]
pub struct FTest {
    params: FTestParams,
}

impl FTest {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: FTestParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

/// The F statistic of one pair, after the guards statrs needs (it panics on NaN and on
/// ratios whose product with the degrees of freedom overflows).
enum FStatistic {
    /// Fewer than two joint observations or a non-finite variance: no value.
    Unknown,
    /// A ratio too large to evaluate: the pair certainly moves.
    Overflow,
    /// The distribution `F(T_ij - 1, T_ij - 1)` and the ratio `s_ij^2 / sigma_d^2`.
    Value(FisherSnedecor, f64),
}

fn f_statistic(var_m2: f64, count: u32, distance_variance_m2: f64) -> FStatistic {
    if count < 2 || !var_m2.is_finite() {
        return FStatistic::Unknown;
    }
    let ratio = var_m2 / distance_variance_m2;
    let dof = f64::from(count - 1);
    if !ratio.is_finite() || ratio * dof > 1e300 {
        return FStatistic::Overflow;
    }
    match FisherSnedecor::new(dof, dof) {
        Ok(f) => FStatistic::Value(f, ratio),
        Err(_) => FStatistic::Unknown,
    }
}

/// The matrix of `values` over `stats`'s points, with the measure's default cut.
fn matrix(
    stats: &PairStats,
    values: Vec<f64>,
    suggested_cut: f64,
    measure: &str,
) -> DissimilarityMatrix {
    DissimilarityMatrix {
        n_points: stats.n_points,
        values,
        suggested_cut,
        measure: measure.into(),
    }
}

/// Applies a per-pair function of `(variance, count, sigma_d^2)` to every pair, the pairs
/// split over the threads: each value depends on its pair alone, so the matrix is the same
/// whatever the thread count. The F distribution's CDF (a regularised incomplete beta
/// function) costs a few hundred nanoseconds a pair: about 30 ms for the 125 000 pairs of
/// 500 points on one thread.
fn per_pair(stats: &PairStats, distance_variance_m2: f64, f: fn(f64, u32, f64) -> f64) -> Vec<f64> {
    use rayon::prelude::*;
    stats
        .var_m2
        .par_iter()
        .zip(&stats.count)
        .map(|(&v, &c)| f(v, c, distance_variance_m2))
        .collect()
}

/// q for one pair: NaN when unknown, 1 when the ratio overflows.
pub fn f_test_q(var_m2: f64, count: u32, distance_variance_m2: f64) -> f64 {
    match f_statistic(var_m2, count, distance_variance_m2) {
        FStatistic::Unknown => f64::NAN,
        FStatistic::Overflow => 1.0,
        FStatistic::Value(f, ratio) => f.cdf(ratio),
    }
}

impl Dissimilarity for FTest {
    fn name(&self) -> &str {
        "f_test"
    }

    fn compute(&self, input: &DissimilarityInput<'_>) -> Result<DissimilarityMatrix> {
        let vd = check_sigma(input.noise_sigma_m)?;
        let s = input.stats;
        Ok(matrix(
            s,
            per_pair(s, vd, f_test_q),
            self.params.cut,
            self.name(),
        ))
    }
}

/// Parameters of [`LogPValue`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LogPValueParams {
    /// Average `-log10 p` above which two groups of points stop looking rigid (default cut for
    /// the clusterer). Under the null hypothesis `-log10 p` has mean `1 / ln 10 = 0.43`.
    pub cut: f64,
}

impl Default for LogPValueParams {
    fn default() -> Self {
        Self { cut: 2.0 }
    }
}

impl LogPValueParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] when `cut` is not finite and above 0.5.
    pub fn validate(&self) -> Result<()> {
        if !(self.cut.is_finite() && self.cut > 0.5) {
            return Err(Error::InvalidParameter {
                name: "cut".into(),
                message: format!("must be finite and above 0.5, got {}", self.cut),
            });
        }
        Ok(())
    }
}

/// The largest `-log10 p` reported; the survival function underflows near 1e-308.
pub const MAX_LOG_P: f64 = 300.0;

/// `-log10` of the F-test's p-value, the survival function of `F(T_ij - 1, T_ij - 1)` at
/// `s_ij^2 / sigma_d^2`: the paper's q made into evidence that does not saturate. q rounds to
/// exactly 1 once `p < 5e-17`, so every clearly moving pair looks the same; here the evidence
/// keeps growing (capped at [`MAX_LOG_P`]), and in an average over pairs a few strongly moving
/// pairs outweigh many that barely move.
#[derive(Debug, Clone)]
pub struct LogPValue {
    params: LogPValueParams,
}

impl LogPValue {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: LogPValueParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

/// `-log10 p` for one pair: NaN when unknown, [`MAX_LOG_P`] where `p` underflows.
pub fn f_test_log_p(var_m2: f64, count: u32, distance_variance_m2: f64) -> f64 {
    match f_statistic(var_m2, count, distance_variance_m2) {
        FStatistic::Unknown => f64::NAN,
        FStatistic::Overflow => MAX_LOG_P,
        FStatistic::Value(f, ratio) => {
            let p = f.sf(ratio);
            if p > 0.0 {
                (-p.log10()).clamp(0.0, MAX_LOG_P)
            } else {
                MAX_LOG_P
            }
        }
    }
}

impl Dissimilarity for LogPValue {
    fn name(&self) -> &str {
        "log_p_value"
    }

    fn compute(&self, input: &DissimilarityInput<'_>) -> Result<DissimilarityMatrix> {
        let vd = check_sigma(input.noise_sigma_m)?;
        let s = input.stats;
        Ok(matrix(
            s,
            per_pair(s, vd, f_test_log_p),
            self.params.cut,
            self.name(),
        ))
    }
}

/// Parameters of [`DistanceStd`] and [`DistanceVariance`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SpreadParams {
    /// Default cut as a multiple of the noise's distance std-dev `sqrt(2) sigma`.
    pub cut_in_noise_std: f64,
}

impl Default for SpreadParams {
    fn default() -> Self {
        Self {
            cut_in_noise_std: 3.0,
        }
    }
}

impl SpreadParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] when `cut_in_noise_std` is not finite and above 1.
    pub fn validate(&self) -> Result<()> {
        if !(self.cut_in_noise_std.is_finite() && self.cut_in_noise_std > 1.0) {
            return Err(Error::InvalidParameter {
                name: "cut_in_noise_std".into(),
                message: format!("must be finite and above 1, got {}", self.cut_in_noise_std),
            });
        }
        Ok(())
    }
}

/// Standard deviation of each pair's distance, metres (the left panel of the paper's Fig. 3).
#[derive(Debug, Clone)]
pub struct DistanceStd {
    params: SpreadParams,
}

impl DistanceStd {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SpreadParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Dissimilarity for DistanceStd {
    fn name(&self) -> &str {
        "distance_std"
    }

    fn compute(&self, input: &DissimilarityInput<'_>) -> Result<DissimilarityMatrix> {
        let vd = check_sigma(input.noise_sigma_m)?;
        let s = input.stats;
        let values = s.var_m2.iter().map(|v| v.sqrt()).collect();
        Ok(matrix(
            s,
            values,
            self.params.cut_in_noise_std * vd.sqrt(),
            self.name(),
        ))
    }
}

/// Sample variance of each pair's distance, m^2.
#[derive(Debug, Clone)]
pub struct DistanceVariance {
    params: SpreadParams,
}

impl DistanceVariance {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SpreadParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Dissimilarity for DistanceVariance {
    fn name(&self) -> &str {
        "distance_variance"
    }

    fn compute(&self, input: &DissimilarityInput<'_>) -> Result<DissimilarityMatrix> {
        let vd = check_sigma(input.noise_sigma_m)?;
        let s = input.stats;
        let cut = self.params.cut_in_noise_std.powi(2) * vd;
        Ok(matrix(s, s.var_m2.clone(), cut, self.name()))
    }
}
