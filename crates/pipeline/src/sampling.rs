//! Tracks with many points (a video point tracker's dense tracks): the discovery runs on a
//! sample of the points chosen to cover the scene, and every other point is then tested
//! against the bodies' poses and given to the body that explains it best.
//!
//! The pair statistics and the clustering cost `N^2` in time and memory; the sample bounds
//! them, and the assignment costs `N B T` (`B` bodies, `T` frames). The assignment's test
//! is the one that attaches points the clustering discarded
//! ([`kinetree_pose::point_fit`] within [`kinetree_pose::misfit_bound`]): a point's track
//! mapped into the body's frame must stay put within its noise and the poses' own.

use crate::run::{Discovery, Pipeline};
use crate::runner::DiscoveryObserver;
use kinetree_core::nalgebra::Point3;
use kinetree_core::{Error, Result, Tracks, Warning};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// `[pipeline.sampling]`: when and how a discovery runs on a sample of the points.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SamplingParams {
    /// Tracks with more points seen in any frame than this are discovered on a sample of
    /// this many (default 500), half chosen to cover the scene, preferring well-seen points,
    /// and half drawn at random (with the pipeline's `seed`): the pair statistics and the
    /// clustering, quadratic in the points, stay within what 500 points cost, and dense
    /// keypoints that turn in and out of view are clustered on their best-seen ones
    /// (`docs/decisions.md`, `[pipeline.sampling]`).
    pub max_points: usize,
    /// Most discoveries a run makes (default 2). After one, when at least
    /// `min_unexplained` points seen in three frames or more fit no body (a body too small
    /// or too briefly seen to be sampled well), up to `max_points / 2` of them join the
    /// sample and the discovery runs again; 1 never runs again.
    pub max_rounds: usize,
    /// Fewest points fitting no body that make another discovery (default 12: four bodies'
    /// worth of the fewest points a pose needs).
    pub min_unexplained: usize,
    /// A body explains a point when the point's misfit (`chi^2 / k`) is within the
    /// chi-square quantile at this many standard deviations (default 4, the attachment's)...
    pub misfit_z: f64,
    /// ... times this slack for the approximations in its predicted variance (default 2,
    /// the attachment's).
    pub misfit_slack: f64,
}

impl Default for SamplingParams {
    fn default() -> Self {
        Self {
            max_points: 500,
            max_rounds: 2,
            min_unexplained: 12,
            misfit_z: kinetree_pose::ATTACH_BOUND.0,
            misfit_slack: kinetree_pose::ATTACH_BOUND.1,
        }
    }
}

impl SamplingParams {
    /// Checks the ranges: `max_points` 20 to 10^7, `max_rounds` 1 to 10, `min_unexplained`
    /// at least 1, `misfit_z` in `(0, 100]`, `misfit_slack` in `[1, 100]`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming `pipeline.sampling.<key>`.
    pub fn validate(&self) -> Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count(
            "pipeline.sampling.max_points",
            self.max_points,
            20,
            10_000_000,
        )?;
        check_count("pipeline.sampling.max_rounds", self.max_rounds, 1, 10)?;
        check_count(
            "pipeline.sampling.min_unexplained",
            self.min_unexplained,
            1,
            usize::MAX,
        )?;
        check_within("pipeline.sampling.misfit_z", self.misfit_z, 1e-9, 100.0)?;
        check_within(
            "pipeline.sampling.misfit_slack",
            self.misfit_slack,
            1.0,
            100.0,
        )
    }
}

/// Each point's mean position over the frames that see it (`None` for a point never seen).
fn mean_positions(tracks: &Tracks) -> Vec<Option<[f64; 3]>> {
    let n = tracks.n_points();
    let mut sum = vec![[0.0f64; 3]; n];
    let mut count = vec![0usize; n];
    for t in 0..tracks.n_frames() {
        for (i, xyz) in tracks.frame_raw(t).chunks_exact(3).enumerate() {
            if xyz[0].is_nan() {
                continue;
            }
            for a in 0..3 {
                sum[i][a] += xyz[a];
            }
            count[i] += 1;
        }
    }
    sum.iter()
        .zip(&count)
        .map(|(s, &c)| (c > 0).then(|| s.map(|v| v / c as f64)))
        .collect()
}

