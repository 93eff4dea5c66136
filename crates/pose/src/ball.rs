//! Bodies seen through two markers, posed through a ball joint on a posed body (or on the
//! camera frame).
//!
//! Clinical marker sets put two markers on a hand or a foot and the others on the joint
//! axes of the segment above, so Kabsch-Umeyama cannot pose the segment and its joint is
//! lost. If it turns about a point fixed in a posed body, each of its markers stays at a
//! fixed distance from that point in the posed body's frame: a sphere fit over the frames
//! gives the centre, and the centre with two markers off its line fixes the pose.

use kinetree_core::geom::{centroid, kabsch};
use kinetree_core::nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, Vector3};
use kinetree_core::{BodyPoses, BodyTrack, PoseQuality, Tracks};

/// Default of [`BallLimits::min_frames`].
pub const MIN_BALL_FRAMES: usize = 10;

/// Default of [`BallLimits::min_lever_in_sigma`].
pub const MIN_BALL_LEVER_IN_SIGMA: f64 = 3.0;

/// Rounds of alternation between the poses and the shape.
const SHAPE_ROUNDS: usize = 5;

/// Most Gauss-Newton steps of the sphere fit.
const SPHERE_STEPS: usize = 20;

/// When [`balled_body`] can fit a ball joint at all.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BallLimits {
    /// Fewest frames in which the parent is posed and two of the group's keypoints are
    /// visible (default 10).
    pub min_frames: usize,
    /// The centre and the visible keypoints must spread at least this many noise std-devs
    /// (RMS along their second principal direction) for a frame to be posed, else the turn
    /// about the keypoints' line is not determined (default 3).
    pub min_lever_in_sigma: f64,
    /// Whether a group that no frame shows whole is fitted, its shape linked through the
    /// frames that show parts of it (default false: a frame must show every keypoint).
    /// Posing a body the clustering found, as a link seen a few keypoints at a time, needs
    /// it; making a body of leftover keypoints asks for the stronger evidence of one frame
    /// that shows them all.
    pub partial_views: bool,
}

impl Default for BallLimits {
    fn default() -> Self {
        Self {
            min_frames: MIN_BALL_FRAMES,
            min_lever_in_sigma: MIN_BALL_LEVER_IN_SIGMA,
            partial_views: false,
        }
    }
}

/// A group of keypoints posed through a ball joint on `parent`.
#[derive(Debug, Clone, PartialEq)]
pub struct Ball {
    /// The body it turns on (`None`: the camera frame).
    pub parent: Option<usize>,
    /// The joint's centre in the parent's body frame.
    pub centre: Point3<f64>,
    /// Covariance of the centre per unit noise variance (parent frame), from the sphere fit.
    pub centre_cov_per_sigma2: Matrix3<f64>,
    /// Standard deviation of the centre along its worst direction, in noise std-devs: a
    /// hinge leaves the centre free along its axis, and a small swing leaves it loose.
    pub centre_std_in_sigma: f64,
    /// RMS distance of the keypoints from their mean places in the parent's frame, in noise
    /// std-devs: about 1.7 (three coordinates of noise) for a group rigid with the parent,
    /// which fits spheres of any small centre.
    pub swing_in_sigma: f64,
    /// Residual of the keypoints' distances from the centre about their means:
    /// `chi^2 / dof` against the noise along the radius (each keypoint's own plus the parent's
    /// pose noise at its lever arm).
    pub chi2_per_dof: f64,
    /// Degrees of freedom of that `chi^2`.
    pub dof: f64,
    /// RMS of those distances about their means, metres; among balls on different bodies it
    /// favours the one that explains the keypoints best.
    pub rms_residual_m: f64,
    /// The group's poses: frames where the parent is posed and the centre with the visible
    /// keypoints spreads enough, with the precision propagated from the parent's pose, the
    /// keypoints' noise and the centre's.
    pub track: BodyTrack,
}

