//! Scenes for the clusterers' unit tests.

use kinetree_core::{DissimilarityMatrix, Segmentation, condensed_index, n_pairs};

/// Blocks of the given sizes with the true block of every point: like the F-test's `q`,
/// spread over 0-0.8 inside a block and 0.95-1 across (a deterministic jitter), every 11th
/// pair unknown.
pub(crate) fn blocks(sizes: &[usize]) -> (DissimilarityMatrix, Vec<usize>) {
    let truth: Vec<usize> = sizes
        .iter()
        .enumerate()
        .flat_map(|(b, &s)| std::iter::repeat_n(b, s))
        .collect();
    let n = truth.len();
    let mut values = vec![0.0; n_pairs(n)];
    for i in 0..n {
        for j in i + 1..n {
            let u = ((i * 31 + j * 17) % 13) as f64 / 12.0;
            let value = if truth[i] == truth[j] {
                0.8 * u
            } else {
                1.0 - 0.05 * u
            };
            values[condensed_index(n, i, j)] = if (i + j) % 11 == 0 { f64::NAN } else { value };
        }
    }
    let m = DissimilarityMatrix {
        n_points: n,
        values,
        suggested_cut: 0.8,
        measure: "test".into(),
    };
    (m, truth)
}

/// Whether `seg` assigns every point and groups them as `truth` does.
pub(crate) fn same_partition(seg: &Segmentation, truth: &[usize]) -> bool {
    let n = truth.len();
    (0..n).all(|i| {
        (0..n).all(|j| {
            let a = seg.body_of(i).zip(seg.body_of(j)).map(|(x, y)| x == y);
            a == Some(truth[i] == truth[j])
        })
    })
}
