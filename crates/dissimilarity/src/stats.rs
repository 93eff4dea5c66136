//! The pairwise distance statistics kernel.
//!
//! Frames are processed in chunks. Each chunk is laid out as structure-of-arrays (x, y, z and
//! a 0/1 visibility mask, occluded coordinates set to 0) so that the inner loop over one row
//! of the condensed triangle is branch-free and the compiler vectorises it. Each row's
//! accumulators stay in cache while the chunk's frames stream past. Rows are spread over
//! threads with rayon, and every row's results belong to one thread. Per-chunk count, mean
//! and M2 merge into the running totals with Chan's formula, so a recording can be fed in
//! pieces ([`PairStatsAccumulator`]).

use kinetree_core::{Error, PairStats, Result, Tracks, n_pairs};
use rayon::prelude::*;

/// Frames per chunk: 32 frames of 1000 points take 1 MB as structure-of-arrays, about one
/// core's L2.
const CHUNK_FRAMES: usize = 32;

/// Chunks of fewer points are handed to the threads together, up to about this many bytes
/// (1 MB, as one chunk of 1000 points): each thread then carries its rows through every
/// chunk of the group in turn, so a row merges its chunks in the same order as one chunk at
/// a time and the statistics keep every bit, while the threads are woken once a group
/// rather than once a chunk (with 100 points a chunk is 80 microseconds of work).
const GROUP_BYTES: usize = 1 << 20;

/// Running count, mean and sum of squared deviations of every pair's distance.
///
/// Feed frames with [`PairStatsAccumulator::add_frames`] in any number of calls, then take
/// [`PairStatsAccumulator::finish`]. Memory is O(N^2) whatever the number of frames.
#[derive(Debug, Clone)]
pub struct PairStatsAccumulator {
    n: usize,
    count: Vec<u32>,
    mean: Vec<f64>,
    m2: Vec<f64>,
}

/// One row of the running statistics (pairs `(i, j)`, `j > i`), owned by one thread.
struct RowMut<'a> {
    i: usize,
    count: &'a mut [u32],
    mean: &'a mut [f64],
    m2: &'a mut [f64],
}

/// One chunk of frames as structure-of-arrays.
struct Chunk {
    n: usize,
    frames: usize,
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
    mask: Vec<f64>,
}

impl Chunk {
    fn new(tracks: &Tracks, start: usize, end: usize) -> Self {
        let n = tracks.n_points();
        let frames = end - start;
        let mut c = Chunk {
            n,
            frames,
            x: vec![0.0; frames * n],
            y: vec![0.0; frames * n],
            z: vec![0.0; frames * n],
            mask: vec![0.0; frames * n],
        };
        for (f, t) in (start..end).enumerate() {
            for (i, p) in tracks.frame_raw(t).chunks_exact(3).enumerate() {
                if !p[0].is_nan() {
                    let k = f * n + i;
                    c.x[k] = p[0];
                    c.y[k] = p[1];
                    c.z[k] = p[2];
                    c.mask[k] = 1.0;
                }
            }
        }
        c
    }
}

/// Accumulates one row `i` (pairs `(i, j)`, `j > i`) of one chunk into `cnt`, `s1`, `s2`, with
/// the distances shifted by `shift` (one value per `j`).
fn accumulate_row(
    c: &Chunk,
    i: usize,
    shift: &[f64],
    cnt: &mut [f64],
    s1: &mut [f64],
    s2: &mut [f64],
) {
    let n = c.n;
    let len = n - i - 1;
    for f in 0..c.frames {
        let base = f * n;
        if c.mask[base + i] == 0.0 {
            continue;
        }
        let (px, py, pz) = (c.x[base + i], c.y[base + i], c.z[base + i]);
        let xs = &c.x[base + i + 1..base + n];
        let ys = &c.y[base + i + 1..base + n];
        let zs = &c.z[base + i + 1..base + n];
        let ms = &c.mask[base + i + 1..base + n];
        let (cnt, s1, s2, shift) = (
            &mut cnt[..len],
            &mut s1[..len],
            &mut s2[..len],
            &shift[..len],
        );
        for j in 0..len {
            let dx = xs[j] - px;
            let dy = ys[j] - py;
            let dz = zs[j] - pz;
            let d = (dx * dx + dy * dy + dz * dz).sqrt();
            let m = ms[j];
            let e = (d - shift[j]) * m;
            cnt[j] += m;
            s1[j] += e;
            s2[j] += e * e;
        }
    }
}

impl PairStatsAccumulator {
    /// An empty accumulator for `n_points` points.
    pub fn new(n_points: usize) -> Self {
        let m = n_pairs(n_points);
        Self {
            n: n_points,
            count: vec![0; m],
            mean: vec![0.0; m],
            m2: vec![0.0; m],
        }
    }

    /// Adds every frame of `tracks`.
    ///
    /// # Errors
    /// [`Error::Shape`] when `tracks` has a different number of points.
    pub fn add_frames(&mut self, tracks: &Tracks) -> Result<()> {
        if tracks.n_points() != self.n {
            return Err(Error::Shape {
                expected: format!("{} points", self.n),
                found: format!("{} points", tracks.n_points()),
            });
        }
        self.add_frames_unchecked(tracks);
        Ok(())
    }

