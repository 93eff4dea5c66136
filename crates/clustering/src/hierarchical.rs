//! Agglomerative (hierarchical) clustering on the dissimilarity matrix, via kodama or, for the
//! average linkage weighted by the pairs' frames, kinetree's own nearest-neighbour chain.

use crate::unknown::fill_unknown;
use crate::weighted::{Merge, kodama_linkage, weighted_average_linkage};
use kinetree_core::{
    Clustering, ClusteringInput, Error, MIN_BODY_POINTS, Result, Segmentation, condensed_index,
};
use serde::{Deserialize, Serialize};

/// Linkage criterion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Linkage {
    /// Nearest pair (single linkage, minimum spanning tree).
    Single,
    /// Farthest pair.
    Complete,
    /// Mean over all cross pairs (UPGMA).
    #[default]
    Average,
    /// WPGMA.
    Weighted,
    /// Ward's minimum variance.
    Ward,
}

impl Linkage {
    fn method(self) -> kodama::Method {
        match self {
            Linkage::Single => kodama::Method::Single,
            Linkage::Complete => kodama::Method::Complete,
            Linkage::Average => kodama::Method::Average,
            Linkage::Weighted => kodama::Method::Weighted,
            Linkage::Ward => kodama::Method::Ward,
        }
    }
}

/// Parameters of [`Hierarchical`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HierarchicalParams {
    /// Linkage criterion.
    pub linkage: Linkage,
    /// Cut height on the dissimilarity's scale; `None` uses the measure's suggested cut.
    pub cut: Option<f64>,
    /// Cut into exactly this many clusters instead (overrides `cut`).
    pub n_clusters: Option<usize>,
    /// Clusters with fewer points are discarded (at least 3, the minimum for a pose).
    pub min_points: usize,
    /// With `average` linkage, weigh each pair by the frames its points were seen together in
    /// (when the input carries them), so that a pair seen in a few frames counts for little.
    /// A few consecutive frames of smooth motion barely change a distance, so such a pair
    /// reads as rigid whether it is or not; unweighted, it counts as much as a pair seen
    /// throughout. A pair inferred through third points counts as one frame. Other linkages
    /// ignore it.
    pub weigh_by_frames: bool,
}

impl Default for HierarchicalParams {
    fn default() -> Self {
        Self {
            linkage: Linkage::Average,
            cut: None,
            n_clusters: None,
            min_points: MIN_BODY_POINTS,
            weigh_by_frames: true,
        }
    }
}

impl HierarchicalParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a cut that is negative (every dissimilarity is at least
    /// zero, so it would leave every point alone) or not finite, zero clusters, or
    /// `min_points < 3`.
    pub fn validate(&self) -> Result<()> {
        if let Some(c) = self.cut
            && !(c.is_finite() && c >= 0.0)
        {
            return Err(Error::InvalidParameter {
                name: "cut".into(),
                message: format!("must be finite and at least 0, got {c}"),
            });
        }
        if self.n_clusters == Some(0) {
            return Err(Error::InvalidParameter {
                name: "n_clusters".into(),
                message: "must be at least 1".into(),
            });
        }
        if self.min_points < MIN_BODY_POINTS {
            return Err(Error::InvalidParameter {
                name: "min_points".into(),
                message: format!(
                    "must be at least {MIN_BODY_POINTS}, got {}",
                    self.min_points
                ),
            });
        }
        Ok(())
    }
}

/// Hierarchical clustering with a cut by height or by number of clusters.
///
/// Unknown pairs are first inferred through third points ([`crate::fill_unknown`]); points with
/// no known pair are left unassigned. The dendrogram comes from kodama (Müllner 2011,
/// "Modern hierarchical, agglomerative clustering algorithms"), except for the average linkage
/// weighted by the pairs' frames ([`HierarchicalParams::weigh_by_frames`], the default), which
/// kodama cannot weigh and which runs its own nearest-neighbour chain. The cut is a union-find
/// over the merges, valid because the supported linkages are monotone.
///
/// Complexity: O(N^2) memory, O(N^2) to O(N^2 log N) time depending on the linkage.
#[derive(Debug, Clone)]
pub struct Hierarchical {
    params: HierarchicalParams,
}

