//! Point-level refinement of a segmentation against observed pairs only.

use kinetree_core::{DissimilarityMatrix, MIN_BODY_POINTS, Segmentation};

/// Mean dissimilarity from `point` to each body's other points over the *observed* pairs,
/// with the number of pairs behind it (`(NaN, 0)` for a body with none).
pub(crate) fn body_means(
    m: &DissimilarityMatrix,
    labels: &[Option<usize>],
    n_bodies: usize,
    point: usize,
) -> Vec<(f64, usize)> {
    let mut sum = vec![0.0; n_bodies];
    let mut cnt = vec![0usize; n_bodies];
    for (j, l) in labels.iter().enumerate() {
        let Some(b) = *l else { continue };
        if j == point {
            continue;
        }
        if let Some(d) = m.get(point, j) {
            sum[b] += d;
            cnt[b] += 1;
        }
    }
    sum.iter()
        .zip(&cnt)
        .map(|(s, &c)| (if c > 0 { s / c as f64 } else { f64::NAN }, c))
        .collect()
}

/// Moves every point to the body it fits best, judged on its *observed* pairs only.
///
/// A clusterer works on a matrix whose unknown pairs were inferred; a point seen rarely can
/// then be merged into a body on inferred values alone, and one wrong point spoils that
/// body's poses. Here each point's score for body `B` is the mean dissimilarity to `B`'s
/// other points over the pairs actually observed (at least `min_pairs` of them). The point
/// joins the body with the lowest score when that score is at most `cut` (the measure's
/// rigid/non-rigid boundary), and is discarded when no body qualifies. Two rounds; bodies
/// left with fewer than three points are discarded.
///
/// Complexity: O(N^2) per round.
pub fn reassign_points(
    m: &DissimilarityMatrix,
    seg: &Segmentation,
    cut: f64,
    min_pairs: usize,
) -> Segmentation {
    let mut labels: Vec<Option<usize>> = seg.labels().to_vec();
    let nb = seg.n_bodies();
    for _ in 0..2 {
        let mut next = labels.clone();
        for (i, slot) in next.iter_mut().enumerate() {
            let means = body_means(m, &labels, nb, i);
            let best = means
                .iter()
                .enumerate()
                .filter(|(_, (_, c))| *c >= min_pairs)
                .map(|(b, (mean, _))| (*mean, b))
                .min_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            *slot = match best {
                Some((score, b)) if score <= cut => Some(b),
                _ if labels[i].is_some() => None,
                _ => labels[i],
            };
        }
        labels = next;
    }
    let mut out = Segmentation::from_raw(&labels, MIN_BODY_POINTS);
    let mut groups = seg.discarded_groups.clone();
    groups.append(&mut out.discarded_groups);
    let moved: Vec<usize> = (0..labels.len())
        .filter(|&i| seg.labels()[i].is_some() && out.labels()[i].is_none())
        .collect();
    if !moved.is_empty() {
        groups.push(moved);
    }
    groups.sort();
    groups.dedup();
    out.discarded_groups = groups;
    out
}
