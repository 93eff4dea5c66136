//! Moving keypoints to the body whose fitted motion explains them better, once a model exists.
//!
//! Segmentation judges a point by its pairwise distances and, afterwards, by per-body poses.
//! A point near a joint axis is rigid to both bodies pairwise, and against per-body poses of a
//! small body it fits both within their noise, so it can land on the wrong side. The
//! whole-tree fit poses every body through the joints and all keypoints, far more precisely;
//! against those poses the point's own track tells the two bodies apart.

use crate::solver::{Observer, Scratch};
use kinetree_core::nalgebra::{Isometry3, Vector3};
use kinetree_core::stats::chi2_per_dof_quantile;
use kinetree_core::{BodyPoses, Error, FittedPoses, MIN_BODY_POINTS, Model, Result, Tracks};

/// Default of [`MotionLimits::min_frames`].
pub const MIN_FRAMES: usize = 10;
/// Default of [`MotionLimits::min_frames_to_place`] (`docs/decisions.md`,
/// `kinetree_fit::MIN_FRAMES_TO_PLACE`).
pub const MIN_FRAMES_TO_PLACE: usize = 5;
/// Default of [`MotionLimits::min_margin`] (`docs/decisions.md`, `kinetree_fit::MIN_MARGIN`).
pub const MIN_MARGIN: f64 = 0.05;
/// Default of [`MotionLimits::min_chi2_gain`] (`docs/decisions.md`,
/// `kinetree_fit::MIN_CHI2_GAIN`).
pub const MIN_CHI2_GAIN: f64 = 16.0;
/// Default of [`MotionLimits::max_body_median`] (`docs/decisions.md`,
/// `kinetree_fit::MAX_BODY_MEDIAN`).
pub const MAX_BODY_MEDIAN: f64 = 1.5;
/// Default of [`MotionLimits::outlier_ratio`] (`docs/decisions.md`,
/// `kinetree_fit::OUTLIER_RATIO`).
pub const OUTLIER_RATIO: f64 = 5.0;

/// The limits by which points are judged against a model's fitted motions; the pipeline's
/// points repairs set them from their parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionLimits {
    /// Fewest frames in which a point must be seen with a body's fitted pose to count in the
    /// body's median misfit (default 10).
    pub min_frames: usize,
    /// Fewest frames in which a point must be seen with a body's fitted pose to be placed on
    /// it or moved to it (default 5): a wrong body's motion seldom matches a point's over 5
    /// frames.
    pub min_frames_to_place: usize,
    /// How much better (in `chi^2 / k`) another body must explain a point than its own: at
    /// least this, and a gain in `chi^2` of two standard deviations of `chi^2`,
    /// `2 sqrt(2 k)`, or `min_chi2_gain`, whichever is smaller (default 0.05).
    pub min_margin: f64,
    /// A gain in `chi^2` that moves a point whatever its number of frames (default 16): the
    /// two bodies' `chi^2` of one track differ by the misfit of the motion between them plus
    /// noise that does not grow with the frames.
    pub min_chi2_gain: f64,
    /// A point moves only between bodies the model fits well, the median of their points'
    /// own `chi^2 / k` at most this (default 1.5); a target over it still takes a point that
    /// fits it no worse than its median point.
    pub max_body_median: f64,
    /// A point whose own `chi^2 / k` exceeds this many times its body's median may leave the
    /// body even when the body fits poorly (default 5): one point of another link spoils its
    /// body's fitted poses, and with them the fit of the body's other points.
    pub outlier_ratio: f64,
}

impl Default for MotionLimits {
    fn default() -> Self {
        Self {
            min_frames: MIN_FRAMES,
            min_frames_to_place: MIN_FRAMES_TO_PLACE,
            min_margin: MIN_MARGIN,
            min_chi2_gain: MIN_CHI2_GAIN,
            max_body_median: MAX_BODY_MEDIAN,
            outlier_ratio: OUTLIER_RATIO,
        }
    }
}

