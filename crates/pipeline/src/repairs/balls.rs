//! Segments seen through two markers, posed through a ball joint on a posed body: `balls`
//! poses bodies registered in few frames that no hinge poses, and `ball_groups` makes bodies
//! of the clusters too small for a pose whose points turn about a point of a posed body.
//!
//! Clinical marker sets put two markers on a hand or a foot and the rest on the axes of the
//! joint above, carried by the segment above; the two alone give no pose, so the segment and
//! its joint were lost.

use super::{count_in_range, in_range, poses_of};
use kinetree_core::{
    BodyPoses, Draft, Edit, Proposal, Repair, RepairContext, RepairLimit, RepairPhase, Result,
    Tracks, Warning,
};
use kinetree_pose::Ball;
use serde::{Deserialize, Serialize};

/// When a group of keypoints is taken to turn about a point of a posed body (`best_ball`);
/// used by [`Balls`] and [`BallGroups`], each with these parameters in its own section.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BallBounds {
    /// Slack on the `chi^2 / dof` bound at `bound_in_std` std-devs (default 2.0, as the
    /// hinges').
    pub slack: f64,
    /// Std-devs of the `chi^2` bound (default 4.0).
    pub bound_in_std: f64,
    /// Largest RMS of the keypoints' distances from the centre about their means, in noise
    /// std-devs (default 3.0): as the hinges' bound, against a poorly posed parent whose pose
    /// noise passes almost any ball.
    pub max_rms_in_sigma: f64,
    /// Largest std-dev of the fitted centre along its worst direction, in noise std-devs
    /// (default 3.0): a group turning about one axis leaves the centre free along it (a
    /// hinge, which the hinge repairs take first), one that hardly turns leaves it loose.
    pub max_centre_std_in_sigma: f64,
    /// Least RMS motion of the keypoints in the parent's frame, in noise std-devs
    /// (default 5): a group rigid with the parent (about 1.7) fits spheres about any
    /// centre near it.
    pub min_swing_in_sigma: f64,
    /// A body whose poses explain one of the group's keypoints within this many std-devs
    /// (the attachment's rule, `kinetree_pose::explains_point`; default 4) is no parent: the
    /// group is then part of it, as a fragment a split cut off (`docs/decisions.md`).
    pub explained_bound_in_std: f64,
    /// Slack on that bound (default 2).
    pub explained_slack: f64,
    /// When a ball can be fitted at all: frames, lever of the centre.
    pub fit: kinetree_pose::BallLimits,
}

impl Default for BallBounds {
    fn default() -> Self {
        Self {
            slack: 2.0,
            bound_in_std: 4.0,
            max_rms_in_sigma: 3.0,
            max_centre_std_in_sigma: 3.0,
            min_swing_in_sigma: 5.0,
            explained_bound_in_std: kinetree_pose::ATTACH_BOUND.0,
            explained_slack: kinetree_pose::ATTACH_BOUND.1,
            fit: kinetree_pose::BallLimits::default(),
        }
    }
}

impl BallBounds {
    fn validate(&self, repair: &str) -> Result<()> {
        in_range(repair, "slack", self.slack, 0.1, 100.0)?;
        in_range(repair, "bound_in_std", self.bound_in_std, 0.0, 20.0)?;
        in_range(repair, "max_rms_in_sigma", self.max_rms_in_sigma, 0.0, 1e6)?;
        in_range(
            repair,
            "max_centre_std_in_sigma",
            self.max_centre_std_in_sigma,
            0.0,
            1e6,
        )?;
        in_range(
            repair,
            "min_swing_in_sigma",
            self.min_swing_in_sigma,
            0.0,
            1e6,
        )?;
        in_range(
            repair,
            "explained_bound_in_std",
            self.explained_bound_in_std,
            0.0,
            20.0,
        )?;
        in_range(repair, "explained_slack", self.explained_slack, 0.1, 100.0)?;
        count_in_range(repair, "min_fit_frames", self.fit.min_frames, 3, 1_000_000)?;
        in_range(
            repair,
            "min_lever_in_sigma",
            self.fit.min_lever_in_sigma,
            0.0,
            1e6,
        )
    }
}

