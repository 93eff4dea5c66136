//! DBSCAN on the precomputed dissimilarity matrix.

use crate::{Hierarchical, HierarchicalParams};
use kinetree_core::{
    Clustering, ClusteringInput, DissimilarityMatrix, Error, MIN_BODY_POINTS, Result, Segmentation,
    condensed_index,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`Dbscan`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DbscanParams {
    /// Neighbourhood radius on the dissimilarity's scale; `None` uses the measure's suggested
    /// cut.
    pub eps: Option<f64>,
    /// Neighbours (the point itself included) that make a core point.
    pub min_points: usize,
    /// Two core points `p`, `q` within `eps` join one cluster only if their closed
    /// neighbourhoods (each point with its neighbours) share at least this fraction of the
    /// smaller one; 0 gives classic DBSCAN.
    pub shared_fraction: f64,
    /// Clusters with fewer points are discarded (at least 3, the minimum for a pose).
    pub min_cluster_points: usize,
    /// Find exactly this many clusters instead: `eps` is chosen from 64 radii spaced
    /// geometrically over the observed dissimilarities, the one giving this count that lies
    /// nearest the measure's cut (overrides `eps`).
    pub n_clusters: Option<usize>,
    /// Points DBSCAN leaves as noise or in clusters under `min_cluster_points` are clustered
    /// among themselves by average linkage cut at `eps`, and groups of at least
    /// `min_cluster_points` become clusters (see [`Dbscan`]).
    pub regroup_leftovers: bool,
}

impl Default for DbscanParams {
    fn default() -> Self {
        Self {
            eps: None,
            min_points: 3,
            shared_fraction: 0.9,
            min_cluster_points: MIN_BODY_POINTS,
            n_clusters: None,
            regroup_leftovers: true,
        }
    }
}

impl DbscanParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a non-finite `eps`, `min_points < 2` or
    /// `min_cluster_points < 3`.
    pub fn validate(&self) -> Result<()> {
        if let Some(e) = self.eps
            && !e.is_finite()
        {
            return Err(Error::InvalidParameter {
                name: "eps".into(),
                message: format!("must be finite, got {e}"),
            });
        }
        if !(0.0..=1.0).contains(&self.shared_fraction) {
            return Err(Error::InvalidParameter {
                name: "shared_fraction".into(),
                message: format!("must be within 0 to 1, got {}", self.shared_fraction),
            });
        }
        if self.n_clusters == Some(0) {
            return Err(Error::InvalidParameter {
                name: "n_clusters".into(),
                message: "must be at least 1".into(),
            });
        }
        if self.min_points < 2 {
            return Err(Error::InvalidParameter {
                name: "min_points".into(),
                message: format!("must be at least 2, got {}", self.min_points),
            });
        }
        if self.min_cluster_points < MIN_BODY_POINTS {
            return Err(Error::InvalidParameter {
                name: "min_cluster_points".into(),
                message: format!(
                    "must be at least {MIN_BODY_POINTS}, got {}",
                    self.min_cluster_points
                ),
            });
        }
        Ok(())
    }
}

/// Density-based clustering (Ester et al. 1996) on the precomputed matrix: a point with at
/// least `min_points` neighbours within `eps` (itself included) is a core point; clusters are
/// the core points connected through neighbourhoods plus the points they reach; the rest is
/// noise (unassigned). Neighbours use `d <= eps` (sklearn's convention); a pair never seen
/// together (NaN) is never a neighbour.
///
/// Written here rather than taken from linfa-clustering, whose `Dbscan` has no precomputed
/// mode: it wants coordinates and a nearest-neighbour index, and the workaround (records as
/// indices, a distance that looks them up) measured 80 ms against 15 ms for this loop at
/// N = 2000, with identical labels (shared/notes/crates.md).
///
/// Unknown pairs are first inferred through third points ([`crate::fill_unknown`]).
///
/// Classic DBSCAN chains bodies together: a point of one body near a joint axis has low-q
/// pairs with the other body's points near the axis, and one such core-to-core link merges
/// the two bodies (the pipeline then discards the mixed cluster). So a core point joins a
/// cluster through another core point only when their closed neighbourhoods overlap by
/// `shared_fraction` of the smaller (the shared-nearest-neighbour idea of Jarvis and Patrick
/// 1973, Ertöz et al. 2003): two points of one body see mostly the same body, two points on
/// either side of an axis see different ones. Non-core points still join as borders.
///
/// Measured on 200 general-position mechanisms of 2-12 bodies at 1 mm and 30 % occlusion
/// (pipeline defaults otherwise, `ARI = 1`): classic DBSCAN (`shared_fraction = 0`,
/// `min_points = 4`) 135 of 200, the overlap rule at 0.9 with `min_points = 3` 185, and 193
/// with the leftovers regrouped (below); average linkage 192 (`docs/decisions.md`,
/// `clustering.dbscan.shared_fraction`). Without the regrouping, most of DBSCAN's failures
/// are 4-5 point bodies without enough pairs under the cut to hold a core point.
///
/// Small bodies fall apart under the overlap rule: with the F-test's `q` uniform on rigid
/// pairs, a 6-point body's points have 3-4 neighbours each, two of them rarely share 90 % of
/// their neighbourhoods, and the body ends as fragments of 1-2 points that are discarded.
/// So the leftovers (noise and fragments) are clustered once more among themselves, by
/// average linkage at `eps` (`regroup_leftovers`): a group of them that is rigid on average
/// becomes a cluster. Measured on the same 200 mechanisms (with the pipeline's pairwise split
/// of mixed bodies; identifiable ARI, see `kinetree_eval::identifiable_ari`): 187 without,
/// 193 with (hierarchical 195, spectral 194); with the pipeline's own regrouping of
/// unassigned points by their poses, every clusterer gets 196.
///
/// Complexity: O(N^2).
#[derive(Debug, Clone)]
pub struct Dbscan {
    params: DbscanParams,
}

