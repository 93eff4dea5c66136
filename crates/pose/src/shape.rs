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
    DMatrix, DVector, Isometry3, Matrix3, Matrix3x6, Matrix6, Point3, Vector3, Vector6,
};

/// Bodies with more placed points than this keep the alternation's shape: the step's dense
/// solve grows as the cube of the points (600 unknowns here, a few milliseconds), and a body
/// with that many keypoints shows many of them in each frame, where the alternation converges.
pub(crate) const MAX_POINTS: usize = 200;

/// One frame's registration: its pose (`camera_from_shape`) and the observations that entered
/// it, as `(index into the shape, observed point)`.
pub(crate) type FrameObs = (Isometry3<f64>, Vec<(usize, Point3<f64>)>);

/// The Gauss-Newton step of the placed points of `shape` (all frames' residuals
/// `pose * s_k - q`, the poses eliminated), as a move per shape entry (zero for unplaced
/// ones). `None` when no point or more than [`MAX_POINTS`] are placed, or the reduced system
/// cannot be solved.
///
/// A rigid motion of the whole shape, undone by every pose, leaves the residuals unchanged:
/// the reduced matrix has that 6-dimensional null space, which a ridge of 1e-9 of its mean
/// diagonal closes (the gradient has no component along it, so the step has next to none).
///
/// Cost: O(sum over frames of v^2) to assemble (v visible points) and O((3 m)^3) to solve
/// (m placed points).
pub(crate) fn gauss_newton_step(
    shape: &[Option<Point3<f64>>],
    frames: &[FrameObs],
) -> Option<Vec<Vector3<f64>>> {
    let mut index = vec![None; shape.len()];
    let mut m = 0;
    for (k, s) in shape.iter().enumerate() {
        if s.is_some() {
            index[k] = Some(m);
            m += 1;
        }
    }
    if m == 0 || m > MAX_POINTS {
        return None;
    }
    let mut reduced = DMatrix::<f64>::zeros(3 * m, 3 * m);
    let mut gradient = DVector::<f64>::zeros(3 * m);
    for (pose, obs) in frames {
        let r = pose.rotation.to_rotation_matrix().into_inner();
        let mut a = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        let mut couplings: Vec<(usize, Matrix3x6<f64>)> = Vec::with_capacity(obs.len());
        for &(k, q) in obs {
            let (Some(i), Some(s)) = (index[k], shape[k]) else {
                continue;
            };
            // Residual pose * s - q; pose perturbed on the left by a rotation vector w and a
            // translation v: d(residual) = -[R s]x w + v + R ds.
            let residual = pose * s - q;
            let mut jp = Matrix3x6::<f64>::zeros();
            jp.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-(r * s.coords).cross_matrix()));
            jp.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&Matrix3::identity());
            a += jp.transpose() * jp;
            g += jp.transpose() * residual;
            // The shape block of this observation is R^T R = I.
            for d in 0..3 {
                reduced[(3 * i + d, 3 * i + d)] += 1.0;
            }
            let rt_res = r.transpose() * residual;
            for d in 0..3 {
                gradient[3 * i + d] += rt_res[d];
            }
            couplings.push((i, r.transpose() * jp));
        }
        // A registered frame has three non-collinear points, so `a` is invertible.
        let Some(a_inv) = a.try_inverse() else {
            continue;
        };
        for (i, bi) in &couplings {
            let bi_a = bi * a_inv;
            let gi = bi_a * g;
            for d in 0..3 {
                gradient[3 * i + d] -= gi[d];
            }
            for (j, bj) in &couplings {
                let block = bi_a * bj.transpose();
                let mut view = reduced.view_mut((3 * i, 3 * j), (3, 3));
                view -= block;
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
                    Some((fitted, obs))
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

    #[test]
    fn no_placed_point_gives_no_step() {
        assert!(gauss_newton_step(&[None, None], &[]).is_none());
    }
}