/// `chi^2 / k` of a point's track in a body's frame about its mean, in units of the noise
/// variance, and `k = 3 (frames - 1)`: about 1 for a point rigidly attached to the body whose
/// poses are given. `None` with fewer than `min_frames` frames.
fn misfit(
    poses: &[Option<Isometry3<f64>>],
    tracks: &Tracks,
    point: usize,
    sigma: f64,
    min_frames: usize,
) -> Option<(f64, f64)> {
    let z = in_body_frame(poses, tracks, point);
    if z.len() < min_frames.max(2) || sigma <= 0.0 {
        return None;
    }
    let mean = z.iter().sum::<Vector3<f64>>() / z.len() as f64;
    let k = 3.0 * (z.len() - 1) as f64;
    let chi2 = z.iter().map(|v| (v - mean).norm_squared()).sum::<f64>() / (sigma * sigma);
    Some((chi2 / k, k))
}

/// `point`'s observations in the body frame of `poses`, over the frames that have both.
pub(crate) fn in_body_frame(
    poses: &[Option<Isometry3<f64>>],
    tracks: &Tracks,
    point: usize,
) -> Vec<Vector3<f64>> {
    poses
        .iter()
        .enumerate()
        .filter_map(|(t, pose)| {
            Some(
                pose.as_ref()?
                    .inverse_transform_point(&tracks.get(t, point)?)
                    .coords,
            )
        })
        .collect()
}

/// How much better than the next body a point's best body must fit it, in `chi^2 / k`:
/// `min_margin`, or the smaller of two standard deviations and `min_chi2_gain` when larger.
fn margin(k: f64, l: &MotionLimits) -> f64 {
    l.min_margin
        .max((2.0 * (2.0 * k).sqrt()).min(l.min_chi2_gain) / k)
}

/// The largest `chi^2 / k` of a point on the body it is given to: the Wilson-Hilferty bound at
/// 4 standard deviations, times 1.6 for the fit's own errors.
fn bound(k: f64) -> f64 {
    1.6 * chi2_per_dof_quantile(k, 4.0)
}

/// Every body's pose in every frame from the whole-tree fit of a model
/// ([`Observer::fit_sequence`]): computed once, then used by
/// [`FittedMotions::points_fitting_another_body`] and [`FittedMotions::points_settled`].
#[derive(Debug, Clone)]
pub struct FittedMotions {
    /// The fitted poses and their precision, by model body.
    fitted: FittedPoses,
    /// The limits points are judged by.
    limits: MotionLimits,
}

/// `point`'s `chi^2 / k` on its own body `own`, and the other body whose fitted poses explain
/// it best with its `(chi^2 / k, k)`; `None` when either cannot be scored.
fn own_and_best_other(
    body_poses: &[Vec<Option<Isometry3<f64>>>],
    tracks: &Tracks,
    point: usize,
    own: usize,
    sigma: f64,
    min_frames: usize,
) -> Option<(f64, (f64, f64), usize)> {
    let (mine, _) = misfit(&body_poses[own], tracks, point, sigma, min_frames)?;
    let (best, body) = (0..body_poses.len())
        .filter(|&c| c != own)
        .filter_map(|c| misfit(&body_poses[c], tracks, point, sigma, min_frames).map(|m| (m, c)))
        .min_by(|a, b| a.0.0.total_cmp(&b.0.0))?;
    Some((mine, best, body))
}

/// The body of `point` in `model`, when it has one and the point is in `tracks`.
fn body_of(model: &Model, tracks: &Tracks, point: usize) -> Option<usize> {
    model
        .point_body
        .get(point)
        .and_then(|&b| usize::try_from(b).ok())
        .filter(|&b| b < model.bodies.len() && point < tracks.n_points())
}

impl FittedMotions {
    /// The whole-tree fit of `model` on `tracks`.
    ///
    /// # Errors
    /// As [`Observer::new`] and [`Observer::fit_sequence`].
    pub fn new(model: &Model, tracks: &Tracks) -> Result<Self> {
        Self::freeing(model, tracks, &[])
    }

