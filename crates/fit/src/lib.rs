//! The whole-tree fit of a discovered model: every frame's root pose and joint positions
//! fitted to its visible keypoints ([`Observer`], `solver.rs`, factored along the tree by
//! `tree_cholesky.rs`), the joints' parameters bundle-adjusted over all frames (`bundle.rs`),
//! one joint refined alone (`refine.rs`), the policy that frees, readmits and types joints by
//! the fit ([`fit_model_positions`], `policy.rs`), the positions smoothed over time
//! (`smooth.rs`), and the fitted motions that judge points against every body
//! ([`FittedMotions`], `motions.rs`), and the joint positions of new frames with each
//! frame's fit ([`observe`], `observation.rs`), whether the motion can tell each joint's
//! type from the others ([`identifiability_warnings`], `identify.rs`), and links no keypoint
//! shows put between two hinges ([`unseen_links`], `unseen.rs`).
//!
//! Module dependencies run one way: `tree_cholesky` <- `solver` <- `refine` <- `bundle` <-
//! `policy` <- `unseen`; `smooth` and `motions` use `solver` only.

mod bundle;
mod hubs;
mod identify;
mod motions;
mod observation;
mod policy;
mod refine;
mod smooth;
mod solver;
mod tree_cholesky;
mod unseen;

pub use bundle::BundleLimits;
pub use hubs::unseen_hubs;
pub use identify::identifiability_warnings;
pub use motions::{
    FittedMotions, MAX_BODY_MEDIAN, MIN_CHI2_GAIN, MIN_FRAMES, MIN_FRAMES_TO_PLACE, MIN_MARGIN,
    MotionLimits, OUTLIER_RATIO,
};
pub use observation::{
    DEFAULT_UNEXPLAINED_FACTOR, Observation, ObserveOptions, POSE_COLUMNS,
    TYPICAL_REPREDICTION_IN_SIGMA, observe,
};
pub use policy::{
    FitState, FreeLimits, MAX_JOINT_EXCESS, TypeByFitLimits, bundle_adjust, fit_model_positions,
    free_unfollowed_joints, readmit_freed_joints, type_joints_by_fit, write_joint_precision,
    write_positions,
};
pub use smooth::{PositionColumn, SmoothedPositions, smooth_fitted_positions, smooth_positions};
pub use solver::{FrameFit, Observer};
pub use unseen::{UnseenLinkLimits, unseen_links};