impl Hierarchical {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: HierarchicalParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

fn find(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

impl Clustering for Hierarchical {
    fn name(&self) -> &str {
        "hierarchical"
    }

    fn cluster(&self, input: &ClusteringInput<'_>) -> Result<Segmentation> {
        let m = input.dissimilarity;
        crate::check_matrix(m)?;
        let (filled, has_known) = fill_unknown(m);
        // Cluster only points with at least one known pair.
        let keep: Vec<usize> = (0..m.n_points).filter(|&i| has_known[i]).collect();
        let k = keep.len();
        let mut raw = vec![None; m.n_points];
        if k == 0 {
            return Ok(Segmentation::from_raw(&raw, self.params.min_points));
        }
        if k == 1 {
            raw[keep[0]] = Some(0);
            return Ok(Segmentation::from_raw(&raw, self.params.min_points));
        }
        let frames = match input.pair_frames {
            Some(f) if self.params.weigh_by_frames && self.params.linkage == Linkage::Average => {
                if f.len() != m.values.len() {
                    return Err(Error::Shape {
                        expected: format!("{} pair frame counts", m.values.len()),
                        found: format!("{}", f.len()),
                    });
                }
                Some(f)
            }
            _ => None,
        };
        let mut condensed = Vec::with_capacity(k * (k - 1) / 2);
        let mut weights = Vec::with_capacity(if frames.is_some() { k * (k - 1) / 2 } else { 0 });
        for (a, &i) in keep.iter().enumerate() {
            for &j in &keep[a + 1..] {
                let c = condensed_index(m.n_points, i, j);
                condensed.push(filled[c]);
                if let Some(frames) = frames {
                    let seen = if m.values[c].is_nan() { 1 } else { frames[c] };
                    weights.push(f64::from(seen.max(1)));
                }
            }
        }
        // Each merge names one point of either group, in order of height.
        let merges: Vec<Merge> = if frames.is_some() {
            weighted_average_linkage(&condensed, &weights, k)
        } else {
            kodama_linkage(&mut condensed, k, self.params.linkage.method())
        };
        let n_merges = match (self.params.n_clusters, self.params.cut) {
            (Some(c), _) => k.saturating_sub(c.min(k)),
            (None, cut) => {
                let cut = cut.unwrap_or(m.suggested_cut);
                merges.iter().take_while(|s| s.height <= cut).count()
            }
        };
        let mut parent: Vec<usize> = (0..k).collect();
        for &Merge { a, b, .. } in &merges[..n_merges] {
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            parent[rb] = ra;
        }
        for (a, &i) in keep.iter().enumerate() {
            raw[i] = Some(find(&mut parent, a));
        }
        Ok(Segmentation::from_raw(&raw, self.params.min_points))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinetree_core::{DissimilarityMatrix, n_pairs};

    /// Two groups of ten points that move against each other: every pair seen throughout is
    /// clearly moving (0.99) or rigid (0.4), but half the cross pairs were seen together in
    /// only four frames, over which the motion hid in the noise (0.45).
    fn moving_groups_with_short_pairs() -> (DissimilarityMatrix, Vec<u32>) {
        let n = 20;
        let mut values = vec![0.0; n_pairs(n)];
        let mut frames = vec![300u32; n_pairs(n)];
        for i in 0..n {
            for j in i + 1..n {
                let c = condensed_index(n, i, j);
                if (i < 10) == (j < 10) {
                    values[c] = 0.4;
                } else if (i + j) % 2 == 0 {
                    values[c] = 0.45;
                    frames[c] = 4;
                } else {
                    values[c] = 0.99;
                }
            }
        }
        let m = DissimilarityMatrix {
            n_points: n,
            values,
            suggested_cut: 0.8,
            measure: "test".into(),
        };
        (m, frames)
    }

    #[test]
    fn pairs_seen_in_a_few_frames_do_not_join_moving_groups() {
        let (m, frames) = moving_groups_with_short_pairs();
        let run = |weigh_by_frames: bool, pair_frames: Option<&[u32]>| {
            Hierarchical::new(HierarchicalParams {
                weigh_by_frames,
                ..HierarchicalParams::default()
            })
            .expect("params")
            .cluster(&ClusteringInput {
                dissimilarity: &m,
                seed: 0,
                pair_frames,
            })
            .expect("clusters")
            .n_bodies()
        };
        // Weighed by frames the cross mean is about 0.98; unweighted it is 0.72, under the
        // cut.
        assert_eq!(run(true, Some(&frames)), 2);
        assert_eq!(run(false, Some(&frames)), 1);
        assert_eq!(run(true, None), 1);
        // A count vector of the wrong length is an error, not a silent fallback.
        let short = &frames[1..];
        let err = Hierarchical::new(HierarchicalParams::default())
            .expect("params")
            .cluster(&ClusteringInput {
                dissimilarity: &m,
                seed: 0,
                pair_frames: Some(short),
            });
        assert!(matches!(err, Err(Error::Shape { .. })), "{err:?}");
    }
}