/// Of the balls of `group` on the posed bodies other than `skip` and on the camera frame that
/// hold (the group rigid, within the `chi^2` bound, at most `max_rms_in_sigma` off, the centre
/// within `max_centre_std_in_sigma`, moving at least `min_swing_in_sigma`, no keypoint
/// explained by the parent's poses), the one that explains the keypoints best (lowest RMS
/// residual, then the most frames posed).
pub(crate) fn best_ball(
    bounds: &BallBounds,
    tracks: &Tracks,
    poses: &BodyPoses,
    group: &[usize],
    skip: Option<usize>,
    sigma: f64,
) -> Option<Ball> {
    let bound = |dof: f64| kinetree_pose::misfit_bound(dof, bounds.bound_in_std, bounds.slack);
    let (rigidity, rigidity_dof) = kinetree_pose::group_rigidity(tracks, group, sigma);
    if rigidity > bound(rigidity_dof) {
        return None;
    }
    std::iter::once(None)
        .chain((0..poses.bodies.len()).map(Some))
        .filter(|&parent| parent.is_none() || parent != skip)
        .filter(|&parent| {
            let explained = (bounds.explained_bound_in_std, bounds.explained_slack);
            parent.is_none_or(|b| {
                !group
                    .iter()
                    .any(|&i| kinetree_pose::explains_point(tracks, poses, b, i, sigma, explained))
            })
        })
        .filter_map(|parent| {
            kinetree_pose::balled_body(tracks, poses, parent, group, sigma, &bounds.fit)
        })
        .filter(|b| {
            b.chi2_per_dof <= bound(b.dof)
                && b.rms_residual_m <= bounds.max_rms_in_sigma * sigma
                && b.centre_std_in_sigma <= bounds.max_centre_std_in_sigma
                && b.swing_in_sigma >= bounds.min_swing_in_sigma
        })
        .min_by(|x, y| {
            x.rms_residual_m
                .total_cmp(&y.rms_residual_m)
                .then(y.track.n_registered().cmp(&x.track.n_registered()))
        })
}

/// Parameters of [`Balls`] (`[pipeline.repairs.balls]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BallsParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// A body registered in at most this share of the frames that show one of its keypoints
    /// is tried (default 0.5, as the hinges').
    pub max_reposed_share: f64,
    /// ... and posed through the ball when that poses it in at least this many times as many
    /// frames (default 1.5).
    pub min_repose_gain: f64,
    /// Slack on the ball's `chi^2` bound ([`BallBounds::slack`], default 2.0).
    pub slack: f64,
    /// Std-devs of the ball's `chi^2` bound ([`BallBounds::bound_in_std`], default 4.0).
    pub bound_in_std: f64,
    /// Largest RMS misfit ([`BallBounds::max_rms_in_sigma`], default 3.0).
    pub max_rms_in_sigma: f64,
    /// Loosest centre ([`BallBounds::max_centre_std_in_sigma`], default 3.0).
    pub max_centre_std_in_sigma: f64,
    /// Least motion on the parent ([`BallBounds::min_swing_in_sigma`], default 5).
    pub min_swing_in_sigma: f64,
    /// A body explaining a keypoint of the group within this many std-devs is no parent
    /// ([`BallBounds::explained_bound_in_std`], default 4). Keep it, with its slack, no
    /// looser than `ball_groups`': this repair poses the bodies that one makes, and a parent
    /// it refuses leaves such a body unposed (`docs/decisions.md`,
    /// `balls.explained_bound_in_std`).
    pub explained_bound_in_std: f64,
    /// Slack on that bound ([`BallBounds::explained_slack`], default 2).
    pub explained_slack: f64,
    /// Fewest frames for a fit ([`kinetree_pose::BallLimits::min_frames`], default 10).
    pub min_fit_frames: usize,
    /// Least spread of the centre with the visible keypoints
    /// ([`kinetree_pose::BallLimits::min_lever_in_sigma`], default 3).
    pub min_lever_in_sigma: f64,
    /// Whether a body no frame shows whole is posed, its shape linked through the frames
    /// that show parts of it ([`kinetree_pose::BallLimits::partial_views`]; default false).
    /// On, links on ball joints seen a few keypoints at a time get their joints, but
    /// fragments of hinged links are kept as bodies too (`docs/decisions.md`,
    /// `balls.partial_views`). `ball_groups` makes bodies only of groups some frame shows
    /// whole.
    pub partial_views: bool,
}