/// The centre of spheres, one radius per keypoint, through the samples `z[k]` (parent
/// frame): an algebraic fit (`|q|^2 = 2 q.c + e_k`, linear in `c` and `e_k`) refined by
/// Gauss-Newton on the geometric residuals with the radii eliminated. Returns the centre and
/// its normal matrix `A` (`cov(c) = sigma^2 A^-1`).
fn sphere_centre(z: &[Vec<Option<Point3<f64>>>]) -> Option<(Point3<f64>, Matrix3<f64>)> {
    let m = z.len();
    let origin = centroid(&z[0].iter().flatten().copied().collect::<Vec<_>>());
    let cols = 3 + m;
    let (mut ata, mut atb) = (
        DMatrix::<f64>::zeros(cols, cols),
        DVector::<f64>::zeros(cols),
    );
    let mut row = DVector::<f64>::zeros(cols);
    for (k, zk) in z.iter().enumerate() {
        for p in zk.iter().flatten() {
            let q = p - origin;
            row.fill(0.0);
            row[0] = 2.0 * q.x;
            row[1] = 2.0 * q.y;
            row[2] = 2.0 * q.z;
            row[3 + k] = 1.0;
            ata += &row * row.transpose();
            atb += &row * q.norm_squared();
        }
    }
    let sol = ata.cholesky()?.solve(&atb);
    let mut c = origin + Vector3::new(sol[0], sol[1], sol[2]);
    let mut normal = Matrix3::zeros();
    for _ in 0..SPHERE_STEPS {
        let (mut a, mut g) = (Matrix3::zeros(), Vector3::zeros());
        for zk in z {
            let units: Vec<(Vector3<f64>, f64)> = zk
                .iter()
                .flatten()
                .map(|p| {
                    let d = p - c;
                    let r = d.norm();
                    (d / r.max(f64::MIN_POSITIVE), r)
                })
                .collect();
            let n = units.len() as f64;
            let mean_n = units.iter().map(|(u, _)| u).sum::<Vector3<f64>>() / n;
            let mean_r = units.iter().map(|(_, r)| r).sum::<f64>() / n;
            for (u, r) in &units {
                let du = u - mean_n;
                a += du * du.transpose();
                g += du * (r - mean_r);
            }
        }
        normal = a;
        let step = a.try_inverse()? * g;
        c += step;
        if !c.coords.iter().all(|x| x.is_finite()) {
            return None;
        }
        if step.norm() <= 1e-12 * (1.0 + c.coords.norm()) {
            break;
        }
    }
    Some((c, normal))
}

/// Rotation and origin covariances (body frame, per unit noise variance) of an unweighted
/// Kabsch fit of `points` (body frame) whose noise variances per unit noise variance are
/// `var`: the sandwich `J^-1 M J^-1`, with `J = sum (|d|^2 I - d d^T)` and `M` the same
/// sum weighted by `var`, `d` about the points' centroid; the origin's adds the centroid's
/// `sum var / n^2` to the rotation's at the centroid's lever arm.
fn kabsch_covariances(points: &[Point3<f64>], var: &[f64]) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    let g = centroid(points);
    let (mut j, mut mw) = (Matrix3::zeros(), Matrix3::zeros());
    for (p, v) in points.iter().zip(var) {
        let d = p - g;
        let block = Matrix3::identity() * d.norm_squared() - d * d.transpose();
        j += block;
        mw += block * *v;
    }
    let ji = j.try_inverse()?;
    let rot = ji * mw * ji;
    let n = points.len() as f64;
    let gx = g.coords.cross_matrix();
    let origin =
        Matrix3::identity() * (var.iter().sum::<f64>() / (n * n)) + gx * rot * gx.transpose();
    Some((rot, origin))
}

