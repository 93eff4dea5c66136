//! Average linkage with a weight per pair, by the nearest-neighbour chain, and kodama's
//! linkages in the same form.

/// One merge of the weighted average linkage: the clusters holding points `a` and `b` join at
/// height `height`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Merge {
    pub a: usize,
    pub b: usize,
    pub height: f64,
}

/// Average linkage in which each pair counts with its weight: the dissimilarity of two groups
/// is `sum w_ij d_ij / sum w_ij` over their cross pairs. With equal weights this is UPGMA.
/// The update `d(A + B, C) = (W_AC d_AC + W_BC d_BC) / (W_AC + W_BC)`, with `W` the summed
/// weights, lies between `d_AC` and `d_BC`, so the linkage is reducible and the
/// nearest-neighbour chain finds the same merges as the greedy closest-pair loop (Müllner
/// 2011, Sec. 3) in O(k^2) time and memory. Pairs of zero total weight fall back to the
/// unweighted mean.
///
/// Returns the `k - 1` merges sorted by height (ties in the order found), each naming one
/// point of either group; union-find over them in that order rebuilds the dendrogram.
pub(crate) fn weighted_average_linkage(values: &[f64], weights: &[f64], k: usize) -> Vec<Merge> {
    // Dense symmetric copies (16 k^2 bytes): the chain reads one group's row per step, which
    // in the condensed triangle is a walk down a column with a cache miss per pair.
    let mut d = vec![0.0; k * k];
    let mut w = vec![0.0; k * k];
    let mut c = 0;
    for i in 0..k {
        for j in i + 1..k {
            d[i * k + j] = values[c];
            d[j * k + i] = values[c];
            w[i * k + j] = weights[c];
            w[j * k + i] = weights[c];
            c += 1;
        }
    }
    // The groups still open, by their slot, in increasing order.
    let mut alive: Vec<usize> = (0..k).collect();
    let mut merges = Vec::with_capacity(k.saturating_sub(1));
    let mut chain: Vec<usize> = Vec::new();
    while alive.len() > 1 {
        if chain.is_empty() {
            chain.push(alive[0]);
        }
        let top = chain[chain.len() - 1];
        let prev = (chain.len() >= 2).then(|| chain[chain.len() - 2]);
        // The nearest open neighbour of `top`; a tie keeps the chain's previous element so
        // that the chain ends in a reciprocal pair instead of cycling.
        let row = &d[top * k..(top + 1) * k];
        let mut best = (f64::INFINITY, usize::MAX);
        if let Some(p) = prev {
            best = (row[p], p);
        }
        for &c in alive.iter().filter(|&&c| c != top) {
            let v = row[c];
            if v < best.0 || best.1 == usize::MAX {
                best = (v, c);
            }
        }
        let (height, near) = best;
        if Some(near) != prev {
            chain.push(near);
            continue;
        }
        chain.truncate(chain.len() - 2);
        // Merge `near` into `top`'s slot.
        let (keep, gone) = (top.min(near), top.max(near));
        for &c in alive.iter().filter(|&&c| c != keep && c != gone) {
            let (ik, ig) = (keep * k + c, gone * k + c);
            let (wk, wg) = (w[ik], w[ig]);
            let value = if wk + wg > 0.0 {
                (wk * d[ik] + wg * d[ig]) / (wk + wg)
            } else {
                0.5 * (d[ik] + d[ig])
            };
            d[ik] = value;
            d[c * k + keep] = value;
            w[ik] = wk + wg;
            w[c * k + keep] = wk + wg;
        }
        alive.retain(|&c| c != gone);
        merges.push(Merge {
            a: keep,
            b: gone,
            height,
        });
    }
    merges.sort_by(|x, y| x.height.total_cmp(&y.height));
    merges
}

