//! Clustering of points into rigid bodies, each method a [`kinetree_core::Clustering`].

mod dbscan;
mod diagnostics;
#[cfg(feature = "linfa")]
mod embedded;
mod hierarchical;
mod reassign;
mod spectral;
#[cfg(test)]
mod test_support;
mod unknown;
mod weighted;

pub use dbscan::{Dbscan, DbscanParams};
pub use diagnostics::{SegmentationDiagnostics, diagnostics};
#[cfg(feature = "linfa")]
pub use embedded::{SpectralDbscan, SpectralDbscanParams, SpectralGmm, SpectralGmmParams};
pub use hierarchical::{Hierarchical, HierarchicalParams, Linkage};
pub use reassign::reassign_points;
pub use spectral::{DENSE_LIMIT, EmbeddingParams, KMeansImpl, Spectral, SpectralParams};
pub use unknown::fill_unknown;

/// The checks every clusterer makes on its input: one value per pair, none infinite (NaN marks
/// an unknown pair and is allowed).
///
/// # Errors
/// [`kinetree_core::Error::Shape`] for a wrong number of values,
/// [`kinetree_core::Error::InvalidParameter`] for an infinite one.
fn check_matrix(m: &kinetree_core::DissimilarityMatrix) -> kinetree_core::Result<()> {
    let n = kinetree_core::n_pairs(m.n_points);
    if m.values.len() != n {
        return Err(kinetree_core::Error::Shape {
            expected: format!("{n} condensed values"),
            found: format!("{}", m.values.len()),
        });
    }
    if m.values.iter().any(|v| v.is_infinite()) {
        return Err(kinetree_core::Error::InvalidParameter {
            name: "dissimilarity".into(),
            message: "contains infinite values".into(),
        });
    }
    Ok(())
}
