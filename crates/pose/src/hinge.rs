//! Bodies seen too few points at a time to be registered on their own, posed through a hinge
//! on a body that is (or on the camera frame).
//!
//! A link hidden by its neighbours may show one or two keypoints per frame and never three,
//! so Kabsch-Umeyama cannot pose it, and every joint below it looks multi-DoF. If it turns on
//! a posed body about one axis, each of its keypoints moves on a circle about that axis in
//! the posed body's frame, and one visible keypoint off the axis fixes the angle. This module
//! fits that hypothesis to a group of keypoints and, when it holds, poses the group in every
//! frame where one of them is visible; the pair tests then treat the group like any body.

use kinetree_core::geom::{cam_from, unwrap_angles};
use kinetree_core::nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix3x2, Matrix3x4, Matrix4, Point3, Translation3,
    Unit, UnitQuaternion, Vector2, Vector3,
};
use kinetree_core::{BodyPoses, BodyTrack, PoseQuality, Tracks};

/// Default of [`HingeLimits::min_frames`].
pub const MIN_HINGE_FRAMES: usize = 10;

/// Default of [`HingeLimits::min_spread_in_sigma`].
pub const MIN_HINGE_SPREAD_IN_SIGMA: f64 = 5.0;

/// Default of [`HingeLimits::min_lever_in_sigma`].
pub const MIN_LEVER_IN_SIGMA: f64 = 3.0;

/// When [`hinged_body`] can fit a hinge at all.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HingeLimits {
    /// Fewest frames in which the parent is posed and a keypoint of the group is visible
    /// (default 10).
    pub min_frames: usize,
    /// The keypoint tracks must spread at least this many noise std-devs (RMS about their
    /// means) across the axis in the weaker in-plane direction, else the plane of the
    /// circles, hence the axis, is not determined (default 5).
    pub min_spread_in_sigma: f64,
    /// A keypoint nearer the axis than this many noise std-devs does not tell the angle
    /// (default 3).
    pub min_lever_in_sigma: f64,
}

impl Default for HingeLimits {
    fn default() -> Self {
        Self {
            min_frames: MIN_HINGE_FRAMES,
            min_spread_in_sigma: MIN_HINGE_SPREAD_IN_SIGMA,
            min_lever_in_sigma: MIN_LEVER_IN_SIGMA,
        }
    }
}

/// Rounds of alternation between the angles and the shape after the first estimate.
const REFINE_ROUNDS: usize = 10;

/// Most Gauss-Newton steps of the whole hinge ([`refine`]).
const GAUSS_NEWTON_STEPS: usize = 10;

/// A group of keypoints posed through a hinge on `parent`.
#[derive(Debug, Clone, PartialEq)]
pub struct Hinge {
    /// The body it turns on (`None`: the camera frame).
    pub parent: Option<usize>,
    /// Unit axis in the parent's body frame.
    pub axis: Vector3<f64>,
    /// A point of the axis in the parent's body frame.
    pub pivot: Point3<f64>,
    /// Residual of the keypoints about the fitted hinge: `chi^2 / dof` against the noise
    /// (each keypoint's own noise plus the parent's pose noise at its lever arm).
    pub chi2_per_dof: f64,
    /// Degrees of freedom of that `chi^2`.
    pub dof: f64,
    /// RMS distance of the keypoints from where the hinge puts them, metres: the parent's
    /// pose noise counts in full, so among hinges on different bodies it favours the one
    /// that explains the keypoints best.
    pub rms_residual_m: f64,
    /// Angle swept (unwrapped, radians) over the median std-dev of a frame's angle.
    pub arc_in_std: f64,
    /// The group's poses: frames where the parent is posed and a keypoint off the axis is
    /// visible, with the precision propagated from the parent's pose and the angle.
    pub track: BodyTrack,
}

/// Rotation by `angle` about the line through `pivot` along unit `axis`.
fn turn(axis: &Unit<Vector3<f64>>, pivot: &Point3<f64>, angle: f64) -> Isometry3<f64> {
    let r = UnitQuaternion::from_axis_angle(axis, angle);
    Isometry3::from_parts(Translation3::from(pivot.coords - r * pivot.coords), r)
}

/// `parent`'s pose in frame `t` (`None`: the camera frame, exact) with its fit quality, as the
/// hinge and ball fits read it; `None` where the parent is not posed.
pub(crate) fn parent_pose(
    poses: &BodyPoses,
    parent: Option<usize>,
    t: usize,
) -> Option<(Isometry3<f64>, Option<PoseQuality>)> {
    let quality = parent.and_then(|b| poses.bodies[b].quality[t]);
    cam_from(poses, parent, t).map(|p| (p, quality))
}

/// Distance of `p` from the line through `pivot` along unit `a`.
fn distance_from_axis(p: &Point3<f64>, pivot: &Point3<f64>, a: &Vector3<f64>) -> f64 {
    let d = p - pivot;
    (d - a * d.dot(a)).norm()
}

