//! The policy for pairs never seen together: infer them through third points.

use kinetree_core::{DissimilarityMatrix, condensed_index};

/// Fills the unknown (NaN) entries of a condensed dissimilarity matrix through third points:
/// `d_ij = min_k max(d_ik, d_kj)`, the best two-hop path in the minimax sense. If `i` and `j`
/// are both rigidly attached to some `k` seen with each of them, the pair is inferred rigid;
/// otherwise it takes the smallest bottleneck available. Pairs with no such `k` get the largest
/// known value. Points with no known pair at all are reported in the returned mask (`false`).
///
/// The paper drops every point with an unknown pair; under heavy occlusion that discards most
/// of the data, while this keeps every point that shares a body with something it was seen with.
///
/// Complexity: O(U N) for U unknown pairs.
pub fn fill_unknown(m: &DissimilarityMatrix) -> (Vec<f64>, Vec<bool>) {
    let n = m.n_points;
    let v = &m.values;
    let mut has_known = vec![false; n];
    let mut max_known = f64::NEG_INFINITY;
    for i in 0..n {
        for j in i + 1..n {
            let d = v[condensed_index(n, i, j)];
            if !d.is_nan() {
                has_known[i] = true;
                has_known[j] = true;
                max_known = max_known.max(d);
            }
        }
    }
    if !max_known.is_finite() {
        max_known = 1.0;
    }
    let mut out = v.clone();
    for i in 0..n {
        for j in i + 1..n {
            let k = condensed_index(n, i, j);
            if !v[k].is_nan() {
                continue;
            }
            let mut best = f64::INFINITY;
            for h in 0..n {
                if h == i || h == j {
                    continue;
                }
                let a = v[condensed_index(n, i, h)];
                let b = v[condensed_index(n, h, j)];
                if a.is_nan() || b.is_nan() {
                    continue;
                }
                best = best.min(a.max(b));
            }
            out[k] = if best.is_finite() { best } else { max_known };
        }
    }
    (out, has_known)
}
