//! The pairwise distance statistics kernel.

use kinetree_core::{PairStats, Tracks, n_pairs};

/// Count, mean and sample variance of every pair's distance over the frames in which both
/// points are visible (the paper's eq. 1-3).
///
/// Numerically stable: each pair's sums are taken about a shift (its first observed distance),
/// so a 1 m distance with 0.1 mm noise keeps its variance. Memory is O(N^2) whatever `T` is.
///
/// Complexity: O(T N^2) time.
pub fn pair_stats(tracks: &Tracks) -> PairStats {
    let n = tracks.n_points();
    let m = n_pairs(n);
    let mut count = vec![0u32; m];
    let mut shift = vec![0.0f64; m];
    let mut s1 = vec![0.0f64; m];
    let mut s2 = vec![0.0f64; m];
    let mut visible: Vec<(usize, [f64; 3])> = Vec::with_capacity(n);
    for t in 0..tracks.n_frames() {
        visible.clear();
        for (i, p) in tracks.frame_raw(t).chunks_exact(3).enumerate() {
            if !p[0].is_nan() {
                visible.push((i, [p[0], p[1], p[2]]));
            }
        }
        for (a, &(i, pi)) in visible.iter().enumerate() {
            // Pairs (i, j) with j > i are contiguous in the condensed layout.
            let row = i * n - i * (i + 1) / 2;
            for &(j, pj) in &visible[a + 1..] {
                let k = row + j - i - 1;
                let dx = pi[0] - pj[0];
                let dy = pi[1] - pj[1];
                let dz = pi[2] - pj[2];
                let d = (dx * dx + dy * dy + dz * dz).sqrt();
                if count[k] == 0 {
                    shift[k] = d;
                }
                let e = d - shift[k];
                count[k] += 1;
                s1[k] += e;
                s2[k] += e * e;
            }
        }
    }
    let mut mean_m = vec![f64::NAN; m];
    let mut var_m2 = vec![f64::NAN; m];
    for k in 0..m {
        let c = f64::from(count[k]);
        if count[k] >= 1 {
            mean_m[k] = shift[k] + s1[k] / c;
        }
        if count[k] >= 2 {
            var_m2[k] = ((s2[k] - s1[k] * s1[k] / c) / (c - 1.0)).max(0.0);
        }
    }
    PairStats {
        n_points: n,
        count,
        mean_m,
        var_m2,
    }
}