/// Sum of squared distances of the samples `z[k][t]` from the hinge's prediction.
fn hinge_sse(
    z: &[Vec<Option<Point3<f64>>>],
    shape: &[Point3<f64>],
    angle: &[Option<f64>],
    a: &Vector3<f64>,
    pivot: &Point3<f64>,
) -> f64 {
    let axis = Unit::new_normalize(*a);
    let mut sse = 0.0;
    for (t, th) in angle.iter().enumerate() {
        let Some(th) = th else { continue };
        let h = turn(&axis, pivot, *th);
        for (zk, s) in z.iter().zip(shape) {
            if let Some(p) = zk[t] {
                sse += (p - h * s).norm_squared();
            }
        }
    }
    sse
}

/// Two orthonormal directions across unit axis `a`: the axis tilts and the pivot shifts
/// along them.
fn across(a: &Vector3<f64>) -> [Vector3<f64>; 2] {
    let b1 = a
        .cross(&if a.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        })
        .normalize();
    [b1, a.cross(&b1)]
}

/// The derivatives of a frame's samples by the pivot shifted along each of `basis`, for the
/// frame's turn `rot`: the same for every keypoint.
fn pivot_columns(basis: &[Vector3<f64>; 2], rot: &Matrix3<f64>) -> [Vector3<f64>; 2] {
    basis.map(|b| -(b - rot * b))
}

/// A sample's derivatives by the axis tilted along each of `basis` and the pivot shifted
/// along each (the columns; the latter are its frame's `pivot`, [`pivot_columns`]), for a
/// keypoint at `v` from the pivot at angle 0, turned by an angle of sine and cosine
/// `(sn, cs)` about unit axis `a`.
fn line_jacobian(
    a: &Vector3<f64>,
    basis: &[Vector3<f64>; 2],
    v: &Vector3<f64>,
    (sn, cs): (f64, f64),
    pivot: &[Vector3<f64>; 2],
) -> Matrix3x4<f64> {
    let mut line = Matrix3x4::zeros();
    for (j, b) in basis.iter().enumerate() {
        let da = -(b.cross(v) * sn + (b * a.dot(v) + a * b.dot(v)) * (1.0 - cs));
        line.set_column(j, &da);
        line.set_column(2 + j, &pivot[j]);
    }
    line
}

/// Gauss-Newton on every unknown of the hinge at once: axis direction (2), pivot across the
/// axis (2), the shape at angle 0 (3 per keypoint) and one angle per posed frame, the angles
/// eliminated frame by frame (each is one unknown, so its block is a scalar). A ridge of
/// 1e-9 of the mean diagonal fixes the gauge (the angles' zero against a turn of the shape
/// about the axis). A step is kept when the squared residual does not rise, else halved up
/// to 3 times; the iteration stops after [`GAUSS_NEWTON_STEPS`] or when no keypoint moves
/// by 1e-9 m.
///
/// Our own: no crate in the workspace fits a model with per-frame nuisance parameters, and
/// the Schur elimination keeps the solve at the size of the shape (4 + 3m unknowns).
///
/// Derivatives of a sample's residual `r = z - p - R(a, th) (s - p)`, with `v = s - p` and
/// `b` across the axis: `dr/dth = -a x R v`, `dr/ds = -R`, `dr/dp = -(I - R) b`, and for the
/// axis tilted towards `b`, `-( (b x v) sin th + (b (a.v) + a (b.v)) (1 - cos th) )`.
/// The hinge's normal equations with the angles eliminated (see [`refine`]): the Schur
/// complement over (axis tilt, pivot shift, shape), its right-hand side, per frame
/// `(t, coupling column, angle block, angle rhs)`, and the two directions across the axis.
type Normal = (
    DMatrix<f64>,
    DVector<f64>,
    Vec<(usize, DVector<f64>, f64, f64)>,
    [Vector3<f64>; 2],
);