/// kodama's dendrogram of the condensed `values` (which it overwrites) by `method`, as merges
/// naming one point of either group, in kodama's order (by height).
pub(crate) fn kodama_linkage(values: &mut [f64], k: usize, method: kodama::Method) -> Vec<Merge> {
    let dendrogram = kodama::linkage(values, k, method);
    // kodama names a merged group `k + step`; carry one point of each group.
    let mut rep: Vec<usize> = (0..k).collect();
    dendrogram
        .steps()
        .iter()
        .map(|s| {
            let (a, b) = (rep[s.cluster1], rep[s.cluster2]);
            rep.push(a);
            Merge {
                a,
                b,
                height: s.dissimilarity,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinetree_core::{condensed_index, n_pairs};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The groups after the merges up to and including height `cut`, as a label per point
    /// (the smallest member of each group).
    fn groups_at(merges: &[Merge], k: usize, cut: f64) -> Vec<usize> {
        let mut label: Vec<usize> = (0..k).collect();
        for m in merges.iter().take_while(|m| m.height <= cut) {
            let (la, lb) = (label[m.a], label[m.b]);
            let keep = la.min(lb);
            for l in &mut label {
                if *l == la || *l == lb {
                    *l = keep;
                }
            }
        }
        label
    }

    /// The closest pair of groups merged one at a time, their weighted mean taken from the
    /// points' own pairs: the definition, in O(k^4).
    fn by_definition(d: &[f64], w: &[f64], k: usize) -> Vec<f64> {
        let mut groups: Vec<Vec<usize>> = (0..k).map(|i| vec![i]).collect();
        let mut heights = Vec::new();
        while groups.len() > 1 {
            let mut best = (f64::INFINITY, 0, 0);
            for x in 0..groups.len() {
                for y in x + 1..groups.len() {
                    let (mut s, mut sw) = (0.0, 0.0);
                    for &i in &groups[x] {
                        for &j in &groups[y] {
                            let c = condensed_index(k, i, j);
                            s += w[c] * d[c];
                            sw += w[c];
                        }
                    }
                    if s / sw < best.0 {
                        best = (s / sw, x, y);
                    }
                }
            }
            let moved = groups.remove(best.2);
            groups[best.1].extend(moved);
            heights.push(best.0);
        }
        heights
    }

    fn random_matrix(k: usize, seed: u64, weighted: bool) -> (Vec<f64>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d = (0..n_pairs(k)).map(|_| rng.random::<f64>()).collect();
        let w = (0..n_pairs(k))
            .map(|_| {
                if weighted {
                    f64::from(rng.random_range(1u32..300))
                } else {
                    1.0
                }
            })
            .collect();
        (d, w)
    }

    #[test]
    fn the_chain_finds_the_merges_of_the_definition() {
        for seed in 0..20 {
            let k = 3 + (seed as usize % 9);
            let (d, w) = random_matrix(k, seed, true);
            let merges = weighted_average_linkage(&d, &w, k);
            assert_eq!(merges.len(), k - 1);
            let expected = by_definition(&d, &w, k);
            for (m, e) in merges.iter().zip(&expected) {
                assert!(
                    (m.height - e).abs() < 1e-12,
                    "seed {seed}: {merges:?} {expected:?}"
                );
            }
        }
    }

    #[test]
    fn equal_weights_give_kodamas_average_linkage() {
        for seed in 0..10 {
            let k = 40;
            let (d, w) = random_matrix(k, 100 + seed, false);
            let merges = weighted_average_linkage(&d, &w, k);
            let mut condensed = d.clone();
            let kodama_merges = kodama_linkage(&mut condensed, k, kodama::Method::Average);
            for (m, s) in merges.iter().zip(&kodama_merges) {
                assert!((m.height - s.height).abs() < 1e-12);
            }
            // The same partition at every height between merges.
            for cut in [0.2, 0.4, 0.45, 0.5, 0.55, 0.6] {
                assert_eq!(
                    groups_at(&merges, k, cut),
                    groups_at(&kodama_merges, k, cut),
                    "seed {seed}, cut {cut}"
                );
            }
        }
    }
}