    /// The whole-tree fit of `model` on `tracks` with the joints `freed` (`(parent, child)`
    /// model body ids) free as well as those the model already frees.
    ///
    /// # Errors
    /// As [`Observer::new`] and [`Observer::fit_sequence`].
    pub fn freeing(model: &Model, tracks: &Tracks, freed: &[(usize, usize)]) -> Result<Self> {
        let mut observer = Observer::new(model)?;
        for &(parent, child) in freed {
            observer.free_joint_between(parent, child);
        }
        let mut scratch = Scratch::default();
        let mut qualities = Vec::with_capacity(tracks.n_frames());
        let fits = observer.fit_sequence_with(tracks, |descent, visible| {
            qualities.push(observer.pose_qualities(&descent, &visible, &mut scratch));
        })?;
        let nb = model.bodies.len();
        Ok(Self::from_fitted(FittedPoses {
            body_poses: (0..nb)
                .map(|b| {
                    fits.iter()
                        .map(|f| f.poses.get(b).copied().flatten())
                        .collect()
                })
                .collect(),
            body_qualities: (0..nb)
                .map(|b| {
                    fits.iter()
                        .zip(&qualities)
                        .map(|(f, q)| {
                            f.poses.get(b).copied().flatten()?;
                            q.get(b).copied().flatten()
                        })
                        .collect()
                })
                .collect(),
        }))
    }

    /// Motions from poses already fitted (as [`FittedMotions::into_fitted`] gives them).
    pub fn from_fitted(fitted: FittedPoses) -> Self {
        Self {
            fitted,
            limits: MotionLimits::default(),
        }
    }

    /// These motions judging points by `limits` (the defaults otherwise).
    pub fn with_limits(mut self, limits: MotionLimits) -> Self {
        self.limits = limits;
        self
    }

    /// The fitted poses and their precision, by model body, given up.
    pub fn into_fitted(self) -> FittedPoses {
        self.fitted
    }

    /// The per-body poses `per_body` (in the model's body numbering, as a draft that adopted
    /// the model has them) with every registered pose replaced by the fitted one, in the same
    /// body frame; a registered pose keeps its per-body quality (the fitted pose is at least
    /// as precise, so tests on these poses are calibrated conservatively). Frames the per-body
    /// estimator left unposed get the fitted pose with the fit's own precision
    /// (`Observer::pose_qualities`).
    ///
    /// # Errors
    /// [`Error::Shape`] when `per_body` does not match these motions.
    pub fn onto_body_poses(&self, per_body: &BodyPoses) -> Result<BodyPoses> {
        if per_body.bodies.len() != self.fitted.body_poses.len()
            || self
                .fitted
                .body_poses
                .iter()
                .any(|p| p.len() != per_body.n_frames)
        {
            return Err(Error::Shape {
                expected: format!(
                    "per-body poses of the {} fitted bodies over {} frames",
                    self.fitted.body_poses.len(),
                    self.fitted.body_poses.first().map_or(0, Vec::len)
                ),
                found: format!(
                    "{} bodies over {} frames",
                    per_body.bodies.len(),
                    per_body.n_frames
                ),
            });
        }
        let mut out = per_body.clone();
        for ((track, fitted), qualities) in out
            .bodies
            .iter_mut()
            .zip(&self.fitted.body_poses)
            .zip(&self.fitted.body_qualities)
        {
            for ((pose, quality), (f, fq)) in track
                .cam_from_body
                .iter_mut()
                .zip(track.quality.iter_mut())
                .zip(fitted.iter().zip(qualities))
            {
                match (pose.is_some(), f, fq) {
                    (true, Some(_), _) => *pose = *f,
                    (false, Some(_), Some(_)) => (*pose, *quality) = (*f, *fq),
                    _ => {}
                }
            }
        }
        Ok(out)
    }

    /// [`Error::Shape`] unless these motions were fitted for `model`'s bodies on `tracks`.
    fn check(&self, model: &Model, tracks: &Tracks) -> Result<()> {
        if self.fitted.body_poses.len() != model.bodies.len()
            || self
                .fitted
                .body_poses
                .iter()
                .any(|p| p.len() != tracks.n_frames())
        {
            return Err(Error::Shape {
                expected: format!(
                    "fitted motions of {} bodies over {} frames",
                    model.bodies.len(),
                    tracks.n_frames()
                ),
                found: format!("{} bodies", self.fitted.body_poses.len()),
            });
        }
        Ok(())
    }

