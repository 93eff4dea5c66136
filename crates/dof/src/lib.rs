//! Relative degree-of-freedom tests between bodies and the camera frame.

mod rank;
mod svd_rank;

pub use rank::{principal_direction, rank_test};
pub use svd_rank::{SvdRank, SvdRankParams};