/// The group's first shape, keypoints then the centre, in the parent's frame at one frame:
/// the first of `frames` that shows every keypoint of `z` (samples in the parent's frame by
/// keypoint and frame). A body seen only in part at a time (an occluded link) has no such
/// frame; with `partial_views` its shape starts from the frame that shows the most
/// keypoints, and each other keypoint is placed from a frame that shows it with two placed
/// ones, posed on those and the centre (Kabsch-Umeyama), the frame with the most placed
/// keypoints first. `None` without such a frame and `partial_views`, or when a keypoint is
/// never seen with two placed ones.
fn initial_shape(
    z: &[Vec<Option<Point3<f64>>>],
    frames: &[usize],
    centre: Point3<f64>,
    partial_views: bool,
) -> Option<Vec<Point3<f64>>> {
    let m = z.len();
    let seen = |t: usize| (0..m).filter(|&k| z[k][t].is_some()).count();
    let mut shape: Vec<Option<Point3<f64>>> = match frames.iter().find(|&&t| seen(t) == m) {
        Some(&t0) => z.iter().map(|zk| zk[t0]).collect(),
        None if !partial_views => return None,
        None => {
            // The earliest of the frames that show the most keypoints.
            let most = frames.iter().map(|&t| seen(t)).max()?;
            let t0 = *frames.iter().find(|&&t| seen(t) == most)?;
            z.iter().map(|zk| zk[t0]).collect()
        }
    };
    while shape.iter().any(Option::is_none) {
        // The frame that shows an unplaced keypoint with the most placed ones (at least
        // two), the earliest among equals.
        let placed_in = |t: usize| -> Vec<usize> {
            (0..m)
                .filter(|&k| shape[k].is_some() && z[k][t].is_some())
                .collect()
        };
        let best = frames
            .iter()
            .copied()
            .filter(|&t| (0..m).any(|k| shape[k].is_none() && z[k][t].is_some()))
            .map(|t| (placed_in(t).len(), t))
            .filter(|&(n, _)| n >= 2)
            .max_by(|x, y| x.0.cmp(&y.0).then(y.1.cmp(&x.1)));
        let (_, t) = best?;
        let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = placed_in(t)
            .into_iter()
            .filter_map(|k| Some((shape[k]?, z[k][t]?)))
            .chain(std::iter::once((centre, centre)))
            .unzip();
        let rel = kabsch(&src, &dst)?;
        for k in 0..m {
            if shape[k].is_none()
                && let Some(p) = z[k][t]
            {
                shape[k] = Some(rel.inverse_transform_point(&p));
            }
        }
    }
    let mut out: Vec<Point3<f64>> = shape.into_iter().collect::<Option<Vec<_>>>()?;
    out.push(centre);
    Some(out)
}