    fn add_frames_unchecked(&mut self, tracks: &Tracks) {
        // Four arrays of f64 per point and frame.
        let chunk_bytes = CHUNK_FRAMES * self.n * 4 * std::mem::size_of::<f64>();
        self.add_frames_grouped(tracks, GROUP_BYTES / chunk_bytes.max(1));
    }

    /// Adds every frame of `tracks`, chunks handed to the threads `group` at a time.
    fn add_frames_grouped(&mut self, tracks: &Tracks, group: usize) {
        let group = group.max(1);
        let mut start = 0;
        while start < tracks.n_frames() {
            let mut chunks = Vec::with_capacity(group);
            while chunks.len() < group && start < tracks.n_frames() {
                let end = (start + CHUNK_FRAMES).min(tracks.n_frames());
                chunks.push(Chunk::new(tracks, start, end));
                start = end;
            }
            self.add_chunks(&chunks);
        }
    }

    /// Adds `chunks`, in order, to every row.
    fn add_chunks(&mut self, chunks: &[Chunk]) {
        let n = self.n;
        // Split the condensed arrays into rows so each thread owns whole rows.
        let mut rows: Vec<RowMut<'_>> = Vec::with_capacity(n);
        let (mut count, mut mean, mut m2) =
            (&mut self.count[..], &mut self.mean[..], &mut self.m2[..]);
        for i in 0..n.saturating_sub(1) {
            let len = n - i - 1;
            let (a, rest_c) = count.split_at_mut(len);
            let (b, rest_m) = mean.split_at_mut(len);
            let (d, rest_m2) = m2.split_at_mut(len);
            rows.push(RowMut {
                i,
                count: a,
                mean: b,
                m2: d,
            });
            count = rest_c;
            mean = rest_m;
            m2 = rest_m2;
        }
        rows.par_iter_mut().with_min_len(4).for_each(|row| {
            let RowMut { i, count, mean, m2 } = row;
            let i = *i;
            let len = n - i - 1;
            let mut shift = vec![0.0; len];
            let mut cnt = vec![0.0; len];
            let mut s1 = vec![0.0; len];
            let mut s2 = vec![0.0; len];
            for c in chunks {
                // Shift: the running mean where known, else this chunk's first joint distance.
                for j in 0..len {
                    shift[j] = if count[j] > 0 {
                        mean[j]
                    } else {
                        first_distance(c, i, i + 1 + j).unwrap_or(0.0)
                    };
                }
                cnt.fill(0.0);
                s1.fill(0.0);
                s2.fill(0.0);
                accumulate_row(c, i, &shift, &mut cnt, &mut s1, &mut s2);
                for j in 0..len {
                    if cnt[j] == 0.0 {
                        continue;
                    }
                    // Chan et al.: merge (n_a, mean_a, M2_a) with the chunk's (n_b, mean_b,
                    // M2_b).
                    let nb = cnt[j];
                    let mean_b = shift[j] + s1[j] / nb;
                    let m2_b = (s2[j] - s1[j] * s1[j] / nb).max(0.0);
                    let na = f64::from(count[j]);
                    let total = na + nb;
                    let delta = mean_b - mean[j];
                    mean[j] += delta * nb / total;
                    m2[j] += m2_b + delta * delta * na * nb / total;
                    count[j] += nb as u32;
                }
            }
        });
    }

    /// The statistics: count, mean distance (NaN without observations) and sample variance
    /// (NaN with fewer than two).
    pub fn finish(&self) -> PairStats {
        let m = self.count.len();
        let mut mean_m = vec![f64::NAN; m];
        let mut var_m2 = vec![f64::NAN; m];
        for k in 0..m {
            let c = self.count[k];
            if c >= 1 {
                mean_m[k] = self.mean[k];
            }
            if c >= 2 {
                var_m2[k] = self.m2[k] / f64::from(c - 1);
            }
        }
        PairStats {
            n_points: self.n,
            count: self.count.clone(),
            mean_m,
            var_m2,
        }
    }
}

/// Distance between `i` and `j` in the first frame of the chunk where both are visible.
fn first_distance(c: &Chunk, i: usize, j: usize) -> Option<f64> {
    (0..c.frames).find_map(|f| {
        let (a, b) = (f * c.n + i, f * c.n + j);
        (c.mask[a] > 0.0 && c.mask[b] > 0.0).then(|| {
            let dx = c.x[a] - c.x[b];
            let dy = c.y[a] - c.y[b];
            let dz = c.z[a] - c.z[b];
            (dx * dx + dy * dy + dz * dz).sqrt()
        })
    })
}

