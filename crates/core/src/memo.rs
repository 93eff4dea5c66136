//! Results of pure computations kept for the rest of one discovery.
//!
//! The model passes make the bodies and the model again after each points edit, and most of
//! their bodies come back with the same points and the same poses: the pair tests of those
//! bodies, and the hinges fitted to them, would be computed again from the same inputs. A
//! [`Memo`] keeps such results under a [`Fingerprint`] of everything they depend on, so a
//! repeated computation is a lookup that returns what the computation would have returned:
//! the discovery's output does not change with the memo on or off, nor with its budget.

use crate::BodyTrack;
use std::any::Any;
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use xxhash_rust::xxh3::Xxh3Default;

/// A 128-bit digest of a computation's inputs: XXH3 (xxhash-rust) over their bytes. Floats
/// enter by their bits, so two inputs share a digest only when they are equal bit for bit
/// (or, with odds of about `2^-128` a pair, by a collision).
#[derive(Clone)]
pub struct Fingerprint {
    hasher: Xxh3Default,
    /// Bytes not yet handed to the hasher: a track's fields arrive eight bytes at a time and
    /// are hashed in blocks.
    pending: Vec<u8>,
}

impl std::fmt::Debug for Fingerprint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fingerprint").finish_non_exhaustive()
    }
}

/// Bytes a [`Fingerprint`] gathers before it hashes them.
const BLOCK: usize = 4096;

impl Fingerprint {
    /// A digest for computations of the kind `kind` (a name that keeps different
    /// computations on the same inputs apart).
    pub fn new(kind: &str) -> Self {
        let mut f = Self {
            hasher: Xxh3Default::new(),
            pending: Vec::with_capacity(BLOCK + 8),
        };
        f.pending.extend_from_slice(kind.as_bytes());
        f.usize(kind.len());
        f
    }

    fn word(&mut self, bytes: [u8; 8]) -> &mut Self {
        self.pending.extend_from_slice(&bytes);
        if self.pending.len() >= BLOCK {
            self.hasher.update(&self.pending);
            self.pending.clear();
        }
        self
    }

    /// Adds a count or an index.
    pub fn usize(&mut self, x: usize) -> &mut Self {
        self.word((x as u64).to_le_bytes())
    }

    /// Adds an optional index (`None` apart from every index).
    pub fn option_usize(&mut self, x: Option<usize>) -> &mut Self {
        match x {
            Some(x) => self.usize(1).usize(x),
            None => self.usize(0),
        }
    }

    /// Adds a float by its bits.
    pub fn f64(&mut self, x: f64) -> &mut Self {
        self.word(x.to_bits().to_le_bytes())
    }

    /// Adds a list of indices, with its length.
    pub fn indices(&mut self, xs: &[usize]) -> &mut Self {
        self.usize(xs.len());
        for &x in xs {
            self.usize(x);
        }
        self
    }

    /// Adds every field of a body's track: its points, shape, reference frame, and each
    /// frame's pose and pose quality.
    pub fn track(&mut self, t: &BodyTrack) -> &mut Self {
        self.indices(&t.points);
        self.usize(t.shape.len());
        for (p, &placed) in t.shape.iter().zip(&t.placed) {
            self.f64(p.x).f64(p.y).f64(p.z).usize(usize::from(placed));
        }
        self.usize(t.reference_frame)
            .usize(t.frames_too_few_points)
            .usize(t.frames_degenerate)
            .usize(t.cam_from_body.len());
        for (pose, quality) in t.cam_from_body.iter().zip(&t.quality) {
            match pose {
                Some(x) => {
                    let (r, v) = (x.rotation.coords, x.translation.vector);
                    self.usize(1);
                    for c in r.iter().chain(v.iter()) {
                        self.f64(*c);
                    }
                }
                None => {
                    self.usize(0);
                }
            }
            match quality {
                Some(q) => {
                    self.usize(1).usize(q.n_visible);
                    self.f64(q.rms_residual_m)
                        .f64(q.rot_std_per_sigma)
                        .f64(q.trans_std_per_sigma);
                    for c in q
                        .rot_cov_per_sigma2
                        .iter()
                        .chain(q.origin_cov_per_sigma2.iter())
                    {
                        self.f64(*c);
                    }
                }
                None => {
                    self.usize(0);
                }
            }
        }
        self
    }

    /// The digest.
    pub fn finish(&self) -> u128 {
        let mut hasher = self.hasher.clone();
        hasher.update(&self.pending);
        hasher.digest128()
    }
}

/// Bytes a body's track holds, for a memo's budget.
pub fn track_bytes(t: &BodyTrack) -> usize {
    use std::mem::size_of;
    t.points.len() * size_of::<usize>()
        + t.shape.len() * size_of::<nalgebra::Point3<f64>>()
        + t.placed.len()
        + t.cam_from_body.len() * size_of::<Option<nalgebra::Isometry3<f64>>>()
        + t.quality.len() * size_of::<Option<crate::PoseQuality>>()
}

type Entry = Arc<dyn Any + Send + Sync>;

/// What a [`Memo`] holds and how often it answered.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MemoUsage {
    /// Results kept.
    pub kept: usize,
    /// Their bytes, as their callers counted them.
    pub bytes: usize,
    /// Lookups answered from a kept result.
    pub hits: usize,
    /// Lookups that computed their result.
    pub misses: usize,
}