fn normal_equations(
    z: &[Vec<Option<Point3<f64>>>],
    shape: &[Point3<f64>],
    angle: &[Option<f64>],
    a: &Vector3<f64>,
    pivot: &Point3<f64>,
) -> Normal {
    let g = 4 + 3 * shape.len();
    let basis = across(a);
    let axis = Unit::new_normalize(*a);
    let mut schur = DMatrix::<f64>::zeros(g, g);
    let mut rhs = DVector::<f64>::zeros(g);
    let mut per_frame = Vec::new();
    for (t, th) in angle.iter().enumerate() {
        let Some(th) = *th else { continue };
        let h = turn(&axis, pivot, th);
        let rot = h.rotation.to_rotation_matrix().into_inner();
        let (turn_sc, pivot_cols) = (th.sin_cos(), pivot_columns(&basis, &rot));
        let mut agt = DVector::<f64>::zeros(g);
        let (mut d, mut bt) = (0.0, 0.0);
        for (k, zk) in z.iter().enumerate() {
            let Some(p) = zk[t] else { continue };
            let v = shape[k] - pivot;
            let r = p - h * shape[k];
            let jt = -a.cross(&(rot * v));
            // A sample's Jacobian is nonzero only in the 4 line columns and in its own
            // keypoint's 3 (there `-R`), so each block is summed on its own.
            let line = line_jacobian(a, &basis, &v, turn_sc, &pivot_cols);
            let o = 4 + 3 * k;
            let cross = -(line.transpose() * rot);
            let mut ll = schur.fixed_view_mut::<4, 4>(0, 0);
            ll += line.transpose() * line;
            let mut lk = schur.fixed_view_mut::<4, 3>(0, o);
            lk += cross;
            let mut kl = schur.fixed_view_mut::<3, 4>(o, 0);
            kl += cross.transpose();
            let mut kk = schur.fixed_view_mut::<3, 3>(o, o);
            kk += rot.transpose() * rot;
            let mut rl = rhs.fixed_rows_mut::<4>(0);
            rl -= line.transpose() * r;
            let mut rk = rhs.fixed_rows_mut::<3>(o);
            rk += rot.transpose() * r;
            let mut al = agt.fixed_rows_mut::<4>(0);
            al += line.transpose() * jt;
            let mut ak = agt.fixed_rows_mut::<3>(o);
            ak -= rot.transpose() * jt;
            d += jt.norm_squared();
            bt -= jt.dot(&r);
        }
        if d > 0.0 {
            per_frame.push((t, agt, d, bt));
        }
    }
    for (_, agt, d, bt) in &per_frame {
        schur.ger(-1.0 / *d, agt, agt, 1.0);
        rhs.axpy(-*bt / *d, agt, 1.0);
    }
    let ridge = 1e-9 * schur.trace() / g as f64;
    for i in 0..g {
        schur[(i, i)] += ridge;
    }
    (schur, rhs, per_frame, basis)
}

/// Gauss-Newton on every unknown of the hinge at once: axis direction (2), pivot across the
/// axis (2), the shape at angle 0 (3 per keypoint) and one angle per posed frame, the angles
/// eliminated frame by frame (each is one unknown, so its block is a scalar). A ridge of
/// 1e-9 of the mean diagonal fixes the gauge (the angles' zero against a turn of the shape
/// about the axis). A step is kept when the squared residual does not rise, else halved up
/// to 3 times; the iteration stops after [`GAUSS_NEWTON_STEPS`] or when no keypoint moves
/// by 1e-9 m. Returns the axis, the pivot, and the covariance per sigma^2 of (axis tilt,
/// pivot shift) along the two returned directions across the axis (rad^2 / m^2 and 1).
///
/// Our own: no crate in the workspace fits a model with per-frame nuisance parameters, and
/// the Schur elimination keeps the solve at the size of the shape (4 + 3m unknowns).
///
/// Derivatives of a sample's residual `r = z - p - R(a, th) (s - p)`, with `v = s - p` and
/// `b` across the axis: `dr/dth = -a x R v`, `dr/ds = -R`, `dr/dp = -(I - R) b`, and for the
/// axis tilted towards `b`, `-( (b x v) sin th + (b (a.v) + a (b.v)) (1 - cos th) )`.
fn refine(
    z: &[Vec<Option<Point3<f64>>>],
    shape: &mut [Point3<f64>],
    angle: &mut [Option<f64>],
    mut a: Vector3<f64>,
    mut pivot: Point3<f64>,
) -> (Vector3<f64>, Point3<f64>, Matrix4<f64>, [Vector3<f64>; 2]) {
    let m = shape.len();
    let mut sse = hinge_sse(z, shape, angle, &a, &pivot);
    for _ in 0..GAUSS_NEWTON_STEPS {
        let (schur, rhs, per_frame, [b1, b2]) = normal_equations(z, shape, angle, &a, &pivot);
        let Some(step) = schur.cholesky().map(|c| c.solve(&rhs)) else {
            break;
        };
        let mut scale = 1.0;
        let mut kept = false;
        for _ in 0..4 {
            let trial_a = (a + b1 * (scale * step[0]) + b2 * (scale * step[1])).normalize();
            let trial_p = pivot + b1 * (scale * step[2]) + b2 * (scale * step[3]);
            let trial_shape: Vec<Point3<f64>> = (0..m)
                .map(|k| {
                    shape[k]
                        + Vector3::new(step[4 + 3 * k], step[5 + 3 * k], step[6 + 3 * k]) * scale
                })
                .collect();
            let mut trial_angle = angle.to_vec();
            for (t, agt, d, bt) in &per_frame {
                let dth = (bt - agt.dot(&step)) / d;
                trial_angle[*t] = angle[*t].map(|x| x + scale * dth);
            }
            let trial_sse = hinge_sse(z, &trial_shape, &trial_angle, &trial_a, &trial_p);
            if trial_sse.is_finite() && trial_sse <= sse {
                sse = trial_sse;
                a = trial_a;
                pivot = trial_p;
                shape.copy_from_slice(&trial_shape);
                angle.copy_from_slice(&trial_angle);
                kept = true;
                break;
            }
            scale *= 0.5;
        }
        let largest = (0..m)
            .map(|k| Vector3::new(step[4 + 3 * k], step[5 + 3 * k], step[6 + 3 * k]).norm())
            .fold(0.0, f64::max);
        if !kept || largest * scale < 1e-9 {
            break;
        }
    }
    let (schur, _, _, basis) = normal_equations(z, shape, angle, &a, &pivot);
    let cov = schur.try_inverse().map_or(Matrix4::zeros(), |inv| {
        inv.fixed_view::<4, 4>(0, 0).into_owned()
    });
    (a, pivot, cov, basis)
}