    /// Points of `model` (discovered on `tracks`) that another body's fitted motion explains
    /// better than their own body's, as `(point, body)` in the model's numbering, against these
    /// motions (fitted for `model`). A point moves when the other body's `chi^2 / k` (see
    /// [`MIN_MARGIN`]) is lower than its own by the margin and within the Wilson-Hilferty
    /// bound at 4 standard deviations (times 1.6 for the fit's own errors), when both bodies
    /// fit their points well ([`MAX_BODY_MEDIAN`]; the other body may fit worse if the point
    /// fits it no worse than its median point; the point's own body may fit worse if the
    /// point is its outlier, [`OUTLIER_RATIO`]), and when its body keeps at least three
    /// points, unless the point is its outlier (what is left under three points is dropped
    /// by the pipeline and placed again).
    ///
    /// The outlier may leave a body of three: the model's fit poses such a body through its
    /// joint to follow the points it has, so two points of another body can hold it while
    /// the third misses it by far (mechanisms sweep, 5-joint tree half prismatic, seed 19:
    /// two base keypoints and one of a link, the link's at `chi^2 / k` 4.7 against the
    /// body's median 0.9 and 1.4 on its own link).
    ///
    /// # Errors
    /// [`Error::Shape`] when the motions were not fitted for `model` on `tracks`.
    pub fn points_fitting_another_body(
        &self,
        model: &Model,
        tracks: &Tracks,
    ) -> Result<Vec<(usize, usize)>> {
        let l = &self.limits;
        self.check(model, tracks)?;
        let body_poses = &self.fitted.body_poses;
        let sigma = model.noise.sigma_m;
        let mut left: Vec<usize> = model.bodies.iter().map(|b| b.points.len()).collect();
        let body_median = self.body_medians(model, tracks);
        let mut moves = Vec::new();
        let fitted = |b: usize| body_median[b].is_some_and(|m| m <= l.max_body_median);
        for i in 0..model.point_body.len() {
            let Some(own_body) = body_of(model, tracks, i) else {
                if let Some(b) = self.body_for_unassigned(model, tracks, i, &body_median) {
                    moves.push((i, b));
                }
                continue;
            };
            let Some((own, (other, k), c)) = own_and_best_other(
                body_poses,
                tracks,
                i,
                own_body,
                sigma,
                l.min_frames_to_place,
            ) else {
                continue;
            };
            let typical = body_median[c].is_some_and(|m| other <= m);
            let outlier = body_median[own_body].is_some_and(|m| own > l.outlier_ratio * m);
            if left[own_body] <= MIN_BODY_POINTS && !outlier {
                continue;
            }
            if (fitted(own_body) && (fitted(c) || typical) || outlier && fitted(c))
                && own - other > margin(k, l)
                && other <= bound(k)
            {
                moves.push((i, c));
                left[own_body] -= 1;
            }
        }
        Ok(moves)
    }

    /// Points of `bodies` (model numbering) that another body's fitted motion explains
    /// clearly better, as `(point, body)`: the target fitted well ([`MAX_BODY_MEDIAN`]), the
    /// margin and bound of [`FittedMotions::points_fitting_another_body`], but only from a
    /// body fitted worse than that bound, and with no floor on the points it keeps (what is
    /// left under three points is dropped by the pipeline and placed again).
    ///
    /// For bodies a split made: the halves of a split can mix points of two links (two points
    /// of a 6.4 cm slider and two of the link turning on it, at a median misfit of 1.79), and
    /// neither rule of the moves lets such a body go. Allowed for every poorly fitted body, it also emptied a 30 cm link swinging
    /// +-2.5 deg into the base, whose poorly determined joint had made it fit poorly.
    ///
    /// # Errors
    /// [`Error::Shape`] when the motions were not fitted for `model` on `tracks`.
    pub fn points_leaving_mixed_bodies(
        &self,
        model: &Model,
        tracks: &Tracks,
        bodies: &[usize],
    ) -> Result<Vec<(usize, usize)>> {
        let l = &self.limits;
        self.check(model, tracks)?;
        let sigma = model.noise.sigma_m;
        let body_median = self.body_medians(model, tracks);
        let fitted = |b: usize| body_median[b].is_some_and(|m| m <= l.max_body_median);
        let mut moves = Vec::new();
        for &b in bodies {
            if b >= model.bodies.len() || fitted(b) {
                continue;
            }
            for &i in &model.bodies[b].points {
                if i >= tracks.n_points() {
                    continue;
                }
                let Some((own, (other, k), c)) = own_and_best_other(
                    &self.fitted.body_poses,
                    tracks,
                    i,
                    b,
                    sigma,
                    l.min_frames_to_place,
                ) else {
                    continue;
                };
                if fitted(c) && own - other > margin(k, l) && other <= bound(k) {
                    moves.push((i, c));
                }
            }
        }
        Ok(moves)
    }