impl Default for BallsParams {
    fn default() -> Self {
        let b = BallBounds::default();
        Self {
            enabled: true,
            max_reposed_share: 0.5,
            min_repose_gain: 1.5,
            slack: b.slack,
            bound_in_std: b.bound_in_std,
            max_rms_in_sigma: b.max_rms_in_sigma,
            max_centre_std_in_sigma: b.max_centre_std_in_sigma,
            min_swing_in_sigma: b.min_swing_in_sigma,
            explained_bound_in_std: b.explained_bound_in_std,
            explained_slack: b.explained_slack,
            min_fit_frames: b.fit.min_frames,
            min_lever_in_sigma: b.fit.min_lever_in_sigma,
            partial_views: false,
        }
    }
}

impl BallsParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "balls";
        in_range(NAME, "max_reposed_share", self.max_reposed_share, 0.0, 1.0)?;
        in_range(NAME, "min_repose_gain", self.min_repose_gain, 1.0, 1e6)?;
        self.bounds().validate(NAME)
    }

    /// The ball bounds of these parameters.
    pub fn bounds(&self) -> BallBounds {
        BallBounds {
            slack: self.slack,
            bound_in_std: self.bound_in_std,
            max_rms_in_sigma: self.max_rms_in_sigma,
            max_centre_std_in_sigma: self.max_centre_std_in_sigma,
            min_swing_in_sigma: self.min_swing_in_sigma,
            explained_bound_in_std: self.explained_bound_in_std,
            explained_slack: self.explained_slack,
            fit: kinetree_pose::BallLimits {
                min_frames: self.min_fit_frames,
                min_lever_in_sigma: self.min_lever_in_sigma,
                partial_views: self.partial_views,
            },
        }
    }
}

/// Poses bodies registered in few frames through their best ball joint; asked after every
/// pose estimate, after the hinges, which take a body that turns about one axis.
#[derive(Debug, Clone)]
pub struct Balls {
    params: BallsParams,
}

impl Balls {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: BallsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for Balls {
    fn name(&self) -> &str {
        "balls"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let (tracks, sigma) = (ctx.tracks, ctx.noise_sigma_m);
        let bounds = self.params.bounds();
        let mut out = poses.clone();
        let (mut warnings, mut points) = (Vec::new(), Vec::new());
        for (b, track) in poses.bodies.iter().enumerate() {
            let Some(own) =
                super::sparsely_registered(tracks, track, self.params.max_reposed_share)
            else {
                continue;
            };
            let Some(ball) = best_ball(&bounds, tracks, poses, &track.points, Some(b), sigma)
            else {
                continue;
            };
            if (ball.track.n_registered() as f64) < self.params.min_repose_gain * own as f64 {
                continue;
            }
            let (filled, frames) = kinetree_pose::filled_from_track(track, &ball.track);
            points.extend(&filled.points);
            warnings.push(Warning::BodyPosedThroughBall {
                points: filled.points.clone(),
                parent: ball.parent.map(|q| poses.bodies[q].points.clone()),
                frames,
            });
            out.bodies[b] = filled;
        }
        if warnings.is_empty() {
            return Ok(None);
        }
        let mut p = Proposal::new(
            Edit::Poses(out),
            format!("{} body(ies) posed through a ball joint", warnings.len()),
        );
        points.sort_unstable();
        (p.points, p.warnings) = (points, warnings);
        Ok(Some(p))
    }
}

/// Parameters of [`BallGroups`] (`[pipeline.repairs.ball_groups]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BallGroupsParams {
    /// Whether the repair runs.
    pub enabled: bool,
    /// Frames a keypoint must be seen in (default 10).
    pub min_frames: usize,
    /// Smallest group (default 2).
    pub min_points: usize,
    /// A keypoint a body's poses explain within this many std-devs (the attachment's rule,
    /// `kinetree_pose::explains_point`; default 4) is not grouped, and that body is no
    /// parent ([`BallBounds::explained_bound_in_std`]).
    pub explained_bound_in_std: f64,
    /// Slack on that bound (default 2).
    pub explained_slack: f64,
    /// As [`BallsParams::slack`] (default 2.0).
    pub slack: f64,
    /// As [`BallsParams::bound_in_std`] (default 4.0).
    pub bound_in_std: f64,
    /// As [`BallsParams::max_rms_in_sigma`] (default 3.0).
    pub max_rms_in_sigma: f64,
    /// As [`BallsParams::max_centre_std_in_sigma`] (default 3.0).
    pub max_centre_std_in_sigma: f64,
    /// As [`BallsParams::min_swing_in_sigma`] (default 5).
    pub min_swing_in_sigma: f64,
    /// As [`BallsParams::min_fit_frames`] (default 10).
    pub min_fit_frames: usize,
    /// As [`BallsParams::min_lever_in_sigma`] (default 3).
    pub min_lever_in_sigma: f64,
    /// Whether a keypoint left with no partner borrows the keypoints of posed bodies that
    /// stay rigid with it (default false). A segment of two markers, one on a joint's axis,
    /// loses that one to the neighbouring segment, which it is rigid with too; the other then
    /// makes no group alone. The borrowed keypoints stay on their bodies and are shared with
    /// the group's body when it is made. Off by default: it gives Plug-in Gait thighs and
    /// upper arms their bodies, but lone keypoints of rigid mechanisms and stray skin markers
    /// make wrong ones (`docs/decisions.md`, `ball_groups.borrow`).
    pub borrow: bool,
}

