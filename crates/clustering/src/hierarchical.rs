//! Agglomerative (hierarchical) clustering on the dissimilarity matrix, via kodama.

use crate::unknown::fill_unknown;
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
}

impl Default for HierarchicalParams {
    fn default() -> Self {
        Self {
            linkage: Linkage::Average,
            cut: None,
            n_clusters: None,
            min_points: MIN_BODY_POINTS,
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
/// "Modern hierarchical, agglomerative clustering algorithms"); kodama has no cut function,
/// so the cut is a union-find over the merge steps, valid because the supported linkages are
/// monotone.
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
        let mut condensed = Vec::with_capacity(k * (k - 1) / 2);
        for (a, &i) in keep.iter().enumerate() {
            for &j in &keep[a + 1..] {
                condensed.push(filled[condensed_index(m.n_points, i, j)]);
            }
        }
        let dendrogram = kodama::linkage(&mut condensed, k, self.params.linkage.method());
        let steps = dendrogram.steps();
        let n_merges = match (self.params.n_clusters, self.params.cut) {
            (Some(c), _) => k.saturating_sub(c.min(k)),
            (None, cut) => {
                let cut = cut.unwrap_or(m.suggested_cut);
                steps.iter().take_while(|s| s.dissimilarity <= cut).count()
            }
        };
        let mut parent: Vec<usize> = (0..k).collect();
        let mut rep: Vec<usize> = (0..k).collect();
        for s in &steps[..n_merges] {
            let (a, b) = (rep[s.cluster1], rep[s.cluster2]);
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            parent[rb] = ra;
            rep.push(ra);
        }
        for (a, &i) in keep.iter().enumerate() {
            raw[i] = Some(find(&mut parent, a));
        }
        Ok(Segmentation::from_raw(&raw, self.params.min_points))
    }
}