impl MemoUsage {
    /// The sum of two usages (of two discoveries, say).
    pub fn plus(self, other: Self) -> Self {
        Self {
            kept: self.kept + other.kept,
            bytes: self.bytes + other.bytes,
            hits: self.hits + other.hits,
            misses: self.misses + other.misses,
        }
    }
}

/// Results kept under their inputs' [`Fingerprint`] for one discovery, up to a budget of
/// bytes: once it is spent, new results are computed and not kept. Safe to share between
/// threads; a result computed by two threads at once is computed twice, the same both times.
#[derive(Debug)]
pub struct Memo {
    budget: usize,
    kept: Mutex<(HashMap<u128, Entry>, usize)>,
    hits: AtomicUsize,
    misses: AtomicUsize,
}

impl Memo {
    /// A memo that keeps results of up to `budget` bytes in all (0 keeps none).
    pub fn new(budget: usize) -> Self {
        Self {
            budget,
            kept: Mutex::new((HashMap::new(), 0)),
            hits: AtomicUsize::new(0),
            misses: AtomicUsize::new(0),
        }
    }

    /// The result kept under `key`, if one of type `T` is.
    pub fn get<T: Clone + 'static>(&self, key: u128) -> Option<T> {
        let kept = self.kept.lock().ok()?;
        kept.0.get(&key)?.downcast_ref::<T>().cloned()
    }

    /// Keeps `value` under `key` when its `bytes` fit in what is left of the budget.
    pub fn put<T: Send + Sync + 'static>(&self, key: u128, value: T, bytes: usize) {
        let Ok(mut kept) = self.kept.lock() else {
            return;
        };
        let bytes = bytes.saturating_add(std::mem::size_of::<T>());
        if kept.1.saturating_add(bytes) > self.budget || kept.0.contains_key(&key) {
            return;
        }
        kept.0.insert(key, Arc::new(value));
        kept.1 += bytes;
    }

    /// The result kept under `key`, or `compute`'s, kept when it fits the budget (`bytes`
    /// gives its size).
    pub fn get_or_compute<T: Clone + Send + Sync + 'static>(
        &self,
        key: u128,
        compute: impl FnOnce() -> T,
        bytes: impl FnOnce(&T) -> usize,
    ) -> T {
        if let Some(v) = self.get::<T>(key) {
            self.hits.fetch_add(1, Ordering::Relaxed);
            return v;
        }
        self.misses.fetch_add(1, Ordering::Relaxed);
        let v = compute();
        let size = bytes(&v);
        self.put(key, v.clone(), size);
        v
    }

    /// What is kept and how often [`Memo::get_or_compute`] answered from it.
    pub fn usage(&self) -> MemoUsage {
        let (kept, bytes) = self.kept.lock().map_or((0, 0), |k| (k.0.len(), k.1));
        MemoUsage {
            kept,
            bytes,
            hits: self.hits.load(Ordering::Relaxed),
            misses: self.misses.load(Ordering::Relaxed),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Vector3};

    fn track(shift: f64) -> BodyTrack {
        BodyTrack {
            points: vec![0, 1, 2],
            shape: vec![
                Point3::origin(),
                Point3::new(0.1, 0.0, 0.0),
                Point3::new(0.0, 0.1, 0.0),
            ],
            placed: vec![true; 3],
            reference_frame: 0,
            cam_from_body: vec![
                Some(Isometry3::translation(shift, 0.0, 0.0)),
                None,
                Some(Isometry3::new(
                    Vector3::new(0.0, 0.2, 0.0),
                    Vector3::z() * 0.3,
                )),
            ],
            quality: vec![None; 3],
            frames_too_few_points: 1,
            frames_degenerate: 0,
        }
    }

    #[test]
    fn a_fingerprint_tells_tracks_apart_by_any_bit_of_a_pose() {
        let key = |t: &BodyTrack| Fingerprint::new("t").track(t).finish();
        let base = track(0.5);
        assert_eq!(key(&base), key(&track(0.5)));
        assert_ne!(
            key(&base),
            key(&track(f64::from_bits(0.5f64.to_bits() + 1)))
        );
        let mut unposed = track(0.5);
        unposed.cam_from_body[0] = None;
        assert_ne!(key(&base), key(&unposed));
        assert_ne!(
            Fingerprint::new("t").track(&base).finish(),
            Fingerprint::new("u").track(&base).finish()
        );
        assert_ne!(
            Fingerprint::new("t").option_usize(None).finish(),
            Fingerprint::new("t").option_usize(Some(0)).finish()
        );
    }

    #[test]
    fn a_memo_returns_what_it_kept_and_keeps_within_its_budget() {
        let memo = Memo::new(100);
        let mut calls = 0;
        let mut get = |key: u128, bytes: usize| {
            memo.get_or_compute(
                key,
                || {
                    calls += 1;
                    key as u64 * 10
                },
                |_| bytes,
            )
        };
        assert_eq!(get(1, 8), 10);
        assert_eq!(get(1, 8), 10);
        // Too large for what is left: computed each time, never kept.
        assert_eq!(get(2, 200), 20);
        assert_eq!(get(2, 200), 20);
        assert_eq!(calls, 3);
        let usage = memo.usage();
        assert_eq!((usage.kept, usage.hits, usage.misses), (1, 1, 3));
        // A result of another type under the same key is not returned.
        assert_eq!(memo.get::<f64>(1), None);
        assert_eq!(Memo::new(0).get_or_compute(3, || 7, |_| 0), 7);
        assert_eq!(Memo::new(0).usage(), MemoUsage::default());
    }
}
