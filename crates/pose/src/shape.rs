//! Gauss-Newton refinement of a body's reference shape against every frame's observations.
//!
//! The alternation of [`crate::KabschPoses`] (register every frame to the shape, average the
//! registered points) is block coordinate descent on shape and poses. Where the visible subset
//! changes from frame to frame (occlusion), each frame's pose absorbs part of the shape's error
//! and the alternation crawls: a 6-point box link seen 3-5 points at a time kept shape errors
//! of 1.6-7.2 mm after its 4 passes, 1.5-6.5 mm after 20 and 0.9-3.7 mm after 100, and its
//! poses missed their propagated precision by 9-16 in chi^2 per degree of freedom, enough for
//! the pair tests to call its two revolute joints multi-DoF (mechanisms sweep, 7-joint tree,
//! seed 13). A Gauss-Newton step on the shape with the poses eliminated (their 6 x 6 blocks,
//! Schur complement) moves the shape along those coupled directions at once.

use kinetree_core::nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix3x6, Matrix6, Matrix6x3, Point3, Vector3, Vector6,
};
use std::borrow::Cow;

/// Bodies with more placed points than this keep the alternation's shape: the step's dense
/// solve grows as the cube of the points (600 unknowns here, a few milliseconds), and a body
/// with that many keypoints shows many of them in each frame, where the alternation converges.
pub(crate) const MAX_POINTS: usize = 200;

/// One frame's registration: its pose (`camera_from_shape`) and the observations that entered
/// it, as `(index into the shape, observed point)`: borrowed from the frame's observations when
/// all of them entered it (a copy of every frame's would double the bodies' memory over long
/// recordings of many points).
pub(crate) type FrameObs<'a> = (Isometry3<f64>, Cow<'a, [(usize, Point3<f64>)]>);