/// Count, mean and sample variance of every pair's distance over the frames in which both
/// points are visible (the paper's eq. 1-3).
///
/// Numerically stable: sums are taken about a per-pair shift (the running mean, or the first
/// joint distance) and chunks merge by Chan's formula, so a 1 m distance with 0.1 mm noise
/// keeps its variance. Memory O(N^2) whatever `T` is.
///
/// Complexity: O(T N^2) time, parallel over rows.
pub fn pair_stats(tracks: &Tracks) -> PairStats {
    let mut acc = PairStatsAccumulator::new(tracks.n_points());
    acc.add_frames_unchecked(tracks);
    acc.finish()
}

/// The straightforward kernel (one frame at a time, one pair at a time, Welford updates),
/// kept as the reference the fast kernel is tested and benchmarked against.
pub fn pair_stats_reference(tracks: &Tracks) -> PairStats {
    let n = tracks.n_points();
    let m = n_pairs(n);
    let mut count = vec![0u32; m];
    let mut mean = vec![0.0f64; m];
    let mut m2 = vec![0.0f64; m];
    for t in 0..tracks.n_frames() {
        for i in 0..n {
            let Some(p) = tracks.get(t, i) else { continue };
            for j in i + 1..n {
                let Some(q) = tracks.get(t, j) else { continue };
                let d = (p - q).norm();
                let k = kinetree_core::condensed_index(n, i, j);
                count[k] += 1;
                let delta = d - mean[k];
                mean[k] += delta / f64::from(count[k]);
                m2[k] += delta * (d - mean[k]);
            }
        }
    }
    let mean_m = mean
        .iter()
        .zip(&count)
        .map(|(&v, &c)| if c >= 1 { v } else { f64::NAN })
        .collect();
    let var_m2 = m2
        .iter()
        .zip(&count)
        .map(|(&v, &c)| {
            if c >= 2 {
                v / f64::from(c - 1)
            } else {
                f64::NAN
            }
        })
        .collect();
    PairStats {
        n_points: n,
        count,
        mean_m,
        var_m2,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wobbly_tracks(n_frames: usize, n_points: usize, hide_every: usize) -> Tracks {
        let mut xyz = Vec::with_capacity(n_frames * n_points * 3);
        for t in 0..n_frames {
            for i in 0..n_points {
                if hide_every > 0 && (t * 7 + i * 3) % hide_every == 0 {
                    xyz.extend_from_slice(&[f64::NAN; 3]);
                    continue;
                }
                let wobble = ((t * 31 + i * 17) % 13) as f64 * 1e-5;
                let swing = if i % 3 == 0 {
                    (t as f64 * 0.1).sin() * 0.2
                } else {
                    0.0
                };
                xyz.extend_from_slice(&[
                    i as f64 * 0.1 + wobble + swing,
                    1000.0 + wobble,
                    2.0 - wobble,
                ]);
            }
        }
        Tracks::new(n_frames, n_points, xyz).expect("valid")
    }

    #[test]
    fn fast_kernel_matches_reference_with_occlusion_and_many_chunks() {
        let tracks = wobbly_tracks(3 * CHUNK_FRAMES + 5, 23, 5);
        let fast = pair_stats(&tracks);
        let slow = pair_stats_reference(&tracks);
        assert_eq!(fast.count, slow.count);
        for k in 0..fast.count.len() {
            let (a, b) = (fast.var_m2[k], slow.var_m2[k]);
            if b.is_nan() {
                assert!(a.is_nan());
                continue;
            }
            assert!(
                (a - b).abs() <= 1e-9 * b.abs() + 1e-20,
                "pair {k}: {a} vs {b}"
            );
            assert!((fast.mean_m[k] - slow.mean_m[k]).abs() < 1e-12);
        }
    }

    #[test]
    fn chunks_handed_over_in_groups_give_the_same_bits_as_one_at_a_time() {
        // 23 points: a chunk is far under the group size, so several go together.
        let tracks = wobbly_tracks(7 * CHUNK_FRAMES + 3, 23, 5);
        let grouped = pair_stats(&tracks);
        let mut single = PairStatsAccumulator::new(23);
        single.add_frames_grouped(&tracks, 1);
        let single = single.finish();
        assert_eq!(grouped.count, single.count);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&grouped.mean_m), bits(&single.mean_m));
        assert_eq!(bits(&grouped.var_m2), bits(&single.var_m2));
    }

    #[test]
    fn streaming_in_pieces_equals_one_pass() {
        let tracks = wobbly_tracks(100, 12, 4);
        let whole = pair_stats(&tracks);
        let mut acc = PairStatsAccumulator::new(12);
        for (a, b) in [(0usize, 17usize), (17, 60), (60, 100)] {
            let part = tracks
                .select_frames(&(a..b).collect::<Vec<_>>())
                .expect("part");
            acc.add_frames(&part).expect("same points");
        }
        let other = wobbly_tracks(5, 4, 0);
        assert!(matches!(acc.add_frames(&other), Err(Error::Shape { .. })));
        let pieces = acc.finish();
        assert_eq!(pieces.count, whole.count);
        for k in 0..whole.count.len() {
            let (a, b) = (pieces.var_m2[k], whole.var_m2[k]);
            assert!(a.is_nan() && b.is_nan() || (a - b).abs() <= 1e-9 * b.abs() + 1e-20);
        }
    }
}