/// Up to `k` of `candidates` (points with a mean position) chosen to cover space:
/// farthest-point sampling on the mean positions, each point's distance to the chosen ones
/// weighted by the fraction of frames that see it, so that among nearby points the
/// better-seen one is taken. Starts from the most seen point (the lowest index on ties);
/// ties go to the lowest index, so the choice is deterministic. Complexity `O(k n)`.
fn farthest_points(
    candidates: &[usize],
    means: &[Option<[f64; 3]>],
    visible: &[usize],
    k: usize,
) -> Vec<usize> {
    let pos: Vec<[f64; 3]> = candidates
        .iter()
        .map(|&i| means[i].unwrap_or([0.0; 3]))
        .collect();
    let weight: Vec<f64> = candidates.iter().map(|&i| visible[i] as f64).collect();
    let mut gap = vec![f64::INFINITY; candidates.len()];
    let mut taken = vec![false; candidates.len()];
    let mut out = Vec::with_capacity(k.min(candidates.len()));
    // The first pick: the largest weight, the first on ties.
    let mut next = (0..candidates.len()).fold(None::<usize>, |best, c| match best {
        Some(b) if weight[b] >= weight[c] => Some(b),
        _ => Some(c),
    });
    while let Some(c) = next {
        if out.len() == k {
            break;
        }
        taken[c] = true;
        out.push(candidates[c]);
        let p = pos[c];
        // On one thread: a few thousand products a pick, less than waking the pool costs.
        for (g, q) in gap.iter_mut().zip(&pos) {
            let d2 = (0..3).map(|a| (q[a] - p[a]).powi(2)).sum::<f64>();
            *g = g.min(d2);
        }
        next = (0..candidates.len())
            .filter(|&j| !taken[j])
            .map(|j| (j, gap[j] * weight[j] * weight[j]))
            .fold(None::<(usize, f64)>, |best, (j, s)| match best {
                Some((_, bs)) if bs >= s => best,
                _ => Some((j, s)),
            })
            .map(|(j, _)| j);
    }
    out
}

/// Up to `k` of `candidates`: half by [`farthest_points`] (every region of the scene,
/// however few points it has), the rest drawn uniformly with `seed` from the others (every
/// body in proportion to its points, however small it is in space). Ascending.
fn choose(
    candidates: &[usize],
    means: &[Option<[f64; 3]>],
    visible: &[usize],
    k: usize,
    seed: u64,
) -> Vec<usize> {
    use rand::SeedableRng;
    if candidates.len() <= k {
        return candidates.to_vec();
    }
    let mut out = farthest_points(candidates, means, visible, k / 2);
    out.sort_unstable();
    let others: Vec<usize> = candidates
        .iter()
        .copied()
        .filter(|i| out.binary_search(i).is_err())
        .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let drawn = rand::seq::index::sample(&mut rng, others.len(), k - out.len());
    out.extend(drawn.iter().map(|j| others[j]));
    out.sort_unstable();
    out
}

/// A point given to a body: `(point, body, place in the body frame)`.
type Assigned = (usize, usize, Point3<f64>);

/// Tests each of `points` against every body's poses of `d`; a point goes to the body
/// whose poses explain it ([`SamplingParams::misfit_z`], `misfit_slack`) with the least
/// misfit (the lowest body on ties). Returns the assigned points and those no body
/// explains, both ascending.
fn assign(
    tracks: &Tracks,
    d: &Discovery,
    points: &[usize],
    p: &SamplingParams,
) -> (Vec<Assigned>, Vec<usize>) {
    let sigma = d.model.noise.sigma_m;
    let nb = d.poses.bodies.len();
    let best: Vec<Option<(usize, Point3<f64>)>> = points
        .par_iter()
        .map(|&i| {
            let mut best: Option<(usize, f64, Point3<f64>)> = None;
            for b in 0..nb {
                let Some(f) = kinetree_pose::point_fit(tracks, &d.poses, b, i, sigma) else {
                    continue;
                };
                let fits =
                    f.misfit <= kinetree_pose::misfit_bound(f.dof, p.misfit_z, p.misfit_slack);
                if fits && best.is_none_or(|(_, m, _)| f.misfit < m) {
                    best = Some((b, f.misfit, f.local));
                }
            }
            best.map(|(b, _, local)| (b, local))
        })
        .collect();
    let mut assigned = Vec::new();
    let mut unexplained = Vec::new();
    for (&i, b) in points.iter().zip(best) {
        match b {
            Some((b, local)) => assigned.push((i, b, local)),
            None => unexplained.push(i),
        }
    }
    (assigned, unexplained)
}

