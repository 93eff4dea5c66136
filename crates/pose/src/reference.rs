//! Per-body reference shapes built from all frames, and the pose estimator on top of them.

use crate::kabsch::{centroid, kabsch, rotation_cov_per_sigma2, spread};
use kinetree_core::nalgebra::{Isometry3, Matrix3, Point3, Translation3};
use kinetree_core::{
    BodyPoses, BodyTrack, Error, PoseEstimator, PoseInput, PoseQuality, Result, Tracks,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;

/// Parameters of [`KabschPoses`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KabschParams {
    /// Rounds of shape re-estimation (generalised Procrustes); each round can also place
    /// points first seen together with already placed ones.
    pub shape_passes: usize,
    /// Gauss-Newton steps of the shape after the passes, the poses eliminated (see
    /// `crate::shape`), stopped early once no point moves by a thousandth of the noise.
    /// 0 keeps the plain alternation.
    pub shape_steps: usize,
    /// A frame's visible points must spread at least this many noise std-devs along their
    /// second principal axis, else they count as collinear and the frame gets no pose.
    pub min_spread_in_sigma: f64,
    /// A body whose points, in the frame that shows the most of them, spread along their
    /// second principal axis by less than this share of their spread along the first is
    /// slender (a rod: its points nearly on a line; default 0.1)...
    pub slender_aspect: f64,
    /// ... and its frames need only this many noise std-devs of spread (default 0.5): every
    /// frame of a rod is nearly collinear, and its pose's precision (poor about the rod's
    /// own axis) goes with it into the pair tests (`docs/decisions.md`,
    /// `pose.slender_aspect`).
    pub slender_min_spread_in_sigma: f64,
    /// Robust fitting: the point with the largest residual, if above this many noise
    /// std-devs (per coordinate, so `sqrt 3` of them is typical), is left out of its frame's
    /// fit and of the shape, and the frame is refitted, up to `ROBUST_ROUNDS` points per
    /// frame. `None` (the default) fits every visible point. Survives mistracked keypoints as
    /// long as three good, non-collinear points remain in the frame.
    pub outlier_in_sigma: Option<f64>,
}

/// Most points left out per frame in the robust mode.
pub const ROBUST_ROUNDS: usize = 4;

impl Default for KabschParams {
    fn default() -> Self {
        Self {
            shape_passes: 4,
            shape_steps: 10,
            min_spread_in_sigma: 1.0,
            slender_aspect: 0.1,
            slender_min_spread_in_sigma: 0.5,
            outlier_in_sigma: None,
        }
    }
}

impl KabschParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for passes outside `1..=1000` (each is a pass over every
    /// frame) or a negative spread.
    pub fn validate(&self) -> Result<()> {
        kinetree_core::limits::check_count("shape_passes", self.shape_passes, 1, 1000)?;
        if let Some(k) = self.outlier_in_sigma
            && !(k.is_finite() && k > 0.0)
        {
            return Err(Error::InvalidParameter {
                name: "outlier_in_sigma".into(),
                message: format!("must be finite and positive, got {k}"),
            });
        }
        for (name, value) in [
            ("min_spread_in_sigma", self.min_spread_in_sigma),
            ("slender_aspect", self.slender_aspect),
            (
                "slender_min_spread_in_sigma",
                self.slender_min_spread_in_sigma,
            ),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(Error::InvalidParameter {
                    name: name.into(),
                    message: format!("must be finite and >= 0, got {value}"),
                });
            }
        }
        Ok(())
    }
}

/// Kabsch-Umeyama poses against a per-body reference shape built from every frame.
///
/// The shape starts from the frame where the body shows the most points and is refined over
/// `shape_passes` rounds: each frame with three or more placed, non-collinear visible points is
/// registered to the current shape and its points, mapped back, are averaged. Any frame with
/// three such points then gets a pose, even if it shares none with frame 0. Up to
/// `shape_steps` Gauss-Newton steps of the shape, with the poses eliminated, then finish what
/// the alternation leaves where occlusion changes the visible subset from frame to frame.
///
/// Reference-pose rule: the body frame has its origin at the shape's centroid and the camera's
/// axes at the body's reference frame, which is frame 0 when the body can be registered there
/// and otherwise the first frame where it can (so `cam_from_body` there is a pure translation,
/// as the paper's `P_0 = P_1` choice).
///
/// Complexity: O(passes * T * n_b) per body, plus per Gauss-Newton step O(T * v^2) with v
/// points visible per frame and O(n_b^3) for its solve (bodies of up to 200 placed points;
/// larger ones keep the alternation's shape).
#[derive(Debug, Clone)]
pub struct KabschPoses {
    params: KabschParams,
}