/// Rigidity of a group of keypoints, whatever it turns on: the distances of the keypoints
/// seen together, about their means, as `(chi^2 / dof, dof)` against their noise
/// (`2 sigma^2`); `(0, 0)` with no pair seen together twice, `(inf, 0)` when `sigma` is
/// not a positive number. A hinge absorbs one degree of
/// freedom per frame, and a poorly posed parent's noise at long lever arms can hide a group
/// that bends, so a hinge's own `chi^2` does not tell this.
///
/// Complexity: O(T m^2) for m keypoints.
pub fn group_rigidity(tracks: &Tracks, points: &[usize], sigma: f64) -> (f64, f64) {
    if !(sigma.is_finite() && sigma > 0.0) {
        return (f64::INFINITY, 0.0);
    }
    let (mut chi2, mut dof) = (0.0, 0.0);
    for (x, &i) in points.iter().enumerate() {
        for &j in &points[x + 1..] {
            let d: Vec<f64> = (0..tracks.n_frames())
                .filter_map(|t| Some((tracks.get(t, i)? - tracks.get(t, j)?).norm()))
                .collect();
            if d.len() < 2 {
                continue;
            }
            let mean = d.iter().sum::<f64>() / d.len() as f64;
            chi2 += d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (2.0 * sigma * sigma);
            dof += (d.len() - 1) as f64;
        }
    }
    (if dof > 0.0 { chi2 / dof } else { 0.0 }, dof)
}

