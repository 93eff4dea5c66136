//! A cluster too small for a pose made a body with the points of other bodies that are rigid
//! with it, which then belong to both bodies.
//!
//! Clinical marker sets put two markers on a segment and the others on its joints' axes
//! (epicondyles, malleoli). A marker on a hinge's axis is rigid with both segments, and the
//! clustering, which gives each point one body, puts it with the neighbour; the segment's
//! own two markers are then discarded, and every joint that touches the segment is lost.
//! Such a marker is shared: it stays on its body and joins the two markers' body, and both
//! poses use it. A body of the fewest points a pose needs takes such points too. The
//! cluster must move on the body it shares with (some other point of that
//! body is not rigid with it): a cluster rigid with a whole body is part of it, which the
//! attachment handles.
//!
//! With soft tissue a segment's own marker near a joint is about as rigid with the
//! neighbouring segment's markers as with its own, and the clustering can put it there. Such
//! a point is not rigid with most of its body's points; it joins the unassigned points as a
//! candidate, alone or paired. A candidate of one point that is not such a loose point needs
//! a shared point more than `min_shared`: one point and two shared ones are what any point
//! near a hinge's axis shows with its neighbour's points there. A loose point that makes no
//! body stays on its body: the repairs after the model (`eject_points`, `joint_spoilers`)
//! judge it against the fitted motions.

