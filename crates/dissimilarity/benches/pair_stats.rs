//! Pair-statistics throughput in pair-frames per second: `N (N - 1) / 2 * T`.
//!
//! Run with `cargo bench -p kinetree-dissimilarity`. Data: points on a unit cube with a
//! 0.1 mm jitter and 30 % of observations occluded (none for `kernel_all_visible`), from a
//! fixed seed. The counter counts every pair-frame, including those skipped because a point
//! is hidden.

use kinetree_core::Tracks;
use kinetree_dissimilarity::{pair_stats, pair_stats_reference};

fn main() {
    divan::main();
}

/// Deterministic test data (xorshift64* from a fixed seed).
fn tracks(n_points: usize, n_frames: usize, occluded: f64) -> Tracks {
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15 ^ ((n_points as u64) << 20) ^ n_frames as u64;
    let mut next = move || {
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    };
    let base: Vec<f64> = (0..n_points * 3).map(|_| next()).collect();
    let mut xyz = Vec::with_capacity(n_frames * n_points * 3);
    for _ in 0..n_frames {
        for i in 0..n_points {
            if next() < occluded {
                xyz.extend_from_slice(&[f64::NAN; 3]);
            } else {
                for c in 0..3 {
                    xyz.push(base[i * 3 + c] + (next() - 0.5) * 2e-4);
                }
            }
        }
    }
    Tracks::new(n_frames, n_points, xyz).expect("valid benchmark data")
}

fn pair_frames(n: usize, t: usize) -> u64 {
    (n * (n - 1) / 2 * t) as u64
}

const SIZES: &[(usize, usize)] = &[
    (100, 100),
    (100, 1000),
    (100, 10000),
    (1000, 100),
    (1000, 1000),
    (1000, 10000),
    (3000, 100),
    (3000, 1000),
    (3000, 10000),
];

#[divan::bench(args = SIZES, sample_count = 3, sample_size = 1)]
fn kernel(bencher: divan::Bencher, &(n, t): &(usize, usize)) {
    let data = tracks(n, t, 0.3);
    bencher
        .counter(divan::counter::ItemsCount::new(pair_frames(n, t)))
        .bench(|| pair_stats(divan::black_box(&data)));
}

#[divan::bench(args = [(1000usize, 1000usize)], sample_count = 3, sample_size = 1)]
fn kernel_all_visible(bencher: divan::Bencher, &(n, t): &(usize, usize)) {
    let data = tracks(n, t, 0.0);
    bencher
        .counter(divan::counter::ItemsCount::new(pair_frames(n, t)))
        .bench(|| pair_stats(divan::black_box(&data)));
}

#[divan::bench(args = [(1000usize, 1000usize)], sample_count = 3, sample_size = 1)]
fn reference_kernel(bencher: divan::Bencher, &(n, t): &(usize, usize)) {
    let data = tracks(n, t, 0.3);
    bencher
        .counter(divan::counter::ItemsCount::new(pair_frames(n, t)))
        .bench(|| pair_stats_reference(divan::black_box(&data)));
}
