//! Body pose estimation: Kabsch-Umeyama registration against per-body reference shapes.

mod kabsch;
mod reference;

pub use kabsch::{centroid, kabsch, rotation_std_per_sigma, spread};
pub use reference::{KabschParams, KabschPoses};
