//! Clustering of points into rigid bodies, each method a [`kinetree_core::Clustering`].

mod dbscan;
mod diagnostics;
mod hierarchical;
mod reassign;
mod spectral;
mod unknown;

pub use dbscan::{Dbscan, DbscanParams};
pub use diagnostics::{SegmentationDiagnostics, diagnostics};
pub use hierarchical::{Hierarchical, HierarchicalParams, Linkage};
pub use reassign::reassign_points;
pub use spectral::{DENSE_LIMIT, Spectral, SpectralParams};
pub use unknown::fill_unknown;
