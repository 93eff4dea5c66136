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
        count_in_range(NAME, "max_own_points", self.max_own_points, 0, 1_000_000)
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
        if !self.rigid(stats, g, sigma) {
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
        let (tracks, sigma, seg) = (ctx.tracks, ctx.noise_sigma_m, &draft.segmentation);
        let seen = |i: usize| tracks.visible_count(i) >= self.params.min_frames;
        let assigned: Vec<usize> = (0..tracks.n_points())
            .filter(|&i| seg.body_of(i).is_some() && seen(i))
            .collect();
        // The candidates: the clusters discarded as too small, then pairs of the other
        // points on no body (a split leaves such pairs) that are rigid together.
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
            .collect();
        let rest: Vec<usize> = (0..tracks.n_points())
            .filter(|&i| seg.body_of(i).is_none() && seen(i))
            .filter(|i| !candidates.iter().flatten().any(|j| j == i))
            .collect();
        candidates.extend(super::rigid_pairs(rest, |a, b| {
            self.params.rigid(ctx.stats, &[a, b], sigma)
        }));
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let mut sharing: Vec<Vec<usize>> = Vec::new();
        for g in candidates {
            let least = self.params.min_shared;
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
        for (b, points) in members.iter().enumerate() {
            let own: Vec<usize> = points
                .iter()
                .copied()
                .filter(|&i| seg.body_of(i) == Some(b))
                .collect();
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
                "{} cluster(s) too small for a pose made bodies, and {} body(ies) of three points grown, with {} point(s) of other bodies rigid with them",
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
