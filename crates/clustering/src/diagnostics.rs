//! Diagnostics of a segmentation against the dissimilarity it came from.

use kinetree_core::{DissimilarityMatrix, Segmentation};

/// Per-point and per-body diagnostics, in the segmentation's body numbering.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentationDiagnostics {
    /// For each point: the mean dissimilarity to the nearest *other* body minus the mean to
    /// its own body, over observed pairs, on the measure's scale. Large and positive: a clear
    /// assignment; near zero or negative: the point could belong elsewhere. `None` for
    /// unassigned points or when either mean has no observed pair.
    pub point_margin: Vec<Option<f64>>,
    /// For each body: the median and 90th percentile of the dissimilarity between its points
    /// (observed pairs only). A rigid body under the F-test has a median near 0.5.
    pub body_spread: Vec<Option<[f64; 2]>>,
}

/// Computes [`SegmentationDiagnostics`].
///
/// Complexity: O(N^2).
pub fn diagnostics(m: &DissimilarityMatrix, seg: &Segmentation) -> SegmentationDiagnostics {
    let nb = seg.n_bodies();
    let mut point_margin = vec![None; m.n_points];
    for (i, margin) in point_margin.iter_mut().enumerate() {
        let Some(own) = seg.body_of(i) else { continue };
        let means = crate::reassign::body_means(m, seg.labels(), nb, i);
        let mean = |b: usize| (means[b].1 > 0).then_some(means[b].0);
        let other = (0..nb)
            .filter(|&b| b != own)
            .filter_map(mean)
            .fold(None, |acc: Option<f64>, v| {
                Some(acc.map_or(v, |a| a.min(v)))
            });
        if let (Some(o), Some(s)) = (other, mean(own)) {
            *margin = Some(o - s);
        }
    }
    let body_spread = seg
        .members()
        .iter()
        .map(|pts| {
            let mut v: Vec<f64> = pts
                .iter()
                .enumerate()
                .flat_map(|(a, &i)| pts[a + 1..].iter().filter_map(move |&j| m.get(i, j)))
                .collect();
            if v.is_empty() {
                return None;
            }
            v.sort_by(f64::total_cmp);
            Some([v[v.len() / 2], v[(v.len() - 1) * 9 / 10]])
        })
        .collect();
    SegmentationDiagnostics {
        point_margin,
        body_spread,
    }
}