use super::{count_in_range, in_range, with_new_bodies};
use kinetree_core::{
    Draft, Edit, MIN_BODY_POINTS, PairStats, Proposal, Repair, RepairContext, RepairLimit,
    RepairPhase, Result, Warning,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`SharePoints`] (`[pipeline.repairs.share_points]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SharePointsParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Frames a keypoint must be seen in, and a pair seen together in (default 10).
    pub min_frames: usize,
    /// Std-devs of the rigidity bound: a set of keypoints is rigid when the `chi^2 / dof` of
    /// their distances about their means, against `2 sigma^2`, is within the Wilson-Hilferty
    /// quantile at this many standard deviations (default 4, as the hinges' rigidity test)...
    pub bound_in_std: f64,
    /// ...times this slack (default 1.5; `docs/decisions.md`).
    pub slack: f64,
    /// Fewest points a group must share (default 2: a hinge's axis, which two markers on it
    /// fix; a single point near an axis can stay rigid with a neighbour's points over the few
    /// frames they are seen together, and a wrong body follows).
    pub min_shared: usize,
    /// A body of at most this many points takes the points of other bodies rigid with it as
    /// well (default 3, the fewest a pose needs).
    pub max_own_points: usize,
    /// A point whose pairs with more than this share of its body's other points are not
    /// rigid is a candidate too, and leaves its body when it makes one (default 0.5; 1 never;
    /// `docs/decisions.md`). With soft tissue a segment's marker near a joint can be clustered
    /// with the neighbouring segment, which then loses its own pose.
    pub loose_share: f64,
    /// The most model error, in metres, the rigidity tests allow (default 0: none). Each test
    /// takes the distances' variance as `2 sigma^2 + e^2`, where `e` is the largest spread
    /// of any body's own distances beyond the noise (the root of its pairs' mean variance
    /// less `2 sigma^2`), at most this value. Skin markers on one segment move against each
    /// other by more than the sensor noise the estimate gives, and a marker on a joint's axis
    /// is then no more rigid with the neighbouring segment than the segments are in
    /// themselves; on rigid bodies `e` is about zero and nothing changes.
    pub model_error_m: f64,
}

impl Default for SharePointsParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_frames: 10,
            bound_in_std: 4.0,
            slack: 1.5,
            min_shared: 2,
            max_own_points: 3,
            loose_share: 0.5,
            model_error_m: 0.0,
        }
    }
}

impl SharePointsParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "share_points";
        count_in_range(NAME, "min_frames", self.min_frames, 2, 1_000_000)?;
        in_range(NAME, "bound_in_std", self.bound_in_std, 0.0, 20.0)?;
        in_range(NAME, "slack", self.slack, 0.1, 100.0)?;
        count_in_range(NAME, "min_shared", self.min_shared, 1, 1_000_000)?;
        count_in_range(NAME, "max_own_points", self.max_own_points, 0, 1_000_000)?;
        in_range(NAME, "loose_share", self.loose_share, 0.0, 1.0)?;
        in_range(NAME, "model_error_m", self.model_error_m, 0.0, 1.0)
    }

    /// The points of bodies of more than the fewest points a pose needs whose pairs with more
    /// than `loose_share` of their body's other points (of at least that fewest number seen
    /// with them) are not rigid, ascending.
    fn loose(
        &self,
        stats: &PairStats,
        seg: &kinetree_core::Segmentation,
        sigma: f64,
    ) -> Vec<usize> {
        let mut out = Vec::new();
        for own in own_members(seg) {
            if own.len() <= MIN_BODY_POINTS {
                continue;
            }
            let mut off = Vec::new();
            for &p in &own {
                let seen: Vec<usize> = own
                    .iter()
                    .copied()
                    .filter(|&q| q != p && self.testable(stats, &[p, q]))
                    .collect();
                let apart = seen
                    .iter()
                    .filter(|&&q| !self.rigid(stats, &[p, q], sigma))
                    .count();
                if seen.len() >= MIN_BODY_POINTS
                    && apart as f64 > self.loose_share * seen.len() as f64
                {
                    off.push(p);
                }
            }
            if own.len() - off.len() >= MIN_BODY_POINTS {
                out.extend(off);
            }
        }
        out.sort_unstable();
        out
    }

    /// Whether every pair of `points` is seen together in at least `min_frames` frames.
    fn testable(&self, stats: &PairStats, points: &[usize]) -> bool {
        points.iter().enumerate().all(|(k, &a)| {
            points[k + 1..]
                .iter()
                .all(|&b| a != b && stats.count(a, b) as usize >= self.min_frames)
        })
    }

    /// The points of `assigned` (on bodies of `seg`, none of `g`) that `g` can share: each
    /// rigid with `g`, `g` moving on each of their bodies (another point of that body, seen
    /// with `g`, is not rigid with it: a group rigid with a whole body is part of it, the
    /// attachment's case), at least `min_shared` of them, and all rigid together with `g`.
    fn shared_with(
        &self,
        stats: &PairStats,
        seg: &kinetree_core::Segmentation,
        assigned: &[usize],
        g: &[usize],
        sigma: f64,
        min_shared: usize,
    ) -> Option<Vec<usize>> {
        if g.len() > 1 && !self.rigid(stats, g, sigma) {
            return None;
        }
        let with_point = |q: usize| {
            let mut set = g.to_vec();
            set.push(q);
            set
        };
        let with: Vec<usize> = assigned
            .iter()
            .copied()
            .filter(|q| !g.contains(q) && self.rigid(stats, &with_point(*q), sigma))
            .collect();
        if with.len() < min_shared {
            return None;
        }
        let moves_on_each = with.iter().all(|&q| {
            let own = seg.body_of(q);
            assigned.iter().any(|&r| {
                seg.body_of(r) == own
                    && !with.contains(&r)
                    && self.testable(stats, &with_point(r))
                    && !self.rigid(stats, &with_point(r), sigma)
            })
        });
        let mut all = g.to_vec();
        all.extend(&with);
        (moves_on_each && all.len() >= MIN_BODY_POINTS && self.rigid(stats, &all, sigma))
            .then_some(with)
    }

    /// Whether `points` move rigidly within noise `sigma`, every pair seen together in at
    /// least `min_frames` frames.
    fn rigid(&self, stats: &PairStats, points: &[usize], sigma: f64) -> bool {
        if !self.testable(stats, points) {
            return false;
        }
        let (chi2, dof) = stats.rigidity(points, sigma);
        dof > 0.0 && chi2 <= kinetree_pose::misfit_bound(dof, self.bound_in_std, self.slack)
    }
}

/// The largest spread of a body's own distances beyond the noise: over the bodies with at
/// least the fewest points a pose needs, the root of their own pairs' mean distance variance
/// (the pairs weighted by their frames, as [`PairStats::rigidity`] weighs them) less
/// `2 sigma^2`, or zero.
fn body_model_error(stats: &PairStats, seg: &kinetree_core::Segmentation, sigma: f64) -> f64 {
    let noise = 2.0 * sigma * sigma;
    own_members(seg)
        .iter()
        .filter(|own| own.len() >= MIN_BODY_POINTS)
        .map(|own| stats.rigidity(own, sigma))
        .filter(|&(_, dof)| dof > 0.0)
        .map(|(per_dof, _)| noise * (per_dof - 1.0))
        .fold(0.0, f64::max)
        .sqrt()
}

/// Each body's own points (not those it shares with another body), ascending.
fn own_members(seg: &kinetree_core::Segmentation) -> Vec<Vec<usize>> {
    let mut own = vec![Vec::new(); seg.n_bodies()];
    for (i, b) in seg.labels().iter().enumerate() {
        if let Some(b) = b {
            own[*b].push(i);
        }
    }
    own
}

/// Makes bodies of discarded clusters with the other bodies' points that are rigid with
/// them; asked once per bodies phase.
#[derive(Debug, Clone)]
pub struct SharePoints {
    params: SharePointsParams,
}

impl SharePoints {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SharePointsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for SharePoints {
    fn name(&self) -> &str {
        "share_points"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Once
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let (tracks, seg) = (ctx.tracks, &draft.segmentation);
        let sigma = ctx.noise_sigma_m;
        let error = if self.params.model_error_m > 0.0 {
            body_model_error(ctx.stats, seg, sigma).min(self.params.model_error_m)
        } else {
            0.0
        };
        // The level every rigidity test below is judged at: `2 sigma^2 + e^2` per distance.
        let sigma = (sigma * sigma + 0.5 * error * error).sqrt();
        let seen = |i: usize| tracks.visible_count(i) >= self.params.min_frames;
        // A loose point is no shared point: the points of two links clustered as one are
        // each other's loose points, and the split separates them.
        let loose = self.params.loose(ctx.stats, seg, sigma);
        let assigned: Vec<usize> = (0..tracks.n_points())
            .filter(|&i| seg.body_of(i).is_some() && seen(i) && !loose.contains(&i))
            .collect();
        // The candidates: the clusters discarded as too small that are rigid, then pairs of
        // the other points on no body (a split leaves such pairs) that are rigid together,
        // then those points alone.
        let mut candidates: Vec<Vec<usize>> = seg
            .discarded_groups
            .iter()
            .map(|g| {
                g.iter()
                    .copied()
                    .filter(|&i| seg.body_of(i).is_none() && seen(i))
                    .collect::<Vec<usize>>()
            })
            .filter(|g| !g.is_empty() && g.len() < MIN_BODY_POINTS)
            .filter(|g| g.len() == 1 || self.params.rigid(ctx.stats, g, sigma))
            .collect();
        // The loose points of bodies pair with those points, or stand alone.
        let rest: Vec<usize> = (0..tracks.n_points())
            .filter(|&i| (seg.body_of(i).is_none() || loose.contains(&i)) && seen(i))
            .filter(|i| !candidates.iter().flatten().any(|j| j == i))
            .collect();
        let paired = super::rigid_pairs(rest.clone(), |a, b| {
            self.params.rigid(ctx.stats, &[a, b], sigma)
        });
        let alone = rest
            .iter()
            .filter(|&&i| !paired.iter().flatten().any(|&j| j == i))
            .map(|&i| vec![i])
            .collect::<Vec<_>>();
        candidates.extend(paired);
        candidates.extend(alone);
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let mut sharing: Vec<Vec<usize>> = Vec::new();
        for g in candidates {
            // One point with two shared ones is what any point near a hinge's axis shows
            // with the neighbour's points near it; a point alone needs one shared point more.
            let least =
                self.params.min_shared + usize::from(g.len() == 1 && !loose.contains(&g[0]));
            if let Some(with) = self
                .params
                .shared_with(ctx.stats, seg, &assigned, &g, sigma, least)
            {
                groups.push(g);
                sharing.push(with);
            }
        }
        // Bodies with the fewest points a pose needs take the points rigid with them too.
        let members = seg.members();
        let mut grown: Vec<(Vec<usize>, Vec<usize>)> = Vec::new();
        for (own, points) in own_members(seg).into_iter().zip(&members) {
            if own.len() != points.len() || own.len() > self.params.max_own_points {
                continue;
            }
            let least = self.params.min_shared;
            if let Some(with) = self
                .params
                .shared_with(ctx.stats, seg, &assigned, &own, sigma, least)
            {
                grown.push((own, with));
            }
        }
        if groups.is_empty() && grown.is_empty() {
            return Ok(None);
        }
        let made = with_new_bodies(seg, &groups);
        let pairs: Vec<(usize, usize)> = groups
            .iter()
            .zip(&sharing)
            .chain(grown.iter().map(|(g, with)| (g, with)))
            .filter_map(|(g, with)| {
                let b = made.body_of(g[0])?;
                Some(with.iter().map(move |&q| (q, b)))
            })
            .flatten()
            .collect();
        let mut p = Proposal::new(
            Edit::Segmentation(made.with_shared(&pairs)),
            format!(
                "{} group(s) too small for a pose made bodies, and {} body(ies) of three points grown, with {} point(s) of other bodies rigid with them",
                groups.len(),
                grown.len(),
                pairs.len()
            ),
        );
        p.points = groups.iter().chain(&sharing).flatten().copied().collect();
        p.points.sort_unstable();
        p.points.dedup();
        for (g, with) in groups.into_iter().zip(sharing).chain(grown) {
            p.warnings.push(Warning::PointsShared {
                points: with,
                body: g,
            });
        }
        Ok(Some(p))
    }
}

#[cfg(test)]
mod tests {
    use super::body_model_error;
    use kinetree_core::{Segmentation, Tracks};
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    /// Two bodies of three points each over 2000 frames at 1 mm of noise, the second one's
    /// points also wobbling independently by `wobble` metres per coordinate (skin under
    /// markers): each distance of the second body varies by `2 sigma^2 + 2 wobble^2`, so the
    /// spread beyond the noise is `sqrt(2) wobble`.
    fn spread(wobble: f64) -> f64 {
        let (frames, sigma) = (2000, 0.001);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut gauss = || -> f64 { StandardNormal.sample(&mut rng) };
        let places = [
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.0, 0.1, 0.0],
            [0.5, 0.0, 0.0],
            [0.6, 0.0, 0.0],
            [0.5, 0.1, 0.0],
        ];
        let mut xyz = Vec::with_capacity(frames * places.len() * 3);
        for _ in 0..frames {
            for (i, p) in places.iter().enumerate() {
                let extra = if i >= 3 { wobble } else { 0.0 };
                for c in p {
                    xyz.push(c + sigma * gauss() + extra * gauss());
                }
            }
        }
        let tracks = Tracks::new(frames, places.len(), xyz).expect("tracks");
        let stats = kinetree_dissimilarity::pair_stats(&tracks);
        let labels = [Some(0), Some(0), Some(0), Some(1), Some(1), Some(1)];
        body_model_error(&stats, &Segmentation::from_raw(&labels, 1), sigma)
    }

    #[test]
    fn the_bodies_spread_beyond_the_noise_is_the_loosest_bodys() {
        let loose = spread(0.002);
        let expected = 2f64.sqrt() * 0.002;
        assert!(
            (loose - expected).abs() < 0.1 * expected,
            "{loose} against {expected}"
        );
        // Rigid bodies: only the sampling scatter of the noise's variance is left.
        let rigid = spread(0.0);
        assert!(rigid < 0.25e-3, "{rigid}");
    }
}