/// Fits a hinge between `parent`'s poses (`None`: the camera frame) and the keypoints
/// `points`, and poses them through it. Returns `None` for a parent that is not a body of
/// `poses`, a noise level that is not a positive number, tracks and poses of different
/// lengths, and when the data cannot support the hypothesis at all: fewer than two
/// keypoints, a keypoint with under 3 frames or the group in under [`MIN_HINGE_FRAMES`]
/// frames with the parent, tracks that do not spread across the axis
/// ([`MIN_HINGE_SPREAD_IN_SIGMA`]), keypoints never seen together with the others, or no
/// keypoint off the axis. Whether the hinge *holds* is the caller's decision, from
/// [`Hinge::chi2_per_dof`], [`Hinge::rms_residual_m`] and [`Hinge::arc_in_std`], and from
/// [`group_rigidity`] (the same for every parent).
///
/// Method: in the parent's frame every keypoint's samples lie in a plane normal to the axis,
/// so the axis is the least principal direction of the scatter summed over the keypoints
/// (each about its own mean); the pivot is the common centre of their circles (an algebraic
/// circle fit, Kasa 1976, with one centre and a radius per keypoint); the angles follow from
/// the keypoints' phases, their offsets from frames where two are seen together. Then the
/// shape (keypoints at angle 0) and the angles are refined in turn, each exactly for the
/// other (the angle of a frame by a 2D Procrustes fit), and last everything together by
/// Gauss-Newton (`refine`; measured on three hidden links of the mechanisms sweep: axis
/// errors 0.13-0.25 deg from the first estimate, 0.13-0.25 after, the squared residual a
/// little lower). Each frame's stated precision holds the angle's, the parent pose's and
/// the axis line's own error (the last shared by every frame).
///
/// Complexity: O(T m^2) per Gauss-Newton step for m keypoints (a sample's Jacobian touches
/// the 4 line unknowns and its own keypoint's 3, and each frame's eliminated angle adds a
/// rank-one term over the 4 + 3m unknowns), plus an O(m^3) solve.
pub fn hinged_body(
    tracks: &Tracks,
    poses: &BodyPoses,
    parent: Option<usize>,
    points: &[usize],
    sigma: f64,
    limits: &HingeLimits,
) -> Option<Hinge> {
    let m = points.len();
    let nt = poses.n_frames;
    if m < 2
        || !(sigma.is_finite() && sigma > 0.0)
        || tracks.n_frames() != nt
        || parent.is_some_and(|b| b >= poses.bodies.len())
    {
        return None;
    }
    let parent_pose = |t: usize| parent_pose(poses, parent, t);
    // Samples in the parent's frame.
    let mut z: Vec<Vec<Option<Point3<f64>>>> = vec![vec![None; nt]; m];
    let mut frames = Vec::new();
    for t in 0..nt {
        let Some((pose, _)) = parent_pose(t) else {
            continue;
        };
        let mut any = false;
        for (zk, &i) in z.iter_mut().zip(points) {
            if let Some(x) = tracks.get(t, i) {
                zk[t] = Some(pose.inverse_transform_point(&x));
                any = true;
            }
        }
        if any {
            frames.push(t);
        }
    }
    let counts: Vec<usize> = z.iter().map(|zk| zk.iter().flatten().count()).collect();
    if frames.len() < limits.min_frames || counts.iter().any(|&c| c < 3) {
        return None;
    }
    let n_samples: usize = counts.iter().sum();
    let means: Vec<Vector3<f64>> = z
        .iter()
        .zip(&counts)
        .map(|(zk, &c)| zk.iter().flatten().map(|p| p.coords).sum::<Vector3<f64>>() / c as f64)
        .collect();
    let mut scatter = Matrix3::zeros();
    for (zk, mean) in z.iter().zip(&means) {
        for p in zk.iter().flatten() {
            let d = p.coords - mean;
            scatter += d * d.transpose();
        }
    }
    let eig = scatter.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&x, &y| eig.eigenvalues[x].total_cmp(&eig.eigenvalues[y]));
    if eig.eigenvalues[order[1]] / (n_samples as f64) < (limits.min_spread_in_sigma * sigma).powi(2)
    {
        return None;
    }
    let mut a = eig.eigenvectors.column(order[0]).into_owned();
    // Sign: a deterministic choice (largest component positive), so the angles' sign is too.
    let big = a.iamax();
    if a[big] < 0.0 {
        a = -a;
    }
    let axis = Unit::new_normalize(a);
    let u = eig.eigenvectors.column(order[2]).into_owned();
    let v = a.cross(&u);
    let plane = |p: &Point3<f64>| Vector2::new(p.coords.dot(&u), p.coords.dot(&v));
    // Shared centre, one radius per keypoint: x^2 + y^2 + D x + E y + F_k = 0, in plane
    // coordinates about the first keypoint's mean (for conditioning).
    let cols = 2 + m;
    let mut row = DVector::<f64>::zeros(cols);
    let origin = plane(&Point3::from(means[0]));
    let mut ata = DMatrix::<f64>::zeros(cols, cols);
    let mut atb = DVector::<f64>::zeros(cols);
    for (k, zk) in z.iter().enumerate() {
        for p in zk.iter().flatten() {
            let q = plane(p) - origin;
            row.fill(0.0);
            row[0] = q.x;
            row[1] = q.y;
            row[2 + k] = 1.0;
            ata += &row * row.transpose();
            atb += &row * -(q.x * q.x + q.y * q.y);
        }
    }
    let sol = ata.cholesky()?.solve(&atb);
    let centre2 = origin + Vector2::new(-sol[0] / 2.0, -sol[1] / 2.0);
    let height = means.iter().map(|mu| mu.dot(&a)).sum::<f64>() / m as f64;
    let pivot = Point3::from(u * centre2.x + v * centre2.y + a * height);
    if !pivot.coords.iter().all(|x| x.is_finite()) {
        return None;
    }
    let phase = |p: &Point3<f64>| {
        let d = p - pivot;
        d.dot(&v).atan2(d.dot(&u))
    };
    let lever = |p: &Point3<f64>| distance_from_axis(p, &pivot, &a);
    let radius: Vec<f64> = z
        .iter()
        .zip(&counts)
        .map(|(zk, &c)| zk.iter().flatten().map(lever).sum::<f64>() / c as f64)
        .collect();
    let tells = |k: usize| radius[k] >= limits.min_lever_in_sigma * sigma;
    // Phase offsets of the keypoints, linked through frames where two are seen together,
    // starting from the best seen keypoint off the axis.
    let first = (0..m).filter(|&k| tells(k)).max_by(|&x, &y| {
        (counts[x] as f64 * radius[x] * radius[x])
            .total_cmp(&(counts[y] as f64 * radius[y] * radius[y]))
            .then(y.cmp(&x))
    })?;
    let mut offset: Vec<Option<f64>> = vec![None; m];
    offset[first] = Some(0.0);
    loop {
        let mut grown = false;
        for j in (0..m).filter(|&j| tells(j)) {
            if offset[j].is_some() {
                continue;
            }
            // The linked keypoint sharing the most frames with j.
            let best = (0..m)
                .filter_map(|i| {
                    let oi = offset[i]?;
                    let (mut s, mut c, mut n) = (0.0, 0.0, 0usize);
                    for (pj, pi) in z[j].iter().zip(&z[i]) {
                        if let (Some(pj), Some(pi)) = (pj, pi) {
                            let d = phase(pj) - phase(pi);
                            s += d.sin();
                            c += d.cos();
                            n += 1;
                        }
                    }
                    (n > 0).then(|| (n, oi + s.atan2(c)))
                })
                .max_by(|x, y| x.0.cmp(&y.0));
            if let Some((_, o)) = best {
                offset[j] = Some(o);
                grown = true;
            }
        }
        if !grown {
            break;
        }
    }
    if (0..m).any(|k| tells(k) && offset[k].is_none()) {
        return None;
    }
    let mut angle: Vec<Option<f64>> = vec![None; nt];
    for &t in &frames {
        let (mut s, mut c) = (0.0, 0.0);
        for k in (0..m).filter(|&k| tells(k)) {
            if let (Some(p), Some(o)) = (z[k][t], offset[k]) {
                let w = radius[k] * radius[k];
                let d = phase(&p) - o;
                s += w * d.sin();
                c += w * d.cos();
            }
        }
        if s != 0.0 || c != 0.0 {
            angle[t] = Some(s.atan2(c));
        }
    }
    // Shape at angle 0 and angles, in turn.
    let mut shape = vec![Point3::origin(); m];
    for _ in 0..REFINE_ROUNDS {
        for k in 0..m {
            let (mut acc, mut n) = (Vector3::zeros(), 0usize);
            for t in 0..nt {
                if let (Some(p), Some(th)) = (z[k][t], angle[t]) {
                    acc += (turn(&axis, &pivot, -th) * p).coords;
                    n += 1;
                }
            }
            if n == 0 {
                return None;
            }
            shape[k] = Point3::from(acc / n as f64);
        }
        for &t in &frames {
            if angle[t].is_none() {
                continue;
            }
            let (mut s, mut c) = (0.0, 0.0);
            for k in 0..m {
                if let Some(p) = z[k][t] {
                    let from = shape[k] - pivot;
                    let to = p - pivot;
                    let from = Vector2::new(from.dot(&u), from.dot(&v));
                    let to = Vector2::new(to.dot(&u), to.dot(&v));
                    s += from.x * to.y - from.y * to.x;
                    c += from.dot(&to);
                }
            }
            angle[t] = Some(s.atan2(c));
        }
    }
    // Axis, pivot, shape and angles together (Gauss-Newton), then what follows from them.
    let (a, pivot, line_cov, across) = refine(&z, &mut shape, &mut angle, a, pivot);
    let axis = Unit::new_normalize(a);
    let lever = |p: &Point3<f64>| distance_from_axis(p, &pivot, &a);
    // Residuals, the angle's precision and the poses.
    let posed: Vec<usize> = frames
        .iter()
        .copied()
        .filter(|&t| angle[t].is_some())
        .collect();
    let t0 = *posed.first()?;
    let (p0, _) = parent_pose(t0)?;
    let k_iso = p0 * turn(&axis, &pivot, angle[t0]?);
    let centre = shape
        .iter()
        .map(|s| (k_iso * s).coords)
        .sum::<Vector3<f64>>()
        / m as f64;
    let body_from_s = Translation3::from(-centre) * k_iso;
    let s_from_body = body_from_s.inverse();
    let body_shape: Vec<Point3<f64>> = shape.iter().map(|s| body_from_s * s).collect();
    // Defined exactly in the posed frames.
    let mut unwrapped = angle.clone();
    unwrap_angles(&mut unwrapped);
    let unwrapped: Vec<f64> = unwrapped.into_iter().flatten().collect();
    // The axis line's own error (`line_cov`) is shared by every frame; each frame's stated
    // precision counts it at the frame's angle from the middle of the swept range, where
    // the shape is best determined, so that a pair test does not take it for motion.
    let middle = unwrapped.iter().sum::<f64>() / unwrapped.len() as f64;
    let across = Matrix3x2::from_columns(&across);
    let tilt_cov = line_cov.fixed_view::<2, 2>(0, 0).into_owned();
    let shift_cov = line_cov.fixed_view::<2, 2>(2, 2).into_owned();
    let mut cam_from_body = vec![None; nt];
    let mut quality = vec![None; nt];
    let (mut chi2, mut n_res, mut sum_sq) = (0.0, 0usize, 0.0);
    let mut angle_std = Vec::with_capacity(posed.len());
    for (&t, &turned) in posed.iter().zip(&unwrapped) {
        let (pose, pq) = parent_pose(t)?;
        let th = angle[t]?;
        let h = turn(&axis, &pivot, th);
        let (rot_p, orig_p, trans_std, rot_std) =
            pq.map_or((Matrix3::zeros(), Matrix3::zeros(), 0.0, 0.0), |q| {
                (
                    q.rot_cov_per_sigma2,
                    q.origin_cov_per_sigma2,
                    q.trans_std_per_sigma,
                    q.rot_std_per_sigma,
                )
            });
        let (mut lever2, mut sq, mut n_vis) = (0.0, 0.0, 0usize);
        for k in 0..m {
            let Some(p) = z[k][t] else { continue };
            let e = p - h * shape[k];
            let var = 1.0 + trans_std * trans_std + (rot_std * p.coords.norm()).powi(2);
            chi2 += e.norm_squared() / (sigma * sigma * var);
            sq += e.norm_squared();
            sum_sq += e.norm_squared();
            n_res += 1;
            n_vis += 1;
            lever2 += lever(&(h * shape[k])).powi(2);
        }
        let var_angle = 1.0 / lever2.max(f64::MIN_POSITIVE);
        angle_std.push(var_angle.sqrt());
        let p_from_body = h * s_from_body;
        let rm = p_from_body.rotation.to_rotation_matrix().into_inner();
        let o = p_from_body.translation.vector;
        let swing = a.cross(&(o - pivot.coords));
        let ox = o.cross_matrix();
        // A tilt of the axis by e (across it) turns the frame by sin(d) e + (1 - cos d) a x e
        // at an angle d from the middle; a shift of the pivot by q moves it by (I - R(d)) q.
        let (sn, cs) = (turned - middle).sin_cos();
        let tilt = across * sn + a.cross_matrix() * across * (1.0 - cs);
        let shift = (Matrix3::identity()
            - turn(&axis, &Point3::origin(), turned - middle)
                .rotation
                .to_rotation_matrix()
                .into_inner())
            * across;
        let lever_o = (o - pivot.coords).cross_matrix();
        let line_rot = tilt * tilt_cov * tilt.transpose();
        let rot_cov = rm.transpose() * (rot_p + a * a.transpose() * var_angle + line_rot) * rm;
        let origin_cov = rm.transpose()
            * (orig_p
                + ox * rot_p * ox.transpose()
                + swing * swing.transpose() * var_angle
                + lever_o * line_rot * lever_o.transpose()
                + shift * shift_cov * shift.transpose())
            * rm;
        cam_from_body[t] = Some(pose * p_from_body);
        quality[t] = Some(PoseQuality::from_covariances(
            n_vis,
            (sq / n_vis as f64).sqrt(),
            rot_cov,
            origin_cov,
        ));
    }
    // Unknowns: an angle per posed frame, 3 per keypoint, 4 for the axis line, less the
    // angle's zero (a gauge).
    let dof = 3.0 * n_res as f64 - (posed.len() + 3 * m + 3) as f64;
    if dof < 1.0 {
        return None;
    }
    let lo = unwrapped.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = unwrapped.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    angle_std.sort_by(f64::total_cmp);
    let median_std = angle_std[angle_std.len() / 2] * sigma;
    let frames_without = nt - posed.len();
    Some(Hinge {
        parent,
        axis: a,
        pivot,
        chi2_per_dof: chi2 / dof,
        dof,
        rms_residual_m: (sum_sq / n_res as f64).sqrt(),
        arc_in_std: (hi - lo) / median_std.max(f64::MIN_POSITIVE),
        track: BodyTrack {
            points: points.to_vec(),
            shape: body_shape,
            placed: vec![true; m],
            reference_frame: t0,
            cam_from_body,
            quality,
            frames_too_few_points: frames_without,
            frames_degenerate: 0,
        },
    })
}