impl Default for BallGroupsParams {
    fn default() -> Self {
        let b = BallBounds::default();
        Self {
            enabled: true,
            min_frames: kinetree_pose::MIN_BALL_FRAMES,
            min_points: 2,
            explained_bound_in_std: kinetree_pose::ATTACH_BOUND.0,
            explained_slack: kinetree_pose::ATTACH_BOUND.1,
            slack: b.slack,
            bound_in_std: b.bound_in_std,
            max_rms_in_sigma: b.max_rms_in_sigma,
            max_centre_std_in_sigma: b.max_centre_std_in_sigma,
            min_swing_in_sigma: b.min_swing_in_sigma,
            min_fit_frames: b.fit.min_frames,
            min_lever_in_sigma: b.fit.min_lever_in_sigma,
            borrow: false,
        }
    }
}

impl BallGroupsParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        const NAME: &str = "ball_groups";
        count_in_range(NAME, "min_frames", self.min_frames, 2, 1_000_000)?;
        count_in_range(NAME, "min_points", self.min_points, 2, 1_000_000)?;
        self.bounds().validate(NAME)
    }

    /// The ball bounds of these parameters.
    pub fn bounds(&self) -> BallBounds {
        BallBounds {
            slack: self.slack,
            bound_in_std: self.bound_in_std,
            max_rms_in_sigma: self.max_rms_in_sigma,
            max_centre_std_in_sigma: self.max_centre_std_in_sigma,
            min_swing_in_sigma: self.min_swing_in_sigma,
            explained_bound_in_std: self.explained_bound_in_std,
            explained_slack: self.explained_slack,
            fit: kinetree_pose::BallLimits {
                min_frames: self.min_fit_frames,
                min_lever_in_sigma: self.min_lever_in_sigma,
                partial_views: false,
            },
        }
    }
}

/// Makes bodies of the clusters discarded as too small for a pose, and of pairs of other
/// keypoints that stay rigid together, whose keypoints, on no body and explained by none,
/// turn together about a point of a posed body; asked once per bodies phase, after
/// `hinge_groups`, which takes the groups that turn about one axis.
#[derive(Debug, Clone)]
pub struct BallGroups {
    params: BallGroupsParams,
}

impl BallGroups {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: BallGroupsParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl Repair for BallGroups {
    fn name(&self) -> &str {
        "ball_groups"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Bodies
    }