/// The discovery of `tracks` (impossible samples already dropped; `warnings` the reader's
/// and the cleaning's) on a sample of its points, when it has more points seen than
/// [`SamplingParams::max_points`]; `None` when it has not, and the caller discovers on every
/// point.
///
/// # Errors
/// As the discovery's.
pub(crate) fn discover_sampled(
    pipeline: &Pipeline,
    tracks: &Tracks,
    warnings: &[Warning],
    observer: &dyn DiscoveryObserver,
) -> Result<Option<Discovery>> {
    let p = pipeline.sampling;
    let n = tracks.n_points();
    let visible: Vec<usize> = tracks.visible_counts();
    let seen: Vec<usize> = (0..n).filter(|&i| visible[i] > 0).collect();
    if seen.len() <= p.max_points {
        return Ok(None);
    }
    let means = mean_positions(tracks);
    let mut sample = choose(&seen, &means, &visible, p.max_points, pipeline.seed);
    let mut round = 1;
    loop {
        sample.sort_unstable();
        let sub = tracks.select_points(&sample)?;
        let d = pipeline.discover_clean(&sub, Vec::new(), observer)?;
        let d = spread_poses(d, &sample);
        observer.stage("assigning the other points");
        let mut in_sample = vec![false; n];
        sample.iter().for_each(|&i| in_sample[i] = true);
        let rest: Vec<usize> = seen.iter().copied().filter(|&i| !in_sample[i]).collect();
        let (assigned, unexplained) = assign(tracks, &d, &rest, &p);
        // Points seen in too few frames to be tested against a body cannot make a body of
        // their own either; only the others call for another discovery.
        let testable: Vec<usize> = unexplained
            .iter()
            .copied()
            .filter(|&i| visible[i] >= kinetree_pose::MIN_SHARED_FRAMES)
            .collect();
        if round < p.max_rounds && testable.len() >= p.min_unexplained {
            sample.extend(choose(
                &testable,
                &means,
                &visible,
                p.max_points / 2,
                pipeline.seed.wrapping_add(round as u64),
            ));
            round += 1;
            continue;
        }
        let duplicated = crate::run::duplicated_points(warnings);
        let never: Vec<Warning> = (0..n)
            .filter(|&i| visible[i] == 0 && !duplicated.contains(&i))
            .map(|point| Warning::PointNeverVisible { point })
            .collect();
        let before: Vec<Warning> = warnings.iter().cloned().chain(never).collect();
        return spread(
            pipeline,
            d,
            tracks,
            &sample,
            &assigned,
            unexplained,
            round,
            before,
        )
        .map(Some);
    }
}

/// `d`'s poses with each body's points in the whole tracks' numbering (`sample[k]` for the
/// sample's point `k`), so that the assignment can read the whole tracks through them.
fn spread_poses(mut d: Discovery, sample: &[usize]) -> Discovery {
    for body in &mut d.poses.bodies {
        body.points.iter_mut().for_each(|i| *i = sample[*i]);
    }
    d
}