/// `own` (a body's own poses) with the frames it lacks filled from `hinge`'s poses of the
/// same keypoints, expressed in `own`'s body frame: the two frames differ by a constant
/// motion, estimated over the frames both pose (quaternion and translation means). With no
/// such frame, the hinge's track is returned as it is. Returns the track and the number of
/// frames filled.
///
/// Where a body has poses of its own they are kept: a hinge on the wrong body can fit
/// within the noise (two links turning about axes 3 deg apart through one anchor), and its
/// poses then bend the body's joints with every other body.
pub fn filled_from_hinge(own: &BodyTrack, hinge: &Hinge) -> (BodyTrack, usize) {
    filled_from_track(own, &hinge.track)
}

/// `own` with the frames it lacks filled from `other`, a track of the same keypoints in
/// another body frame (a hinge's or a ball joint's poses), as [`filled_from_hinge`] does.
pub fn filled_from_track(own: &BodyTrack, other: &BodyTrack) -> (BodyTrack, usize) {
    let h = other;
    let both: Vec<Isometry3<f64>> = own
        .cam_from_body
        .iter()
        .zip(&h.cam_from_body)
        .filter_map(|(k, p)| Some(p.as_ref()?.inverse() * k.as_ref()?))
        .collect();
    let Some(first) = both.first() else {
        let filled = h.n_registered();
        return (h.clone(), filled);
    };
    // Hinge body frame from own body frame: mean rotation (quaternions on one hemisphere)
    // and mean translation.
    let mut q = kinetree_core::nalgebra::Vector4::zeros();
    let mut tr = Vector3::zeros();
    for d in &both {
        let c = d.rotation.coords;
        q += if c.dot(&first.rotation.coords) < 0.0 {
            -c
        } else {
            c
        };
        tr += d.translation.vector;
    }
    let rot = UnitQuaternion::from_quaternion(kinetree_core::nalgebra::Quaternion::from(q));
    let offset = Isometry3::from_parts(Translation3::from(tr / both.len() as f64), rot);
    let rd = rot.to_rotation_matrix().into_inner();
    let dx = offset.translation.vector.cross_matrix();
    let mut out = own.clone();
    let mut filled = 0;
    for t in 0..out.cam_from_body.len() {
        if out.cam_from_body[t].is_some() {
            continue;
        }
        let (Some(p), Some(qh)) = (h.cam_from_body[t], h.quality[t]) else {
            continue;
        };
        out.cam_from_body[t] = Some(p * offset);
        let rot_cov = rd.transpose() * qh.rot_cov_per_sigma2 * rd;
        let origin_cov = rd.transpose()
            * (qh.origin_cov_per_sigma2 + dx * qh.rot_cov_per_sigma2 * dx.transpose())
            * rd;
        out.quality[t] = Some(PoseQuality::from_covariances(
            qh.n_visible,
            qh.rms_residual_m,
            rot_cov,
            origin_cov,
        ));
        filled += 1;
    }
    out.frames_too_few_points = out.frames_too_few_points.saturating_sub(filled);
    (out, filled)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The normal equations formed densely: every sample's full 3 x (4 + 3m) Jacobian and
    /// its products, then the angles eliminated.
    fn dense_normal_equations(
        z: &[Vec<Option<Point3<f64>>>],
        shape: &[Point3<f64>],
        angle: &[Option<f64>],
        a: &Vector3<f64>,
        pivot: &Point3<f64>,
    ) -> (DMatrix<f64>, DVector<f64>) {
        let g = 4 + 3 * shape.len();
        let basis = across(a);
        let axis = Unit::new_normalize(*a);
        let mut schur = DMatrix::<f64>::zeros(g, g);
        let mut rhs = DVector::<f64>::zeros(g);
        for (t, th) in angle.iter().enumerate() {
            let Some(th) = *th else { continue };
            let h = turn(&axis, pivot, th);
            let rot = h.rotation.to_rotation_matrix().into_inner();
            let (turn_sc, pivot_cols) = (th.sin_cos(), pivot_columns(&basis, &rot));
            let mut coupling = DVector::<f64>::zeros(g);
            let (mut d, mut bt) = (0.0, 0.0);
            for (k, zk) in z.iter().enumerate() {
                let Some(p) = zk[t] else { continue };
                let v = shape[k] - pivot;
                let r = p - h * shape[k];
                let jt = -a.cross(&(rot * v));
                let mut jg = DMatrix::<f64>::zeros(3, g);
                jg.view_mut((0, 0), (3, 4)).copy_from(&line_jacobian(
                    a,
                    &basis,
                    &v,
                    turn_sc,
                    &pivot_cols,
                ));
                jg.view_mut((0, 4 + 3 * k), (3, 3)).copy_from(&(-rot));
                let jt = DVector::from_column_slice(jt.as_slice());
                let res = DVector::from_column_slice(r.as_slice());
                schur += jg.transpose() * &jg;
                rhs -= jg.transpose() * &res;
                coupling += jg.transpose() * &jt;
                d += jt.norm_squared();
                bt -= jt.dot(&res);
            }
            if d > 0.0 {
                schur -= &coupling * coupling.transpose() / d;
                rhs -= &coupling * (bt / d);
            }
        }
        let ridge = 1e-9 * schur.trace() / g as f64;
        for i in 0..g {
            schur[(i, i)] += ridge;
        }
        (schur, rhs)
    }

    #[test]
    fn the_blockwise_normal_equations_are_the_dense_ones() {
        let a = Vector3::new(0.3, -0.5, 0.8).normalize();
        let pivot = Point3::new(0.1, 0.05, -0.2);
        let shape: Vec<Point3<f64>> = (0..4)
            .map(|k| {
                Point3::new(
                    0.2 + 0.03 * k as f64,
                    -0.1 * k as f64,
                    0.05 * (k % 2) as f64,
                )
            })
            .collect();
        let angle: Vec<Option<f64>> = (0..40)
            .map(|t| (t % 7 != 3).then(|| 0.9 * (t as f64 * 0.37).sin()))
            .collect();
        // Samples near where a slightly different hinge puts them, some of them hidden.
        let off = turn(
            &Unit::new_normalize(a + Vector3::new(0.01, 0.0, -0.02)),
            &pivot,
            0.0,
        );
        let z: Vec<Vec<Option<Point3<f64>>>> = (0..shape.len())
            .map(|k| {
                angle
                    .iter()
                    .enumerate()
                    .map(|(t, th)| {
                        let th = (*th)?;
                        let h = turn(&Unit::new_normalize(a), &pivot, th + 0.01);
                        let wobble =
                            Vector3::new(0.001, -0.002, 0.0005) * ((t * 3 + k) as f64).cos();
                        ((t + k) % 5 != 0).then(|| off * (h * shape[k]) + wobble)
                    })
                    .collect()
            })
            .collect();
        let (schur, rhs, per_frame, _) = normal_equations(&z, &shape, &angle, &a, &pivot);
        let (want_schur, want_rhs) = dense_normal_equations(&z, &shape, &angle, &a, &pivot);
        assert!(!per_frame.is_empty());
        let scale = want_schur.amax();
        assert!((&schur - &want_schur).amax() <= 1e-12 * scale);
        assert!((&rhs - &want_rhs).amax() <= 1e-12 * want_rhs.amax().max(1e-300));
        assert!(want_rhs.amax() > 0.0);
    }
}