/// Fits a ball joint between `parent`'s poses (`None`: the camera frame) and the keypoints
/// `points`, and poses them through it. Returns `None` for a parent that is not a body of
/// `poses`, a noise level that is not a positive number, tracks and poses of different
/// lengths, and when the data cannot support the hypothesis at all: fewer than two
/// keypoints, a keypoint with under 3 frames or under [`BallLimits::min_frames`] frames
/// with the parent posed and two keypoints visible, a singular sphere fit, a keypoint never
/// seen with two others (without [`BallLimits::partial_views`], no frame that shows every
/// keypoint), or no frame in which the centre and the visible keypoints spread. Whether the
/// ball *holds* is the caller's decision, from [`Ball::chi2_per_dof`], [`Ball::rms_residual_m`],
/// [`Ball::centre_std_in_sigma`] and [`Ball::swing_in_sigma`], and from `group_rigidity` (the
/// same for every parent).
///
/// Method: in the parent's frame every keypoint stays on a sphere about the centre, so the
/// centre is the common centre of spheres with one radius per keypoint (`sphere_centre`).
/// The group's shape (keypoints and centre, body frame) and its poses relative to the
/// parent (Kabsch on the centre and the visible keypoints) are then refined in turn, from
/// one frame's shape or, with [`BallLimits::partial_views`], from one linked through the
/// frames that show parts of the group (`initial_shape`). Each frame's stated precision
/// holds the parent pose's, the keypoints' and the centre's.
///
/// Complexity: O(T m) per sphere step and per shape round for m keypoints.
pub fn balled_body(
    tracks: &Tracks,
    poses: &BodyPoses,
    parent: Option<usize>,
    points: &[usize],
    sigma: f64,
    limits: &BallLimits,
) -> Option<Ball> {
    let m = points.len();
    let nt = poses.n_frames;
    if m < 2
        || !(sigma.is_finite() && sigma > 0.0)
        || tracks.n_frames() != nt
        || parent.is_some_and(|b| b >= poses.bodies.len())
    {
        return None;
    }
    // The parent's pose in every frame, read once.
    let parent_at: Vec<Option<(Isometry3<f64>, Option<PoseQuality>)>> = (0..nt)
        .map(|t| crate::hinge::parent_pose(poses, parent, t))
        .collect();
    let parent_pose = |t: usize| parent_at[t];
    // Samples in the parent's frame, in the frames that show two keypoints.
    let frames: Vec<usize> = (0..nt)
        .filter(|&t| {
            points
                .iter()
                .filter(|&&i| tracks.get(t, i).is_some())
                .count()
                >= 2
                && parent_at[t].is_some()
        })
        .collect();
    let mut z: Vec<Vec<Option<Point3<f64>>>> = vec![vec![None; nt]; m];
    for (zk, &i) in z.iter_mut().zip(points) {
        for &t in &frames {
            let pose = parent_pose(t)?.0;
            zk[t] = tracks.get(t, i).map(|x| pose.inverse_transform_point(&x));
        }
    }
    if frames.len() < limits.min_frames || z.iter().any(|zk| zk.iter().flatten().count() < 3) {
        return None;
    }
    // How far the keypoints move in the parent's frame: RMS about each one's mean.
    let (mut moved, mut n_moved) = (0.0, 0usize);
    for zk in &z {
        let pts: Vec<Point3<f64>> = zk.iter().flatten().copied().collect();
        let mean = centroid(&pts);
        moved += pts.iter().map(|p| (p - mean).norm_squared()).sum::<f64>();
        n_moved += pts.len();
    }
    let swing_in_sigma = (moved / n_moved as f64).sqrt() / sigma;
    let (centre, normal) = sphere_centre(&z)?;
    let centre_cov = normal.try_inverse()?;
    let centre_var = kinetree_core::geom::symmetric_eigenvalues_3x3(&centre_cov)[0].max(0.0);
    // The distances' residuals about each keypoint's mean.
    let radius: Vec<f64> = z
        .iter()
        .map(|zk| {
            let d: Vec<f64> = zk.iter().flatten().map(|p| (p - centre).norm()).collect();
            d.iter().sum::<f64>() / d.len() as f64
        })
        .collect();
    let (mut chi2, mut sum_sq, mut n_samples) = (0.0, 0.0, 0usize);
    for &t in &frames {
        let (_, pq) = parent_pose(t)?;
        for (zk, r) in z.iter().zip(&radius) {
            let Some(p) = zk[t] else { continue };
            let d = p - centre;
            let e = d.norm() - r;
            // The keypoint's noise along the radius, and the parent pose's error moving it
            // there (origin, and rotation at its lever arm; their correlation left out).
            let n = d / d.norm().max(f64::MIN_POSITIVE);
            let var = 1.0
                + pq.map_or(0.0, |q| {
                    let px = p.coords.cross_matrix();
                    let c = q.origin_cov_per_sigma2 + px * q.rot_cov_per_sigma2 * px.transpose();
                    n.dot(&(c * n))
                });
            chi2 += e * e / (sigma * sigma * var);
            sum_sq += e * e;
            n_samples += 1;
        }
    }
    let dof = n_samples as f64 - (3 + m) as f64;
    if dof < 1.0 {
        return None;
    }
    // Shape (keypoints, then the centre) and relative poses, in turn, from the first frame
    // that shows every keypoint, or else linked through the frames that show some.
    let mut shape = initial_shape(&z, &frames, centre, limits.partial_views)?;
    let lever_ok = |shape: &[Point3<f64>], t: usize| {
        let pts: Vec<Point3<f64>> = (0..m)
            .filter(|&k| z[k][t].is_some())
            .map(|k| shape[k])
            .chain(std::iter::once(shape[m]))
            .collect();
        crate::spread(&pts)[1] >= limits.min_lever_in_sigma * sigma
    };
    let relative = |shape: &[Point3<f64>], t: usize| -> Option<Isometry3<f64>> {
        let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = (0..m)
            .filter_map(|k| Some((shape[k], z[k][t]?)))
            .chain(std::iter::once((shape[m], centre)))
            .unzip();
        kabsch(&src, &dst)
    };
    let mut posed: Vec<(usize, Isometry3<f64>)> = Vec::new();
    for _ in 0..SHAPE_ROUNDS {
        posed = frames
            .iter()
            .filter(|&&t| lever_ok(&shape, t))
            .filter_map(|&t| Some((t, relative(&shape, t)?)))
            .collect();
        if posed.is_empty() {
            return None;
        }
        let mut acc = vec![(Vector3::zeros(), 0usize); m + 1];
        for (t, rel) in &posed {
            for (k, zk) in z.iter().enumerate() {
                if let Some(p) = zk[*t] {
                    acc[k].0 += rel.inverse_transform_point(&p).coords;
                    acc[k].1 += 1;
                }
            }
            acc[m].0 += rel.inverse_transform_point(&centre).coords;
            acc[m].1 += 1;
        }
        for (s, (sum, n)) in shape.iter_mut().zip(&acc) {
            if *n > 0 {
                *s = Point3::from(sum / *n as f64);
            }
        }
    }
    // Body frame: origin at the keypoints' centroid, axes the camera's in the first posed
    // frame (as `BodyTrack` has it).
    let (t_ref, rel_ref) = *posed.first()?;
    let cam_from_s = parent_pose(t_ref)?.0 * rel_ref;
    let in_cam: Vec<Point3<f64>> = shape[..m].iter().map(|s| cam_from_s * s).collect();
    let body_from_s =
        kinetree_core::nalgebra::Translation3::from(-centroid(&in_cam).coords) * cam_from_s;
    let body_shape: Vec<Point3<f64>> = shape.iter().map(|s| body_from_s * s).collect();
    let mut cam_from_body = vec![None; nt];
    let mut quality = vec![None; nt];
    for &(t, _) in &posed {
        let mut src = Vec::with_capacity(m + 1);
        let mut dst = Vec::with_capacity(m + 1);
        let mut var = Vec::with_capacity(m + 1);
        for (k, zk) in z.iter().enumerate() {
            if let Some(p) = zk[t] {
                src.push(body_shape[k]);
                dst.push(p);
                var.push(1.0);
            }
        }
        src.push(body_shape[m]);
        dst.push(centre);
        var.push(centre_var);
        // Parent from body.
        let Some(rel) = kabsch(&src, &dst) else {
            continue;
        };
        let Some((own_rot, own_origin)) = kabsch_covariances(&src, &var) else {
            continue;
        };
        let (pose, pq) = parent_pose(t)?;
        let (rot_p, orig_p) = pq.map_or((Matrix3::zeros(), Matrix3::zeros()), |q| {
            (q.rot_cov_per_sigma2, q.origin_cov_per_sigma2)
        });
        let rm = rel.rotation.to_rotation_matrix().into_inner();
        let ox = rel.translation.vector.cross_matrix();
        let rot_cov = rm.transpose() * rot_p * rm + own_rot;
        let origin_cov = rm.transpose() * (orig_p + ox * rot_p * ox.transpose()) * rm + own_origin;
        let n_vis = src.len() - 1;
        let sq: f64 = src[..n_vis]
            .iter()
            .zip(&dst)
            .map(|(s, d)| (rel * s - d).norm_squared())
            .sum();
        cam_from_body[t] = Some(pose * rel);
        quality[t] = Some(PoseQuality::from_covariances(
            n_vis,
            (sq / n_vis as f64).sqrt(),
            rot_cov,
            origin_cov,
        ));
    }
    let reference_frame = (0..nt).find(|&t| cam_from_body[t].is_some())?;
    let n_posed = cam_from_body.iter().filter(|p| p.is_some()).count();
    Some(Ball {
        parent,
        centre,
        centre_cov_per_sigma2: centre_cov,
        centre_std_in_sigma: centre_var.sqrt(),
        swing_in_sigma,
        chi2_per_dof: chi2 / dof,
        dof,
        rms_residual_m: (sum_sq / n_samples as f64).sqrt(),
        track: BodyTrack {
            points: points.to_vec(),
            shape: body_shape[..m].to_vec(),
            placed: vec![true; m],
            reference_frame,
            cam_from_body,
            quality,
            frames_too_few_points: nt - n_posed,
            frames_degenerate: 0,
        },
    })
}