impl KabschPoses {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: KabschParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }

    fn body_track(&self, tracks: &Tracks, points: &[usize], sigma: f64) -> BodyTrack {
        let t_len = tracks.n_frames();
        let nb = points.len();
        // Each frame's observations are kept in a buffer of their exact size: a buffer grown
        // by doubling leaves up to half of itself unused, a large share of the bodies' memory
        // over long recordings of many points.
        let obs: Vec<Vec<(usize, Point3<f64>)>> = (0..t_len)
            .into_par_iter()
            .map(|t| {
                let mut seen = Vec::with_capacity(nb);
                seen.extend(
                    points
                        .iter()
                        .enumerate()
                        .filter_map(|(k, &p)| tracks.get(t, p).map(|q| (k, q))),
                );
                seen.shrink_to_fit();
                seen
            })
            .collect();
        let mut order: Vec<usize> = (0..t_len).collect();
        order.sort_by_key(|&t| std::cmp::Reverse(obs[t].len()));
        let points_of = |t: usize| obs[t].iter().map(|o| o.1).collect::<Vec<_>>();
        let fullest = order.first().map_or([0.0; 3], |&t| spread(&points_of(t)));
        let slender = fullest[1] < self.params.slender_aspect * fullest[0];
        let min_spread = sigma
            * if slender {
                self.params.slender_min_spread_in_sigma
            } else {
                self.params.min_spread_in_sigma
            };
        let usable = |pts: &[Point3<f64>]| pts.len() >= 3 && spread(pts)[1] > min_spread.max(1e-12);
        // Initial shape: the first frame (most points) whose points are usable.
        let mut shape: Vec<Option<Point3<f64>>> = vec![None; nb];
        if let Some(&t0) = order
            .iter()
            .find(|&&t| usable(&obs[t].iter().map(|o| o.1).collect::<Vec<_>>()))
        {
            for &(k, q) in &obs[t0] {
                shape[k] = Some(q);
            }
        }
        // The pose of frame `t` against `shape`, and which of `obs[t]` it used (all placed
        // points, or in the robust mode those within the outlier bound of the final fit).
        let outlier = self.params.outlier_in_sigma.map(|k| k * sigma.max(1e-12));
        let fit_with = |shape: &[Option<Point3<f64>>], t: usize| {
            let mut used: Vec<bool> = obs[t].iter().map(|&(k, _)| shape[k].is_some()).collect();
            let mut pose = None;
            for _ in 0..=outlier.map_or(0, |_| ROBUST_ROUNDS) {
                let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = obs[t]
                    .iter()
                    .zip(&used)
                    .filter(|(_, u)| **u)
                    .filter_map(|(&(k, q), _)| shape[k].map(|s| (s, q)))
                    .unzip();
                if !usable(&src) {
                    break;
                }
                pose = kabsch(&src, &dst);
                let (Some(p), Some(bound)) = (pose, outlier) else {
                    break;
                };
                // Leave out the worst point if it is beyond the bound, then refit: one at a
                // time, because a gross outlier drags the first fit and pushes good points'
                // residuals over the bound too.
                let worst = obs[t]
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| used[*i])
                    .filter_map(|(i, &(k, q))| shape[k].map(|s| (i, (p * s - q).norm())))
                    .max_by(|a, b| a.1.total_cmp(&b.1));
                match worst {
                    Some((i, r)) if r > bound => used[i] = false,
                    _ => break,
                }
            }
            pose.map(|p| (p, used))
        };
        // The frames' fits are independent and run in parallel; what they add up to is
        // summed in one fixed order, so the result does not depend on the thread count.
        for _ in 0..self.params.shape_passes {
            let mut sums = vec![kinetree_core::nalgebra::Vector3::zeros(); nb];
            let mut counts = vec![0usize; nb];
            let fits: Vec<_> = order.par_iter().map(|&t| fit_with(&shape, t)).collect();
            for (&t, fitted) in order.iter().zip(fits) {
                if let Some((pose, used)) = fitted {
                    let inv = pose.inverse();
                    // Unplaced points join the shape here; robustly rejected ones do not.
                    for (&(k, q), u) in obs[t].iter().zip(&used) {
                        if *u || shape[k].is_none() {
                            sums[k] += (inv * q).coords;
                            counts[k] += 1;
                        }
                    }
                }
            }
            for k in 0..nb {
                if counts[k] > 0 {
                    shape[k] = Some(Point3::from(sums[k] / counts[k] as f64));
                }
            }
        }
        // The alternation crawls where frames see different subsets of the points (see
        // `crate::shape`); Gauss-Newton steps with the poses eliminated finish the job.
        // A step is kept when no frame loses its pose and the residual (poses refitted) does
        // not rise, else halved up to three times (far from the optimum a full step can
        // overshoot, and a frame of nearly collinear points can make it large).
        // Every frame registered to `shape`: its pose (`None` where it cannot be registered),
        // the registered frames' observations for the step, and their squared residual.
        let register = |shape: &[Option<Point3<f64>>]| {
            // Each frame's fit, kept observations and squared residual, in parallel; the
            // residuals are summed in frame order.
            let fitted: Vec<Option<(crate::shape::FrameObs, f64)>> = (0..t_len)
                .into_par_iter()
                .map(|t| {
                    let (pose, used) = fit_with(shape, t)?;
                    let enters =
                        |(o, u): (&(usize, Point3<f64>), &bool)| *u && shape[o.0].is_some();
                    let seen = || obs[t].iter().zip(&used);
                    let kept: Cow<[(usize, Point3<f64>)]> =
                        if used.len() == obs[t].len() && seen().all(enters) {
                            Cow::Borrowed(&obs[t])
                        } else {
                            Cow::Owned(seen().filter(|&e| enters(e)).map(|(o, _)| *o).collect())
                        };
                    let cost = kept
                        .iter()
                        .filter_map(|&(k, q)| shape[k].map(|s| (pose * s - q).norm_squared()))
                        .sum::<f64>();
                    Some(((pose, kept), cost))
                })
                .collect();
            let mut cost = 0.0;
            let mut poses: Vec<Option<Isometry3<f64>>> = Vec::with_capacity(t_len);
            let mut frames: Vec<crate::shape::FrameObs> = Vec::with_capacity(t_len);
            for entry in fitted {
                match entry {
                    Some((frame, c)) => {
                        cost += c;
                        poses.push(Some(frame.0));
                        frames.push(frame);
                    }
                    None => poses.push(None),
                }
            }
            (frames, cost, poses)
        };
        let tolerance = 1e-3 * sigma.max(1e-9);
        let mut current = register(&shape);
        for _ in 0..self.params.shape_steps {
            let Some(step) = crate::shape::gauss_newton_step(&shape, &current.0) else {
                break;
            };
            let largest = step.iter().map(|d| d.norm()).fold(0.0, f64::max);
            if !largest.is_finite() {
                break;
            }
            let mut scale = 1.0;
            let mut kept = false;
            for _ in 0..4 {
                let trial: Vec<Option<Point3<f64>>> = shape
                    .iter()
                    .zip(&step)
                    .map(|(s, d)| s.map(|s| s + d * scale))
                    .collect();
                let next = register(&trial);
                if next.0.len() >= current.0.len() && next.1 <= current.1 {
                    (shape, current, kept) = (trial, next, true);
                    break;
                }
                scale *= 0.5;
            }
            if !kept || largest * scale < tolerance {
                break;
            }
        }
        let placed: Vec<Point3<f64>> = shape.iter().flatten().copied().collect();
        // The poses of the last registration, which was to this shape.
        let mut poses = current.2;
        let reference_frame = poses.iter().position(Option::is_some).unwrap_or(0);
        // Re-express the shape in the body frame: camera axes at the reference frame, origin at
        // the centroid of the placed points.
        let mut body_shape = vec![Point3::origin(); nb];
        if let Some(p_ref) = poses[reference_frame] {
            let c = centroid(&placed.iter().map(|s| p_ref * s).collect::<Vec<_>>());
            let body_from_shape = Translation3::from(-c.coords) * p_ref;
            for k in 0..nb {
                if let Some(s) = shape[k] {
                    body_shape[k] = body_from_shape * s;
                }
            }
            let shape_from_body = body_from_shape.inverse();
            for p in poses.iter_mut().flatten() {
                *p *= shape_from_body;
            }
        }
        // Each frame's quality, in parallel; an unregistered frame's is `Err(true)` when it
        // shows too few points and `Err(false)` when they are degenerate.
        let judged: Vec<std::result::Result<PoseQuality, bool>> = (0..t_len)
            .into_par_iter()
            .map(|t| {
                let vis: Vec<(Point3<f64>, Point3<f64>)> = obs[t]
                    .iter()
                    .filter(|(k, _)| shape[*k].is_some())
                    .map(|&(k, q)| (body_shape[k], q))
                    .collect();
                let Some(pose) = poses[t] else {
                    return Err(vis.len() < 3);
                };
                // In the robust mode the quality describes the points the fit kept.
                let vis: Vec<(Point3<f64>, Point3<f64>)> = match outlier {
                    Some(bound) => vis
                        .into_iter()
                        .filter(|(s, q)| (pose * s - q).norm() <= bound)
                        .collect(),
                    None => vis,
                };
                let src: Vec<Point3<f64>> = vis.iter().map(|v| v.0).collect();
                let n = src.len() as f64;
                let rms = (vis
                    .iter()
                    .map(|(s, q)| (pose * s - q).norm_squared())
                    .sum::<f64>()
                    / n)
                    .sqrt();
                // A fit on collinear points never gets here (see `usable`); a huge finite variance
                // keeps the matrix free of the NaN that infinity times zero would put off the
                // diagonal.
                let rot_cov =
                    rotation_cov_per_sigma2(&src).unwrap_or_else(|| Matrix3::identity() * 1e12);
                let c = centroid(&src).coords.cross_matrix();
                let origin_cov = Matrix3::identity() / n + c * rot_cov * c.transpose();
                Ok(PoseQuality::from_covariances(
                    vis.len(),
                    rms,
                    rot_cov,
                    origin_cov,
                ))
            })
            .collect();
        let too_few = judged.iter().filter(|q| matches!(q, Err(true))).count();
        let degenerate = judged.iter().filter(|q| matches!(q, Err(false))).count();
        let quality: Vec<Option<PoseQuality>> = judged.into_iter().map(|q| q.ok()).collect();
        BodyTrack {
            points: points.to_vec(),
            shape: body_shape,
            placed: shape.iter().map(Option::is_some).collect(),
            reference_frame,
            cam_from_body: poses,
            quality,
            frames_too_few_points: too_few,
            frames_degenerate: degenerate,
        }
    }
}

impl PoseEstimator for KabschPoses {
    fn name(&self) -> &str {
        "kabsch"
    }

    fn estimate(&self, input: &PoseInput<'_>) -> Result<BodyPoses> {
        let seg = input.segmentation;
        if seg.n_points() != input.tracks.n_points() {
            return Err(Error::Shape {
                expected: format!("segmentation of {} points", input.tracks.n_points()),
                found: format!("{} points", seg.n_points()),
            });
        }
        if !(input.noise_sigma_m.is_finite() && input.noise_sigma_m >= 0.0) {
            return Err(Error::InvalidParameter {
                name: "noise_sigma_m".into(),
                message: format!("must be finite and >= 0, got {}", input.noise_sigma_m),
            });
        }
        // Bodies are posed independently: in parallel, collected in body order.
        let bodies = seg
            .members()
            .par_iter()
            .map(|pts| self.body_track(input.tracks, pts, input.noise_sigma_m))
            .collect();
        Ok(BodyPoses {
            n_frames: input.tracks.n_frames(),
            bodies,
        })
    }
}
