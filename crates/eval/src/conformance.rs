//! Conformance checks any stage implementation (ours or a user's) can be run through.
//!
//! Each function runs the stage on a small simulated mechanism and returns every contract
//! violation it finds as a string (an empty list means the stage conforms). A panic inside the
//! stage is caught and reported as a violation.

use kinetree_core::{
    BodyPoses, Clustering, ClusteringInput, Dissimilarity, DissimilarityInput, DissimilarityMatrix,
    DofInput, DofTester, PairStats, PoseEstimator, PoseInput, Segmentation, Tracks, n_pairs,
};
use kinetree_synth::{paper_arm, simulate};
use std::panic::{AssertUnwindSafe, catch_unwind};

/// The fixture every check uses: the paper arm (23 points, 3 bodies) from a fixed seed, its
/// true segmentation, and a point permutation.
#[derive(Debug, Clone)]
pub struct Fixture {
    /// Tracks of the paper arm, 1 mm noise.
    pub tracks: Tracks,
    /// Body of each point (the truth).
    pub truth: Vec<usize>,
    /// `permutation[k]` is the original index of point `k` in the permuted tracks.
    pub permutation: Vec<usize>,
    /// The tracks with points in `permutation` order.
    pub permuted: Tracks,
}

impl Fixture {
    /// Builds the fixture.
    ///
    /// # Panics
    /// Never: the paper arm always simulates (checked by the synth tests).
    pub fn new() -> Self {
        let data =
            simulate(&paper_arm(11)).unwrap_or_else(|e| unreachable!("paper arm simulates: {e}"));
        let n = data.tracks.n_points();
        let permutation: Vec<usize> = (0..n).map(|k| (k * 7 + 3) % n).collect();
        let frames: Vec<Vec<_>> = (0..data.tracks.n_frames())
            .map(|t| permutation.iter().map(|&i| data.tracks.get(t, i)).collect())
            .collect();
        let permuted =
            Tracks::from_points(&frames).unwrap_or_else(|e| unreachable!("permuted tracks: {e}"));
        Self {
            tracks: data.tracks,
            truth: data.truth.point_body,
            permutation,
            permuted,
        }
    }

    /// The true segmentation.
    pub fn segmentation(&self) -> Segmentation {
        let raw: Vec<Option<usize>> = self.truth.iter().map(|&b| Some(b)).collect();
        Segmentation::from_raw(&raw, 1)
    }
}

impl Default for Fixture {
    fn default() -> Self {
        Self::new()
    }
}

fn guarded<T>(what: &str, violations: &mut Vec<String>, f: impl FnOnce() -> T) -> Option<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(v) => Some(v),
        Err(_) => {
            violations.push(format!("{what}: panicked"));
            None
        }
    }
}