    /// Points that fit their own body's fitted motion far worse than it allows (over
    /// [`OUTLIER_RATIO`] times the larger of its median and the bound of
    /// [`FittedMotions::points_fitting_another_body`]) and that no other body's motion
    /// explains within that bound either: the worst such point of each body of four or more
    /// (one point of another link spoils its body's fitted poses, and with them the fit of
    /// the body's own points, so the others are judged again after it has gone). They
    /// belong to no body of the model: typically keypoints of a link seen one or two at a
    /// time, which the clustering put on a neighbour. Left on no body, they may form a body
    /// of their own with others like them (posed through a hinge when it fits).
    ///
    /// Measured: the mechanisms sweep's 10-joint revolute tree, seed 1: a keypoint of a link
    /// seen three at a time in 12 of 200 frames sat on a neighbour at `chi^2 / k` 122 (93
    /// degrees of freedom; the body's median 1.3), and three of the neighbour's own points
    /// fitted at 9-12 with it.
    ///
    /// # Errors
    /// [`Error::Shape`] when the motions were not fitted for `model` on `tracks`.
    pub fn points_fitting_no_body(&self, model: &Model, tracks: &Tracks) -> Result<Vec<usize>> {
        let l = &self.limits;
        self.check(model, tracks)?;
        let sigma = model.noise.sigma_m;
        let body_median = self.body_medians(model, tracks);
        // Per body, its worst point that qualifies: `(misfit, point)`.
        let mut worst: Vec<Option<(f64, usize)>> = vec![None; model.bodies.len()];
        for i in 0..tracks.n_points() {
            let Some(own_body) = body_of(model, tracks, i) else {
                continue;
            };
            let Some(median) = body_median[own_body] else {
                continue;
            };
            let Some((own, k)) = misfit(
                &self.fitted.body_poses[own_body],
                tracks,
                i,
                sigma,
                l.min_frames_to_place,
            ) else {
                continue;
            };
            if own <= l.outlier_ratio * bound(k).max(median)
                || model.bodies[own_body].points.len() <= MIN_BODY_POINTS
                || worst[own_body].is_some_and(|(w, _)| w >= own)
            {
                continue;
            }
            let fits_another = (0..self.fitted.body_poses.len())
                .filter(|&c| c != own_body)
                .filter_map(|c| {
                    misfit(
                        &self.fitted.body_poses[c],
                        tracks,
                        i,
                        sigma,
                        l.min_frames_to_place,
                    )
                })
                .any(|(m, kc)| m <= bound(kc));
            if !fits_another {
                worst[own_body] = Some((own, i));
            }
        }
        let mut out: Vec<usize> = worst.into_iter().flatten().map(|(_, i)| i).collect();
        out.sort_unstable();
        Ok(out)
    }

    /// Per body of `model`, the median of its points' own `chi^2 / k` against these motions
    /// (see [`MAX_BODY_MEDIAN`]); `None` for a body with no point to score.
    fn body_medians(&self, model: &Model, tracks: &Tracks) -> Vec<Option<f64>> {
        let l = &self.limits;
        let sigma = model.noise.sigma_m;
        model
            .bodies
            .iter()
            .enumerate()
            .map(|(b, body)| {
                let mut m: Vec<f64> = body
                    .points
                    .iter()
                    .filter(|&&i| i < tracks.n_points())
                    .filter_map(|&i| {
                        misfit(&self.fitted.body_poses[b], tracks, i, sigma, l.min_frames)
                            .map(|m| m.0)
                    })
                    .collect();
                m.sort_by(f64::total_cmp);
                m.get(m.len() / 2).copied()
            })
            .collect()
    }

