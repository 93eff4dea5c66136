//! Clustering time at N points: 30 bodies, q-like dissimilarities (about 0.5 inside a body,
//! about 0.99 between bodies), from a fixed seed; `unknown` is the fraction of pairs never
//! seen together (NaN). Run with `cargo bench -p kinetree-clustering`.
//! `hierarchical_average_by_frames` gives the linkage each pair's frames seen together (2 to
//! 301, from the pair's indices), which runs the weighted nearest-neighbour chain; the other
//! hierarchical bench has no frames and runs kodama.

use kinetree_clustering::{
    Dbscan, DbscanParams, Hierarchical, HierarchicalParams, KMeansImpl, Spectral, SpectralDbscan,
    SpectralDbscanParams, SpectralGmm, SpectralGmmParams, SpectralParams,
};
use kinetree_core::{Clustering, ClusteringInput, DissimilarityMatrix};

fn main() {
    divan::main();
}

fn matrix(n: usize, unknown: f64) -> DissimilarityMatrix {
    let mut state: u64 = 0x2545_F491_4F6C_DD1D ^ n as u64;
    let mut next = move || {
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut values = Vec::with_capacity(n * (n - 1) / 2);
    for i in 0..n {
        for j in i + 1..n {
            let v = if next() < unknown {
                f64::NAN
            } else if i % 30 == j % 30 {
                next()
            } else {
                0.98 + 0.02 * next()
            };
            values.push(v);
        }
    }
    DissimilarityMatrix {
        n_points: n,
        values,
        suggested_cut: 0.8,
        measure: "f_test".into(),
    }
}

/// Frames seen together for every pair over `n` points, 2 to 301.
fn frames(n: usize) -> Vec<u32> {
    let mut out = Vec::with_capacity(n * (n - 1) / 2);
    for i in 0..n {
        for j in i + 1..n {
            out.push(2 + ((i * 7919 + j * 104_729) % 300) as u32);
        }
    }
    out
}

/// Times `stage` on the matrix for `(n, unknown)`, with each pair's frames seen together when
/// `with_frames`; the clustering must succeed.
fn time_stage_with(
    bencher: divan::Bencher,
    stage: &dyn Clustering,
    (n, unknown): (usize, f64),
    with_frames: bool,
) {
    let m = matrix(n, unknown);
    let f = with_frames.then(|| frames(n));
    bencher.bench(|| {
        stage
            .cluster(&ClusteringInput {
                dissimilarity: &m,
                seed: 0,
                pair_frames: f.as_deref(),
            })
            .expect("clusters")
    });
}

/// Times `stage` on the matrix for `(n, unknown)` with no frame counts.
fn time_stage(bencher: divan::Bencher, stage: &dyn Clustering, args: (usize, f64)) {
    time_stage_with(bencher, stage, args, false);
}

#[divan::bench(args = [(1000usize, 0.0f64), (3000, 0.0), (3000, 0.1)], sample_count = 3, sample_size = 1)]
fn hierarchical_average(bencher: divan::Bencher, &args: &(usize, f64)) {
    let stage = Hierarchical::new(HierarchicalParams::default()).expect("params");
    time_stage(bencher, &stage, args);
}

#[divan::bench(args = [(1000usize, 0.0f64), (3000, 0.0), (3000, 0.1)], sample_count = 3, sample_size = 1)]
fn hierarchical_average_by_frames(bencher: divan::Bencher, &args: &(usize, f64)) {
    let stage = Hierarchical::new(HierarchicalParams::default()).expect("params");
    time_stage_with(bencher, &stage, args, true);
}

#[divan::bench(args = [(1000usize, 0.0f64), (3000, 0.0), (3000, 0.1)], sample_count = 3, sample_size = 1)]
fn dbscan(bencher: divan::Bencher, &args: &(usize, f64)) {
    let stage = Dbscan::new(DbscanParams::default()).expect("params");
    time_stage(bencher, &stage, args);
}

#[divan::bench(args = [(1000usize, 0.0f64), (3000, 0.0), (3000, 0.1)], sample_count = 3, sample_size = 1)]
fn spectral(bencher: divan::Bencher, &args: &(usize, f64)) {
    let stage = Spectral::new(SpectralParams::default()).expect("params");
    time_stage(bencher, &stage, args);
}

/// The spectral stage with linfa-clustering's k-means in place of kinetree's.
#[divan::bench(args = [(1000usize, 0.0f64), (3000, 0.0), (3000, 0.1)], sample_count = 3, sample_size = 1)]
fn spectral_linfa_kmeans(bencher: divan::Bencher, &args: &(usize, f64)) {
    let stage = Spectral::new(SpectralParams {
        kmeans: KMeansImpl::Linfa,
        ..SpectralParams::default()
    })
    .expect("params");
    time_stage(bencher, &stage, args);
}

#[divan::bench(args = [(1000usize, 0.0f64), (3000, 0.0), (3000, 0.1)], sample_count = 3, sample_size = 1)]
fn spectral_gmm(bencher: divan::Bencher, &args: &(usize, f64)) {
    let stage = SpectralGmm::new(SpectralGmmParams::default()).expect("params");
    time_stage(bencher, &stage, args);
}

#[divan::bench(args = [(1000usize, 0.0f64), (3000, 0.0), (3000, 0.1)], sample_count = 3, sample_size = 1)]
fn spectral_dbscan(bencher: divan::Bencher, &args: &(usize, f64)) {
    let stage = SpectralDbscan::new(SpectralDbscanParams::default()).expect("params");
    time_stage(bencher, &stage, args);
}