fn same_partition(a: &[Option<usize>], b: &[Option<usize>]) -> bool {
    a.len() == b.len()
        && (0..a.len()).all(|i| {
            (0..a.len())
                .all(|j| (a[i].is_some() && a[i] == a[j]) == (b[i].is_some() && b[i] == b[j]))
        })
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Checks a [`Dissimilarity`]: one value per pair, NaN exactly where a pair has fewer than
/// two joint observations, no panic and an error for a NaN or non-positive noise level,
/// deterministic, and equivariant under a permutation of the points.
pub fn check_dissimilarity(
    stage: &dyn Dissimilarity,
    stats_of: &dyn Fn(&Tracks) -> PairStats,
) -> Vec<String> {
    let fx = Fixture::new();
    let mut v = Vec::new();
    let stats = stats_of(&fx.tracks);
    let run = |tracks: &Tracks, stats: &PairStats, sigma: f64| {
        stage.compute(&DissimilarityInput {
            tracks,
            stats,
            noise_sigma_m: sigma,
        })
    };
    let Some(Ok(m)) = guarded("compute", &mut v, || run(&fx.tracks, &stats, 0.001)) else {
        v.push("compute on the fixture failed".into());
        return v;
    };
    if m.values.len() != n_pairs(fx.tracks.n_points()) {
        v.push(format!(
            "{} values for {} pairs",
            m.values.len(),
            n_pairs(fx.tracks.n_points())
        ));
    }
    for (k, (val, c)) in m.values.iter().zip(&stats.count).enumerate() {
        if val.is_nan() != (*c < 2) {
            v.push(format!("pair {k}: value {val} with {c} joint observations"));
            break;
        }
    }
    for sigma in [f64::NAN, 0.0, -1.0] {
        if let Some(r) = guarded("compute with a bad noise level", &mut v, || {
            run(&fx.tracks, &stats, sigma)
        }) && r.is_ok()
        {
            v.push(format!("noise level {sigma} accepted"));
        }
    }
    if let Some(Ok(again)) = guarded("compute again", &mut v, || run(&fx.tracks, &stats, 0.001))
        && bits(&again.values) != bits(&m.values)
    {
        v.push("not deterministic".into());
    }
    let pstats = stats_of(&fx.permuted);
    if let Some(Ok(pm)) = guarded("compute on permuted points", &mut v, || {
        run(&fx.permuted, &pstats, 0.001)
    }) {
        let p = &fx.permutation;
        let n = p.len();
        'outer: for a in 0..n {
            for b in a + 1..n {
                let (x, y) = (pm.get(a, b), m.get(p[a], p[b]));
                let same = match (x, y) {
                    (Some(x), Some(y)) => (x - y).abs() <= 1e-9 * x.abs().max(1.0),
                    (None, None) => true,
                    _ => false,
                };
                if !same {
                    v.push(format!(
                        "permuting the points changed pair ({a}, {b}): {x:?} vs {y:?}"
                    ));
                    break 'outer;
                }
            }
        }
    }
    v
}

/// Checks a [`Clustering`]: one label per point, no panic on NaN or a wrong-sized matrix,
/// the same seed gives the same labels, and permuting the points permutes the partition.
/// `matrix_of` turns tracks into the dissimilarity the clusterer expects.
pub fn check_clustering(
    stage: &dyn Clustering,
    matrix_of: &dyn Fn(&Tracks) -> DissimilarityMatrix,
) -> Vec<String> {
    let fx = Fixture::new();
    let mut v = Vec::new();
    let m = matrix_of(&fx.tracks);
    let run = |m: &DissimilarityMatrix, seed: u64| {
        stage.cluster(&ClusteringInput {
            dissimilarity: m,
            seed,
            pair_frames: None,
        })
    };
    let Some(Ok(seg)) = guarded("cluster", &mut v, || run(&m, 7)) else {
        v.push("cluster on the fixture failed".into());
        return v;
    };
    if seg.n_points() != fx.tracks.n_points() {
        v.push(format!(
            "{} labels for {} points",
            seg.n_points(),
            fx.tracks.n_points()
        ));
    }
    if let Some(Ok(again)) = guarded("cluster again", &mut v, || run(&m, 7))
        && again != seg
    {
        v.push("same seed, different labels".into());
    }
    let mut nan = m.clone();
    for x in nan.values.iter_mut().step_by(5) {
        *x = f64::NAN;
    }
    guarded("cluster with NaN entries", &mut v, || run(&nan, 7));
    let mut short = m.clone();
    short.values.pop();
    if let Some(r) = guarded("cluster with a wrong-sized matrix", &mut v, || {
        run(&short, 7)
    }) && r.is_ok()
    {
        v.push("a matrix of the wrong size was accepted".into());
    }
    let pm = matrix_of(&fx.permuted);
    if let Some(Ok(pseg)) = guarded("cluster permuted", &mut v, || run(&pm, 7)) {
        let back: Vec<Option<usize>> = {
            let mut b = vec![None; fx.permutation.len()];
            for (k, &orig) in fx.permutation.iter().enumerate() {
                b[orig] = pseg.body_of(k);
            }
            b
        };
        if !same_partition(&back, seg.labels()) {
            v.push("permuting the points changed the partition".into());
        }
    }
    v
}

