//! Pairwise distance statistics, dissimilarity measures and noise estimation.
//!
//! Every measure implements [`kinetree_core::Dissimilarity`]. Noise parameters are the
//! per-coordinate std-dev `sigma` in metres; a distance then has variance about `2 sigma^2`.

mod measures;
mod noise;
mod stats;

pub use measures::{
    DistanceStd, DistanceVariance, FTest, FTestParams, LogPValue, LogPValueParams, MAX_LOG_P,
    SpreadParams, f_test_log_p, f_test_q,
};
pub use noise::{estimate_noise_sigma, estimate_noise_sigma_nearest_rigid, refine_noise_sigma};
pub use stats::{PairStatsAccumulator, pair_stats, pair_stats_reference};
