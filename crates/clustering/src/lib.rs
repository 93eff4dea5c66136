//! Clustering of points into rigid bodies, each method a [`kinetree_core::Clustering`].

mod hierarchical;
mod unknown;

pub use hierarchical::{Hierarchical, HierarchicalParams, Linkage};
pub use unknown::fill_unknown;