/// The Gauss-Newton step of the placed points of `shape` (all frames' residuals
/// `pose * s_k - q`, the poses eliminated), as a move per shape entry (zero for unplaced
/// ones). `None` when no point or more than [`MAX_POINTS`] are placed, or the reduced system
/// cannot be solved.
///
/// A rigid motion of the whole shape, undone by every pose, leaves the residuals unchanged:
/// the reduced matrix has that 6-dimensional null space, which a ridge of 1e-9 of its mean
/// diagonal closes (the gradient has no component along it, so the step has next to none).
///
/// In the shape's own frame the pose block of a frame, `W_t`, the inverse of
/// `sum E_k E_k^T` over its visible points with `E_k = [[s_k]x; I]`, does not depend on the
/// frame's rotation, and the block of points `i` and `j` in the reduced matrix is
/// `-E_i^T (sum of W_t over the frames that see both) E_j`. That sum is
/// `S_i + S_j - W + H_ij`, where `S_i` sums the frames that see `i`, `W` all frames and
/// `H_ij` the frames that miss both. So the frames that see most of the points are assembled
/// through their hidden pairs (`H_ij`) and the others through their visible pairs.
///
/// Cost: O(sum over frames of min(v, h)^2) to assemble (v visible and h hidden placed
/// points) plus O(m^2) for the `S` terms, and O((3 m)^3) to solve (m placed points).
pub(crate) fn gauss_newton_step(
    shape: &[Option<Point3<f64>>],
    frames: &[FrameObs],
) -> Option<Vec<Vector3<f64>>> {
    let mut index = vec![None; shape.len()];
    let mut placed: Vec<Vector3<f64>> = Vec::new();
    for (k, s) in shape.iter().enumerate() {
        if let Some(s) = s {
            index[k] = Some(placed.len());
            placed.push(s.coords);
        }
    }
    let m = placed.len();
    if m == 0 || m > MAX_POINTS {
        return None;
    }
    // E_i^T = [-[s_i]x, I] (3 x 6) of every placed point.
    let et: Vec<Matrix3x6<f64>> = placed
        .iter()
        .map(|s| {
            let mut e = Matrix3x6::<f64>::zeros();
            e.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-s.cross_matrix()));
            e.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&Matrix3::identity());
            e
        })
        .collect();
    // Lower-triangle 3 x 3 blocks (j <= i) of the reduced matrix, row-major by block.
    let mut blocks = vec![Matrix3::<f64>::zeros(); m * (m + 1) / 2];
    let at = |i: usize, j: usize| i * (i + 1) / 2 + j;
    let mut seen_by = vec![0.0f64; m];
    let mut gradient = DVector::<f64>::zeros(3 * m);
    // Sums of W_t over the frames assembled through their hidden pairs: all of them, and
    // those that see each point.
    let mut w_all = Matrix6::<f64>::zeros();
    let mut w_seen = vec![Matrix6::<f64>::zeros(); m];
    let mut visible = vec![false; m];
    let mut list: Vec<usize> = Vec::with_capacity(m);
    let mut rows: Vec<Matrix3x6<f64>> = Vec::with_capacity(m);
    for (pose, obs) in frames {
        let r = pose.rotation.to_rotation_matrix().into_inner();
        let mut a = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        list.clear();
        for &(k, q) in obs.iter() {
            let Some(i) = index[k] else {
                continue;
            };
            // Residual pose * s - q, in the shape frame; the pose perturbed on the right by a
            // rotation vector w and a translation v moves it by E_i^T (w, v), the shape by ds.
            let residual = r.transpose() * (pose * Point3::from(placed[i]) - q);
            let e = &et[i];
            a += e.transpose() * e;
            g += e.transpose() * residual;
            seen_by[i] += 1.0;
            for d in 0..3 {
                gradient[3 * i + d] += residual[d];
            }
            visible[i] = true;
            list.push(i);
        }
        // A registered frame has three non-collinear points, so `a` is invertible.
        let Some(w) = a.try_inverse() else {
            for &i in &list {
                visible[i] = false;
            }
            continue;
        };
        let wg = w * g;
        for &i in &list {
            let gi = et[i] * wg;
            for d in 0..3 {
                gradient[3 * i + d] -= gi[d];
            }
        }
        let hidden = m - list.len();
        if hidden < list.len() {
            w_all += w;
            for &i in &list {
                w_seen[i] += w;
            }
            list.clear();
            list.extend((0..m).filter(|&i| !visible[i]));
            assemble_pairs(&mut blocks, &et, &list, &w, &mut rows, at);
            visible.fill(false);
        } else {
            assemble_pairs(&mut blocks, &et, &list, &w, &mut rows, at);
            for &i in &list {
                visible[i] = false;
            }
        }
    }
    // The frames assembled through their hidden pairs: S_i + S_j - W for every pair.
    if w_all != Matrix6::zeros() {
        let left: Vec<Matrix3x6<f64>> = (0..m).map(|i| et[i] * (w_seen[i] - w_all)).collect();
        let right: Vec<Matrix6x3<f64>> = (0..m).map(|j| w_seen[j] * et[j].transpose()).collect();
        for i in 0..m {
            for j in 0..=i {
                blocks[at(i, j)] += left[i] * et[j].transpose() + et[i] * right[j];
            }
        }
    }
    let mut reduced = DMatrix::<f64>::zeros(3 * m, 3 * m);
    for i in 0..m {
        for j in 0..=i {
            let mut b = -blocks[at(i, j)];
            if i == j {
                b += Matrix3::identity() * seen_by[i];
            }
            reduced.view_mut((3 * i, 3 * j), (3, 3)).copy_from(&b);
            if i != j {
                reduced
                    .view_mut((3 * j, 3 * i), (3, 3))
                    .copy_from(&b.transpose());
            }
        }
    }
    let ridge = 1e-9 * reduced.trace() / (3 * m) as f64;
    for d in 0..3 * m {
        reduced[(d, d)] += ridge.max(f64::MIN_POSITIVE);
    }
    let step = reduced.cholesky()?.solve(&(-gradient));
    Some(
        index
            .iter()
            .map(|i| i.map_or_else(Vector3::zeros, |i| step.fixed_rows::<3>(3 * i).into_owned()))
            .collect(),
    )
}