/// Checks a [`PoseEstimator`]: one track per body, with one pose slot per frame; on the true
/// segmentation the poses reproduce the observations to within a few noise std-devs; an error
/// (not a panic) for a segmentation of the wrong size or a NaN noise level; deterministic.
pub fn check_pose(stage: &dyn PoseEstimator) -> Vec<String> {
    let fx = Fixture::new();
    let mut v = Vec::new();
    let seg = fx.segmentation();
    let run = |seg: &Segmentation, sigma: f64| {
        stage.estimate(&PoseInput {
            tracks: &fx.tracks,
            segmentation: seg,
            noise_sigma_m: sigma,
        })
    };
    let Some(Ok(poses)) = guarded("estimate", &mut v, || run(&seg, 0.001)) else {
        v.push("estimate on the fixture failed".into());
        return v;
    };
    if poses.bodies.len() != seg.n_bodies() {
        v.push(format!(
            "{} tracks for {} bodies",
            poses.bodies.len(),
            seg.n_bodies()
        ));
    }
    for (b, track) in poses.bodies.iter().enumerate() {
        if track.cam_from_body.len() != fx.tracks.n_frames() {
            v.push(format!(
                "body {b}: {} pose slots for {} frames",
                track.cam_from_body.len(),
                fx.tracks.n_frames()
            ));
        }
        for (t, pose) in track.cam_from_body.iter().enumerate() {
            let Some(pose) = pose else { continue };
            for (k, &i) in track.points.iter().enumerate() {
                if let (Some(obs), Some(s)) = (fx.tracks.get(t, i), track.shape.get(k))
                    && (pose * s - obs).norm() > 0.01
                {
                    v.push(format!(
                        "body {b} frame {t} point {i}: pose misses the observation by {:.4} m",
                        (pose * s - obs).norm()
                    ));
                    return v;
                }
            }
        }
    }
    let wrong = Segmentation::from_raw(&[Some(0), Some(0), Some(0)], 1);
    if let Some(r) = guarded("estimate with a wrong-sized segmentation", &mut v, || {
        run(&wrong, 0.001)
    }) && r.is_ok()
    {
        v.push("a segmentation of the wrong size was accepted".into());
    }
    if let Some(r) = guarded("estimate with a NaN noise level", &mut v, || {
        run(&seg, f64::NAN)
    }) && r.is_ok()
    {
        v.push("a NaN noise level was accepted".into());
    }
    if let Some(Ok(again)) = guarded("estimate again", &mut v, || run(&seg, 0.001))
        && again != poses
    {
        v.push("not deterministic".into());
    }
    v
}

/// Checks a [`DofTester`] on poses from `poses_of` (the fixture's true segmentation): the
/// static base shows no DoF to the camera, link 1 one DoF to the base, an error (not a panic)
/// for an invalid pair or a NaN noise level, deterministic.
pub fn check_dof(
    stage: &dyn DofTester,
    poses_of: &dyn Fn(&Tracks, &Segmentation) -> BodyPoses,
) -> Vec<String> {
    let fx = Fixture::new();
    let mut v = Vec::new();
    let poses = poses_of(&fx.tracks, &fx.segmentation());
    let run = |sigma: f64, a: Option<usize>, b: usize| {
        stage.test_pair(
            &DofInput {
                poses: &poses,
                noise_sigma_m: sigma,
            },
            a,
            b,
        )
    };
    match guarded("test base", &mut v, || run(0.001, None, 0)) {
        Some(Ok(p)) if p.dof != 0 => v.push(format!("static base has {} DoF to the camera", p.dof)),
        Some(Err(e)) => v.push(format!("test base failed: {e}")),
        _ => {}
    }
    match guarded("test link 1", &mut v, || run(0.001, Some(0), 1)) {
        Some(Ok(p)) if p.dof != 1 => v.push(format!("link 1 has {} DoF to the base", p.dof)),
        Some(Err(e)) => v.push(format!("test link 1 failed: {e}")),
        _ => {}
    }
    for (what, sigma, a, b) in [
        ("NaN noise level", f64::NAN, Some(0), 1),
        ("pair of a body with itself", 0.001, Some(1), 1),
        ("body out of range", 0.001, None, 99),
    ] {
        if let Some(r) = guarded(what, &mut v, || run(sigma, a, b))
            && r.is_ok()
        {
            v.push(format!("{what} accepted"));
        }
    }
    if let (Some(Ok(x)), Some(Ok(y))) = (
        guarded("test again", &mut v, || run(0.001, Some(1), 2)),
        guarded("test again", &mut v, || run(0.001, Some(1), 2)),
    ) && x != y
    {
        v.push("not deterministic".into());
    }
    v
}