impl Dbscan {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: DbscanParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Dbscan {
    /// Whether core points with these (ascending) neighbour lists may share a cluster.
    fn strongly_linked(&self, a: &[usize], b: &[usize]) -> bool {
        // Closed neighbourhoods: the two points are in each other's lists and in their own.
        let common = shared(a, b) + 2;
        let smaller = a.len().min(b.len()) + 1;
        common as f64 >= self.params.shared_fraction * smaller as f64
    }
}

impl Clustering for Dbscan {
    fn name(&self) -> &str {
        "dbscan"
    }

    fn cluster(&self, input: &ClusteringInput<'_>) -> Result<Segmentation> {
        let m = input.dissimilarity;
        crate::check_matrix(m)?;
        let (filled, has_known) = crate::fill_unknown(m);
        let segment = |eps: f64| {
            Segmentation::from_raw(
                &self.labels(&filled, &has_known, eps),
                self.params.min_cluster_points,
            )
        };
        let Some(k) = self.params.n_clusters else {
            return Ok(segment(self.params.eps.unwrap_or(m.suggested_cut)));
        };
        // Radii over the observed range, geometric (dissimilarities span decades).
        let (lo, hi) = filled
            .iter()
            .filter(|v| v.is_finite() && **v > 0.0)
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        let target = m.suggested_cut.max(f64::MIN_POSITIVE);
        let mut best: Option<(f64, Segmentation)> = None;
        let mut counts = Vec::new();
        if lo.is_finite() && hi > 0.0 {
            for i in 0..64 {
                let eps = lo * (hi / lo).powf(f64::from(i) / 63.0);
                let seg = segment(eps);
                counts.push(seg.n_bodies());
                let distance = (eps / target).ln().abs();
                if seg.n_bodies() == k && best.as_ref().is_none_or(|(d, _)| distance < *d) {
                    best = Some((distance, seg));
                }
            }
        }
        counts.dedup();
        best.map(|(_, seg)| seg).ok_or_else(|| {
            Error::Degenerate(format!(
                "dbscan: no neighbourhood radius gives {k} clusters; the radii tried give {counts:?}"
            ))
        })
    }
}

impl Dbscan {
    /// Raw cluster labels at radius `eps` on the filled matrix.
    fn labels(&self, filled: &[f64], has_known: &[bool], eps: f64) -> Vec<Option<usize>> {
        let n = has_known.len();
        let neighbours: Vec<Vec<usize>> = (0..n)
            .map(|i| {
                if !has_known[i] {
                    return Vec::new();
                }
                (0..n)
                    .filter(|&j| j != i && has_known[j] && filled[condensed_index(n, i, j)] <= eps)
                    .collect()
            })
            .collect();
        let core: Vec<bool> = neighbours
            .iter()
            .map(|nb| nb.len() + 1 >= self.params.min_points)
            .collect();
        let mut label: Vec<Option<usize>> = vec![None; n];
        let mut next = 0usize;
        for start in 0..n {
            if !core[start] || label[start].is_some() {
                continue;
            }
            label[start] = Some(next);
            let mut stack = vec![start];
            while let Some(p) = stack.pop() {
                for &q in &neighbours[p] {
                    if label[q].is_some() {
                        continue;
                    }
                    if !core[q] {
                        label[q] = Some(next);
                    } else if self.strongly_linked(&neighbours[p], &neighbours[q]) {
                        label[q] = Some(next);
                        stack.push(q);
                    }
                }
            }
            next += 1;
        }
        if self.params.regroup_leftovers {
            self.regroup(filled, has_known, eps, &mut label, next);
        }
        label
    }

    /// Clusters the points left as noise or in clusters under `min_cluster_points` among
    /// themselves (average linkage cut at `eps`), labelling groups large enough from `next` on.
    fn regroup(
        &self,
        filled: &[f64],
        has_known: &[bool],
        eps: f64,
        label: &mut [Option<usize>],
        next: usize,
    ) {
        let n = label.len();
        let mut size = vec![0usize; next];
        for l in label.iter().flatten() {
            size[*l] += 1;
        }
        let left: Vec<usize> = (0..n)
            .filter(|&i| {
                has_known[i] && label[i].is_none_or(|l| size[l] < self.params.min_cluster_points)
            })
            .collect();
        if left.len() < self.params.min_cluster_points {
            return;
        }
        let mut values = Vec::with_capacity(kinetree_core::n_pairs(left.len()));
        for (x, &i) in left.iter().enumerate() {
            for &j in &left[x + 1..] {
                values.push(filled[condensed_index(n, i, j)]);
            }
        }
        let sub = DissimilarityMatrix {
            n_points: left.len(),
            values,
            suggested_cut: eps,
            measure: "dbscan leftovers".into(),
        };
        let Ok(linkage) = Hierarchical::new(HierarchicalParams {
            cut: Some(eps),
            min_points: self.params.min_cluster_points,
            ..HierarchicalParams::default()
        }) else {
            return;
        };
        let Ok(groups) = linkage.cluster(&ClusteringInput {
            dissimilarity: &sub,
            seed: 0,
            pair_frames: None,
        }) else {
            return;
        };
        for (x, &i) in left.iter().enumerate() {
            label[i] = groups.body_of(x).map(|g| next + g);
        }
    }
}

/// Size of the intersection of two ascending index lists.
fn shared(a: &[usize], b: &[usize]) -> usize {
    let (mut i, mut j, mut n) = (0, 0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                n += 1;
                i += 1;
                j += 1;
            }
        }
    }
    n
}