    /// The body an unassigned `point` belongs to by the fitted motions: the one explaining it
    /// best, within the bound of [`FittedMotions::points_fitting_another_body`], better than
    /// any other by the margin, and fitting its own points well (or the point no worse than
    /// its median point). `None` when the point is assigned, out of range, or no body
    /// qualifies.
    ///
    /// The attachment before the model (`attach_unassigned` of kinetree-pose, in the
    /// pipeline) takes a point only when exactly one body's per-body poses fit it within a
    /// wide bound; a point near two bodies stays out. Measured on the rate test's draw of
    /// 640: in 3 of its 7 failures on the segmentation alone, one point seen in 76-125 frames
    /// was left unassigned.
    fn body_for_unassigned(
        &self,
        model: &Model,
        tracks: &Tracks,
        point: usize,
        body_median: &[Option<f64>],
    ) -> Option<usize> {
        let l = &self.limits;
        if point >= tracks.n_points() || model.point_body.get(point).is_none_or(|&b| b >= 0) {
            return None;
        }
        let sigma = model.noise.sigma_m;
        let mut scored: Vec<((f64, f64), usize)> = (0..self.fitted.body_poses.len())
            .filter_map(|b| {
                misfit(
                    &self.fitted.body_poses[b],
                    tracks,
                    point,
                    sigma,
                    l.min_frames_to_place,
                )
                .map(|m| (m, b))
            })
            .collect();
        scored.sort_by(|a, b| a.0.0.total_cmp(&b.0.0).then(a.1.cmp(&b.1)));
        let &((best, k), b) = scored.first()?;
        let clear = scored
            .get(1)
            .is_none_or(|&((second, _), _)| second - best > margin(k, l));
        let welcome = body_median[b].is_some_and(|m| m <= l.max_body_median || best <= m);
        (clear && welcome && best <= bound(k)).then_some(b)
    }

    /// Points that body `body` (model numbering) explains clearly best against these motions:
    /// on no body, or on one that keeps at least three points after them; seen with the
    /// body's fitted pose in `min_frames_to_place` frames; with a `chi^2 / k` within the bound
    /// of [`FittedMotions::points_fitting_another_body`] and by its margin below every other
    /// body's, their own included. For a body without keypoints of its own (a link put in
    /// between two hinges), whose median misfit that method's rules need.
    ///
    /// # Errors
    /// [`Error::Shape`] when the motions were not fitted for `model` on `tracks`.
    pub fn points_for_body(
        &self,
        model: &Model,
        tracks: &Tracks,
        body: usize,
    ) -> Result<Vec<usize>> {
        self.check(model, tracks)?;
        let l = &self.limits;
        let sigma = model.noise.sigma_m;
        let poses = &self.fitted.body_poses;
        let mut left: Vec<usize> = model.bodies.iter().map(|b| b.points.len()).collect();
        let mut out = Vec::new();
        for i in 0..model.point_body.len().min(tracks.n_points()) {
            let own = body_of(model, tracks, i);
            if own == Some(body) || own.is_some_and(|b| left[b] <= MIN_BODY_POINTS) {
                continue;
            }
            let Some((best, k)) = poses
                .get(body)
                .and_then(|p| misfit(p, tracks, i, sigma, l.min_frames_to_place))
            else {
                continue;
            };
            let clear = (0..poses.len()).filter(|&c| c != body).all(|c| {
                misfit(&poses[c], tracks, i, sigma, l.min_frames_to_place)
                    .is_none_or(|(other, _)| other - best > margin(k, l))
            });
            if clear && best <= bound(k) {
                out.push(i);
                if let Some(b) = own {
                    left[b] -= 1;
                }
            }
        }
        Ok(out)
    }

    /// Whether each of `points` fits its own body in `model` at least as well as any other
    /// body, against the whole-tree fit's poses: the check that points moved by
    /// [`FittedMotions::points_fitting_another_body`] settled where they went. A point that
    /// cannot be scored counts as settled.
    ///
    /// # Errors
    /// [`Error::Shape`] when the motions were not fitted for `model` on `tracks`.
    pub fn points_settled(&self, model: &Model, tracks: &Tracks, points: &[usize]) -> Result<bool> {
        let l = &self.limits;
        self.check(model, tracks)?;
        let body_poses = &self.fitted.body_poses;
        let sigma = model.noise.sigma_m;
        Ok(points.iter().all(|&i| {
            body_of(model, tracks, i)
                .and_then(|own| {
                    own_and_best_other(body_poses, tracks, i, own, sigma, l.min_frames_to_place)
                })
                .is_none_or(|(mine, (other, _), _)| mine <= other)
        }))
    }
}