/// Adds `E_i^T w E_j` to the lower-triangle block of every pair `j <= i` of `points`.
fn assemble_pairs(
    blocks: &mut [Matrix3<f64>],
    et: &[Matrix3x6<f64>],
    points: &[usize],
    w: &Matrix6<f64>,
    rows: &mut Vec<Matrix3x6<f64>>,
    at: impl Fn(usize, usize) -> usize,
) {
    rows.clear();
    rows.extend(points.iter().map(|&i| et[i] * w));
    for (a, &i) in points.iter().enumerate() {
        for &j in &points[..=a] {
            let (hi, lo, swap) = if i >= j { (i, j, false) } else { (j, i, true) };
            let b = rows[a] * et[j].transpose();
            if swap {
                blocks[at(hi, lo)] += b.transpose();
            } else {
                blocks[at(hi, lo)] += b;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinetree_core::nalgebra::{Translation3, UnitQuaternion};

    /// A 6-point shape, 40 poses of it, and which points each frame sees (3 or 4).
    struct Scene {
        truth: Vec<Point3<f64>>,
        poses: Vec<Isometry3<f64>>,
        visible: Vec<Vec<usize>>,
    }

    fn scene() -> Scene {
        let truth = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.2, 0.0, 0.0),
            Point3::new(0.2, 0.04, 0.0),
            Point3::new(0.0, 0.04, 0.03),
            Point3::new(0.1, 0.0, 0.03),
            Point3::new(0.15, 0.04, 0.03),
        ];
        let poses: Vec<Isometry3<f64>> = (0..40)
            .map(|t| {
                let a = t as f64 * 0.13;
                Isometry3::from_parts(
                    Translation3::new(0.3 * a.sin(), 0.1 * a.cos(), 1.0 + 0.05 * a),
                    UnitQuaternion::from_scaled_axis(Vector3::new(0.4 * a.sin(), a, 0.3)),
                )
            })
            .collect();
        let visible: Vec<Vec<usize>> = (0..40)
            .map(|t| (0..6).filter(|k| (t + k) % 5 < 3).collect())
            .collect();
        Scene {
            truth,
            poses,
            visible,
        }
    }

    #[test]
    fn a_few_steps_recover_a_shape_seen_a_few_points_at_a_time() {
        let Scene {
            truth,
            poses,
            visible,
        } = scene();
        // A start 5 mm off per point, in a pattern no rigid motion undoes.
        let mut shape: Vec<Option<Point3<f64>>> = truth
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let off = Vector3::new(0.005, -0.004, 0.003) * if k % 2 == 0 { 1.0 } else { -1.0 };
                Some(p + off)
            })
            .collect();
        let error = |shape: &[Option<Point3<f64>>]| {
            // Shape error after the best rigid alignment with the truth.
            let est: Vec<Point3<f64>> = shape.iter().flatten().copied().collect();
            let fit = kinetree_core::geom::kabsch(&est, &truth).expect("fit");
            est.iter()
                .zip(&truth)
                .map(|(e, t)| (fit * e - t).norm())
                .fold(0.0, f64::max)
        };
        let before = error(&shape);
        for _ in 0..5 {
            let frames: Vec<FrameObs> = poses
                .iter()
                .zip(&visible)
                .filter_map(|(pose, vis)| {
                    let obs: Vec<(usize, Point3<f64>)> =
                        vis.iter().map(|&k| (k, pose * truth[k])).collect();
                    let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = obs
                        .iter()
                        .map(|&(k, q)| (shape[k].expect("placed"), q))
                        .unzip();
                    let fitted = kinetree_core::geom::kabsch(&src, &dst)?;
                    Some((fitted, Cow::Owned(obs)))
                })
                .collect();
            let step = gauss_newton_step(&shape, &frames).expect("step");
            for (s, d) in shape.iter_mut().zip(&step) {
                if let Some(s) = s {
                    *s += d;
                }
            }
        }
        let after = error(&shape);
        assert!(before > 4e-3, "{before}");
        assert!(
            after < 1e-7,
            "shape error {after} m after 5 steps ({before} m before)"
        );
    }

    /// The step from the reduced matrix assembled frame by frame over every visible pair,
    /// in camera coordinates, as the Schur complement is written in a textbook.
    fn direct_step(shape: &[Point3<f64>], frames: &[FrameObs]) -> DVector<f64> {
        let m = shape.len();
        let mut big = DMatrix::<f64>::zeros(3 * m, 3 * m);
        let mut gradient = DVector::<f64>::zeros(3 * m);
        for (pose, obs) in frames {
            let r = pose.rotation.to_rotation_matrix().into_inner();
            let jac = |k: usize| {
                let mut j = Matrix3x6::<f64>::zeros();
                j.fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&(-(r * shape[k].coords).cross_matrix()));
                j.fixed_view_mut::<3, 3>(0, 3)
                    .copy_from(&Matrix3::identity());
                j
            };
            let mut a = Matrix6::<f64>::zeros();
            let mut g = Vector6::<f64>::zeros();
            for &(k, q) in obs.iter() {
                let residual = pose * shape[k] - q;
                a += jac(k).transpose() * jac(k);
                g += jac(k).transpose() * residual;
                let rr = r.transpose() * residual;
                for d in 0..3 {
                    big[(3 * k + d, 3 * k + d)] += 1.0;
                    gradient[3 * k + d] += rr[d];
                }
            }
            let a_inv = a.try_inverse().expect("pose block");
            for &(i, _) in obs.iter() {
                let bi = r.transpose() * jac(i);
                let gi = bi * a_inv * g;
                for d in 0..3 {
                    gradient[3 * i + d] -= gi[d];
                }
                for &(j, _) in obs.iter() {
                    let bj = r.transpose() * jac(j);
                    let block = bi * a_inv * bj.transpose();
                    let mut view = big.view_mut((3 * i, 3 * j), (3, 3));
                    view -= block;
                }
            }
        }
        let ridge = 1e-9 * big.trace() / (3 * m) as f64;
        for d in 0..3 * m {
            big[(d, d)] += ridge;
        }
        big.cholesky().expect("positive").solve(&(-gradient))
    }

    #[test]
    fn the_step_through_hidden_pairs_is_the_direct_schur_complement_step() {
        // 14 points; most frames miss 0-3 of them (assembled through their hidden pairs),
        // every fifth sees only 4 (assembled through its visible pairs).
        let truth: Vec<Point3<f64>> = (0..14)
            .map(|k| {
                let a = k as f64;
                Point3::new(0.1 * (1.3 * a).sin(), 0.08 * (0.7 * a).cos(), 0.02 * a)
            })
            .collect();
        let start: Vec<Point3<f64>> = truth
            .iter()
            .enumerate()
            .map(|(k, p)| p + Vector3::new(0.002, -0.001, 0.0015) * ((k % 3) as f64 - 1.0))
            .collect();
        let frames: Vec<FrameObs> = (0..50)
            .map(|t| {
                let a = t as f64 * 0.11;
                let pose = Isometry3::from_parts(
                    Translation3::new(0.2 * a.sin(), 0.1, 1.0 + 0.03 * a),
                    UnitQuaternion::from_scaled_axis(Vector3::new(0.5 * a.sin(), a, -0.2)),
                );
                let seen: Vec<usize> = if t % 5 == 0 {
                    (0..4).map(|k| (t + 3 * k) % 14).collect()
                } else {
                    (0..14).filter(|k| (k + t) % 7 > t % 4).collect()
                };
                let obs = seen
                    .into_iter()
                    .map(|k| (k, pose * truth[k] + Vector3::new(1e-4, 0.0, -1e-4)))
                    .collect();
                (pose, Cow::Owned(obs))
            })
            .collect();
        let placed: Vec<Option<Point3<f64>>> = start.iter().copied().map(Some).collect();
        let step = gauss_newton_step(&placed, &frames).expect("step");
        let direct = direct_step(&start, &frames);
        let scale = direct.amax();
        assert!(scale > 1e-4, "a step to take: {scale}");
        // The two agree up to float rounding, which the ridge over the rigid motions' null
        // space amplifies along those motions alone: compare after aligning them.
        let ours: Vec<Point3<f64>> = start.iter().zip(&step).map(|(p, d)| p + d).collect();
        let theirs: Vec<Point3<f64>> = (0..start.len())
            .map(|k| start[k] + direct.fixed_rows::<3>(3 * k))
            .collect();
        let fit = kinetree_core::geom::kabsch(&ours, &theirs).expect("fit");
        for k in 0..start.len() {
            let gap = (fit * ours[k] - theirs[k]).norm();
            assert!(gap < 1e-8 * scale, "point {k}: {gap} m apart");
        }
    }

    #[test]
    fn no_placed_point_gives_no_step() {
        assert!(gauss_newton_step(&[None, None], &[]).is_none());
    }
}
