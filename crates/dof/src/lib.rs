//! Relative degree-of-freedom tests between bodies and the camera frame.

mod axis;
mod rank;
mod tester;
mod track;

pub use axis::fixed_axis;
pub use rank::{
    HiddenHinge, MIN_EXCESS, RankRule, chi2_per_dof_quantile, hidden_next_rank,
    hidden_next_rank_above, mahalanobis_line, rank_test, rank_test_uncentred, weighted_direction,
};
pub use tester::{Chi2Rank, Chi2RankParams, SvdRank, SvdRankParams};
pub use track::{
    TRACK_MIN_ARC_DEG, TRACK_SIGNIFICANCE, TrackFit, TrackFitParams, TrackJoint, fit_point_track,
};
