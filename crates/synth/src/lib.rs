//! Synthetic articulated mechanisms: boxes joined by revolute and prismatic joints, joint
//! trajectories, a camera with a field of view, self-occlusion by ray casting, extra burst
//! dropout and Gaussian noise, all from a seed.

mod mechanism;
mod named;
mod scenario;

pub use mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
pub use named::{RandomParams, paper_arm, random_scenario};
pub use scenario::{Camera, GroundTruth, Scenario, SynthData, Trajectory, is_angular, simulate};
