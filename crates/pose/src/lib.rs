//! Body pose estimation: Kabsch-Umeyama registration against per-body reference shapes.

mod attach;
mod ball;
mod hinge;
mod kabsch;
mod reference;
mod shape;

pub use attach::{
    ATTACH_BOUND, AttachRule, MIN_SHARED_FRAMES, PointFit, attach_unassigned, explains_point,
    misfit_bound, point_fit, point_misfit,
};
pub use ball::{Ball, BallLimits, MIN_BALL_FRAMES, MIN_BALL_LEVER_IN_SIGMA, balled_body};
pub use hinge::{
    Hinge, HingeLimits, MIN_HINGE_FRAMES, MIN_HINGE_SPREAD_IN_SIGMA, MIN_LEVER_IN_SIGMA,
    filled_from_hinge, filled_from_track, group_rigidity, hinged_body,
};
pub use kabsch::{centroid, kabsch, rotation_cov_per_sigma2, rotation_std_per_sigma, spread};
pub use reference::{KabschParams, KabschPoses};