    fn limit(&self) -> RepairLimit {
        RepairLimit::Once
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        let poses = poses_of(self.name(), draft.poses.as_ref())?;
        let (tracks, sigma, seg) = (ctx.tracks, ctx.noise_sigma_m, &draft.segmentation);
        let explained = (
            self.params.explained_bound_in_std,
            self.params.explained_slack,
        );
        // Points on no body that no body's poses explain, ascending; each tested once.
        let free: Vec<usize> = super::unassigned_points(tracks, seg, self.params.min_frames)
            .into_iter()
            .filter(|&i| {
                !(0..poses.bodies.len())
                    .any(|b| kinetree_pose::explains_point(tracks, poses, b, i, sigma, explained))
            })
            .collect();
        let is_free = |i: &usize| free.binary_search(i).is_ok();
        let bounds = self.params.bounds();
        // The candidates: the clusters discarded as too small, then pairs of the other free
        // points that are rigid together (the clustering may leave a segment's two markers
        // apart, each a cluster of one).
        let mut candidates: Vec<Vec<usize>> = seg
            .discarded_groups
            .iter()
            .map(|g| g.iter().copied().filter(is_free).collect::<Vec<usize>>())
            .filter(|g| g.len() >= self.params.min_points)
            .collect();
        let rest: Vec<usize> = free
            .iter()
            .copied()
            .filter(|i| !candidates.iter().flatten().any(|j| j == i))
            .collect();
        let rigid = |g: &[usize]| {
            let (chi2, dof) = ctx.stats.rigidity(g, sigma);
            dof > 0.0 && chi2 <= kinetree_pose::misfit_bound(dof, bounds.bound_in_std, bounds.slack)
        };
        if self.params.min_points <= 2 {
            candidates.extend(super::rigid_pairs(rest.clone(), |a, b| rigid(&[a, b])));
        }
        // Keypoints still alone borrow the keypoints on bodies rigid with them, seen together
        // in enough frames: a marker on a joint's axis the clustering gave the neighbour.
        let mut borrowed: Vec<(usize, usize)> = Vec::new();
        if self.params.borrow {
            let on_body: Vec<usize> = (0..seg.n_points())
                .filter(|&i| seg.body_of(i).is_some())
                .collect();
            for &i in &rest {
                if candidates.iter().flatten().any(|&j| j == i) {
                    continue;
                }
                let mut group: Vec<usize> = on_body
                    .iter()
                    .copied()
                    .filter(|&j| {
                        ctx.stats.count(i, j) as usize >= self.params.min_frames && rigid(&[i, j])
                    })
                    .collect();
                if group.is_empty() || group.len() + 1 < self.params.min_points {
                    continue;
                }
                borrowed.extend(group.iter().map(|&j| (j, i)));
                group.push(i);
                group.sort_unstable();
                candidates.push(group);
            }
        }
        let mut groups: Vec<Vec<usize>> = candidates
            .into_iter()
            .filter(|g| best_ball(&bounds, tracks, poses, g, None, sigma).is_some())
            .collect();
        groups.sort();
        if groups.is_empty() {
            return Ok(None);
        }
        // Each group's own keypoints make its body; the borrowed ones are shared with it.
        let lent = |g: &[usize], j: usize| {
            borrowed
                .iter()
                .any(|&(b, owner)| b == j && g.contains(&owner))
        };
        let own: Vec<Vec<usize>> = groups
            .iter()
            .map(|g| g.iter().copied().filter(|&j| !lent(g, j)).collect())
            .collect();
        let made = super::with_new_bodies(seg, &own);
        let shares: Vec<(usize, usize)> = groups
            .iter()
            .zip(&own)
            .filter_map(|(g, o)| Some((g, made.body_of(*o.first()?)?)))
            .flat_map(|(g, body)| {
                g.iter()
                    .copied()
                    .filter(|&j| lent(g, j))
                    .map(move |j| (j, body))
            })
            .collect();
        let mut p = Proposal::new(
            Edit::Segmentation(made.with_shared(&shares)),
            format!(
                "{} group(s) of keypoints turning about a point of a body made bodies{}",
                groups.len(),
                if shares.is_empty() {
                    String::new()
                } else {
                    format!(", sharing {} keypoint(s) of other bodies", shares.len())
                }
            ),
        );
        p.points = groups.iter().flatten().copied().collect();
        p.points.sort_unstable();
        p.points.dedup();
        Ok(Some(p))
    }
}