/// The sample's discovery `d` (poses already in the whole numbering, [`spread_poses`])
/// spread over every point of `tracks`: the sample's points renumbered, the assigned points
/// added to their bodies (their places in the shapes), and the warnings and trace named in
/// the whole numbering after `before`, with a [`Warning::TracksSampled`].
#[allow(clippy::too_many_arguments)]
fn spread(
    pipeline: &Pipeline,
    mut d: Discovery,
    tracks: &Tracks,
    sample: &[usize],
    assigned: &[Assigned],
    unexplained: Vec<usize>,
    rounds: usize,
    before: Vec<Warning>,
) -> Result<Discovery> {
    let n = tracks.n_points();
    let extra: Vec<(usize, usize)> = assigned.iter().map(|&(i, b, _)| (i, b)).collect();
    d.segmentation = d
        .segmentation
        .on_points(n, sample, &extra)
        .ok_or_else(|| Error::Degenerate("the sample's segmentation does not fit it".into()))?;
    for (b, body) in d.poses.bodies.iter_mut().enumerate() {
        for &(i, _, local) in assigned.iter().filter(|a| a.1 == b) {
            body.points.push(i);
            body.shape.push(local);
            body.placed.push(true);
        }
        let mut order: Vec<usize> = (0..body.points.len()).collect();
        order.sort_by_key(|&k| body.points[k]);
        body.points = order.iter().map(|&k| body.points[k]).collect();
        body.shape = order.iter().map(|&k| body.shape[k]).collect();
        body.placed = order.iter().map(|&k| body.placed[k]).collect();
    }
    let m = &mut d.model;
    let whole = |k: usize| sample[k];
    m.n_points = n;
    m.point_labels = tracks.labels().map(<[String]>::to_vec);
    let mut point_body = vec![-1i64; n];
    for (k, &b) in m.point_body.iter().enumerate() {
        point_body[sample[k]] = b;
    }
    for &(i, b, _) in assigned {
        point_body[i] = b as i64;
    }
    m.point_body = point_body;
    for s in &mut m.shared_points {
        s[0] = whole(s[0]);
    }
    m.shared_points.sort_unstable();
    if m.point_confidence.len() == sample.len() {
        let mut confidence = vec![None; n];
        for (k, &c) in m.point_confidence.iter().enumerate() {
            confidence[sample[k]] = c;
        }
        m.point_confidence = confidence;
    }
    for body in &mut m.bodies {
        let mut entries: Vec<(usize, Option<[f64; 3]>)> = body
            .points
            .iter()
            .enumerate()
            .map(|(j, &k)| (whole(k), body.shape.get(j).copied().flatten()))
            .collect();
        for &(i, _, local) in assigned.iter().filter(|a| a.1 == body.id) {
            entries.push((i, Some([local.x, local.y, local.z])));
        }
        entries.sort_by_key(|e| e.0);
        body.points = entries.iter().map(|e| e.0).collect();
        body.shape = entries.into_iter().map(|e| e.1).collect();
    }
    let found = std::mem::take(&mut m.warnings);
    m.warnings = before;
    m.warnings
        .extend(found.into_iter().map(|w| w.map_points(whole)));
    m.warnings.push(Warning::TracksSampled {
        sampled: sample.len(),
        assigned: assigned.len(),
        unexplained,
        rounds,
    });
    for e in &mut m.trace {
        e.points.iter_mut().for_each(|i| *i = whole(*i));
    }
    m.validate()?;
    // Every point now on a body measures the joints: their positions, precision and
    // re-prediction come from the whole-tree fit on all of them.
    let state = kinetree_fit::FitState::new(m, tracks)?;
    crate::runner::write_fit(pipeline, m, &state, tracks)?;
    d.sampled = Some(sample.to_vec());
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 100 points in a tight cluster at the origin and 4 far apart, all seen in every frame.
    fn crowd() -> (Vec<usize>, Vec<Option<[f64; 3]>>, Vec<usize>) {
        let mut means: Vec<Option<[f64; 3]>> = (0..100)
            .map(|k| Some([1e-3 * (k % 10) as f64, 1e-3 * (k / 10) as f64, 0.0]))
            .collect();
        for k in 0..4 {
            means.push(Some([1.0 + k as f64, 0.0, 0.0]));
        }
        ((0..104).collect(), means, vec![50; 104])
    }

    #[test]
    fn the_farthest_points_reach_every_far_point_however_few() {
        let (candidates, means, visible) = crowd();
        let picked = farthest_points(&candidates, &means, &visible, 6);
        assert_eq!(picked.len(), 6);
        for far in 100..104 {
            assert!(picked.contains(&far), "{far} missing from {picked:?}");
        }
        // Of two points in one far place, the better-seen one is taken.
        let (mut means, mut visible) = (means, visible);
        means[103] = means[102];
        visible[102] = 5;
        let picked = farthest_points(&candidates, &means, &visible, 2);
        assert_eq!(picked, vec![0, 103]);
    }

    #[test]
    fn the_choice_is_ascending_distinct_and_fixed_by_its_seed() {
        let (candidates, means, visible) = crowd();
        let a = choose(&candidates, &means, &visible, 20, 7);
        assert_eq!(a.len(), 20);
        assert!(a.windows(2).all(|w| w[0] < w[1]), "{a:?}");
        assert_eq!(a, choose(&candidates, &means, &visible, 20, 7));
        assert_ne!(a, choose(&candidates, &means, &visible, 20, 8));
        // The crowd gets the random half too: it holds most of the points.
        assert!(a.iter().filter(|&&i| i < 100).count() >= 10, "{a:?}");
        assert_eq!(choose(&candidates, &means, &visible, 200, 7), candidates);
    }
}
