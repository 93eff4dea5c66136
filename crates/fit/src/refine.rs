//! Refining a single-DoF joint's parameters (axis, pivot, reference pose) against the child's
//! keypoints over all frames, with the parent posed by the whole-tree fit.
//!
//! The DoF tester estimates a joint from per-body Kabsch-Umeyama poses of both bodies, so a
//! small parent's pose noise (a 3 cm body with four points, unregistered in half the frames)
//! enters the axis and pivot directly: up to 4 deg and 8 cm on random mechanisms at 1 mm. The
//! whole-tree fit poses that parent through its own joints and neighbours. Here the joint is
//! fitted again as a least-squares problem over the child's keypoints, in the parent's frame:
//! the joint's parameters shared by all frames, one position per frame (eliminated by a
//! Schur complement, as in bundle adjustment), damped Gauss-Newton.

use crate::solver::{Measure, ObservedJoint};
use kinetree_core::geom::perpendicular_basis;
use kinetree_core::nalgebra::{
    DMatrix, DVector, Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3,
};

/// One frame's data for the refinement: the child's keypoints as `(shape point, observation
/// in the parent's body frame)`.
pub(crate) type FramePoints = Vec<(Point3<f64>, Point3<f64>)>;

/// A joint's parameters in the parent's body frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct JointParams {
    pub(crate) axis: Vector3<f64>,
    /// A point on a revolute axis (unused for a prismatic joint).
    pub(crate) pivot: Point3<f64>,
    /// `parent_from_child` at position zero.
    pub(crate) reference: Isometry3<f64>,
    pub(crate) revolute: bool,
}

impl JointParams {
    /// From an observer's joint; `None` unless it is single-DoF.
    pub(crate) fn of(j: &ObservedJoint) -> Option<Self> {
        match j.measure {
            Measure::Revolute(axis, pivot) => Some(Self {
                axis,
                pivot,
                reference: j.reference,
                revolute: true,
            }),
            Measure::Prismatic(axis) => Some(Self {
                axis,
                pivot: Point3::origin(),
                reference: j.reference,
                revolute: false,
            }),
            Measure::Spherical(_) | Measure::Universal(..) | Measure::None => None,
        }
    }

    /// Number of free parameters: axis tilt (2), pivot across the axis (2, revolute only),
    /// reference pose (6).
    pub(crate) fn len(&self) -> usize {
        if self.revolute { 10 } else { 8 }
    }

    /// `parent_from_child` at position `q`.
    pub(crate) fn transform(&self, q: f64) -> Isometry3<f64> {
        if self.revolute {
            let turn = UnitQuaternion::from_axis_angle(&Unit::new_unchecked(self.axis), q);
            Translation3::from(self.pivot.coords)
                * turn
                * Translation3::from(-self.pivot.coords)
                * self.reference
        } else {
            Translation3::from(self.axis * q) * self.reference
        }
    }

    /// Shape point `s` at position `q`, in the parent's frame.
    fn predict(&self, q: f64, s: &Point3<f64>) -> Point3<f64> {
        self.transform(q) * s
    }

    /// The derivative of [`JointParams::predict`] with respect to `q`.
    fn predict_dq(&self, q: f64, s: &Point3<f64>) -> Vector3<f64> {
        if self.revolute {
            let turn = UnitQuaternion::from_axis_angle(&Unit::new_unchecked(self.axis), q);
            self.axis.cross(&(turn * (self.reference * s - self.pivot)))
        } else {
            self.axis
        }
    }

    /// The parameters moved by `delta` ([`JointParams::len`] entries): the axis tilted along
    /// its two perpendiculars, the pivot moved across the axis, the reference pose turned
    /// and shifted in the parent's frame.
    pub(crate) fn moved(&self, delta: &[f64]) -> Self {
        let (e1, e2) = perpendicular_basis(&self.axis);
        let axis = (self.axis + e1 * delta[0] + e2 * delta[1]).normalize();
        let (pivot, rest) = if self.revolute {
            (self.pivot + e1 * delta[2] + e2 * delta[3], &delta[4..])
        } else {
            (self.pivot, &delta[2..])
        };
        let turn = UnitQuaternion::from_scaled_axis(Vector3::new(rest[0], rest[1], rest[2]));
        let shift = Translation3::new(rest[3], rest[4], rest[5]);
        Self {
            axis,
            pivot,
            reference: shift * turn * self.reference,
            revolute: self.revolute,
        }
    }

    /// The same joint with its pivot moved along the axis to the point level with the
    /// child's origin at position zero (a revolute joint's canonical pivot).
    pub(crate) fn canonical(mut self) -> Self {
        if self.revolute {
            let t = self.reference.translation.vector - self.pivot.coords;
            self.pivot += self.axis * self.axis.dot(&t);
        }
        self
    }

    /// The measure an observer's joint takes from these parameters.
    pub(crate) fn measure(&self) -> Measure {
        if self.revolute {
            Measure::Revolute(self.axis, self.pivot)
        } else {
            Measure::Prismatic(self.axis)
        }
    }

    /// The closed-form best position of one frame (see [`crate::solver::best_position`]):
    /// the observations are already in the parent's frame.
    fn best_position(&self, points: &[(Point3<f64>, Point3<f64>)]) -> Option<f64> {
        let j = ObservedJoint {
            parent: 0,
            child: 0,
            measure: self.measure(),
            reference: self.reference,
        };
        crate::solver::best_position(&j, &Isometry3::identity(), points, 0.0)
    }
}

/// Sum of squared residuals of `params` with positions `q` over `frames`.
fn cost(params: &JointParams, frames: &[FramePoints], q: &[f64]) -> f64 {
    frames
        .iter()
        .zip(q)
        .map(|(f, &q)| {
            f.iter()
                .map(|(s, b)| (b - params.predict(q, s)).norm_squared())
                .sum::<f64>()
        })
        .sum()
}

/// Most damped Gauss-Newton iterations.
const MAX_ITERATIONS: usize = 50;
/// Finite-difference step of the parameters' Jacobian (metres or radians).
const DIFF_STEP: f64 = 1e-6;

/// Refines `start` against the child's points of every frame: the parameters and one position
/// per frame minimising the sum of squared distances between the observed points (in the
/// parent's frame) and the joint's prediction. Returns the refined parameters and the cost
/// before and after, or `None` with fewer than three frames.
///
/// Complexity per iteration: O(F P^2 + P^3) with F the point observations and P the 8-10
/// parameters; the Jacobian of the parameters is taken by central differences (the
/// prediction is cheap, and the analytic derivatives of the axis tilt through the rotation
/// are long to write for no measured gain at this size).
pub(crate) fn refine(
    start: &JointParams,
    frames: &[FramePoints],
) -> Option<(JointParams, f64, f64)> {
    let mut params = *start;
    let mut q: Vec<f64> = frames
        .iter()
        .map(|f| params.best_position(f).unwrap_or(0.0))
        .collect();
    let used = frames.iter().filter(|f| !f.is_empty()).count();
    if used < 3 {
        return None;
    }
    let initial = cost(&params, frames, &q);
    let mut current = initial;
    let n = params.len();
    let mut lambda = 1e-4;
    for _ in 0..MAX_ITERATIONS {
        // Normal equations with the positions eliminated frame by frame (Schur complement).
        let mut a = DMatrix::<f64>::zeros(n, n);
        let mut g = DVector::<f64>::zeros(n);
        let mut per_frame: Vec<(DVector<f64>, f64, f64)> = Vec::with_capacity(frames.len());
        let mut column = vec![Vector3::zeros(); n];
        // The parameters moved either way along each direction, once per iteration.
        let nudged: Vec<(JointParams, JointParams)> = (0..n)
            .map(|k| {
                let mut delta = vec![0.0; n];
                delta[k] = DIFF_STEP;
                let plus = params.moved(&delta);
                delta[k] = -DIFF_STEP;
                (plus, params.moved(&delta))
            })
            .collect();
        let mut moved = vec![(Isometry3::identity(), Isometry3::identity()); n];
        for (f, &qt) in frames.iter().zip(&q) {
            let mut b = DVector::<f64>::zeros(n);
            let (mut d, mut gq) = (0.0, 0.0);
            let at = params.transform(qt);
            for (m, (plus, minus)) in moved.iter_mut().zip(&nudged) {
                *m = (plus.transform(qt), minus.transform(qt));
            }
            for (s, obs) in f {
                let r = obs - at * s;
                for (col, (plus, minus)) in column.iter_mut().zip(&moved) {
                    *col = (plus * s - minus * s) / (2.0 * DIFF_STEP);
                }
                let jq = params.predict_dq(qt, s);
                for k in 0..n {
                    for l in k..n {
                        a[(k, l)] += column[k].dot(&column[l]);
                    }
                    g[k] += column[k].dot(&r);
                    b[k] += column[k].dot(&jq);
                }
                d += jq.norm_squared();
                gq += jq.dot(&r);
            }
            per_frame.push((b, d, gq));
        }
        for k in 0..n {
            for l in 0..k {
                a[(k, l)] = a[(l, k)];
            }
        }
        let mut accepted = false;
        while lambda < 1e8 {
            let mut s = a.clone();
            let mut rhs = g.clone();
            for k in 0..n {
                s[(k, k)] *= 1.0 + lambda;
            }
            for (b, d, gq) in &per_frame {
                let dd = d * (1.0 + lambda);
                if dd > 0.0 {
                    s -= b * b.transpose() / dd;
                    rhs -= b * (gq / dd);
                }
            }
            // The damping keeps the gauge directions (a position offset against the
            // reference pose's turn about the axis) from moving far.
            let Some(chol) = s.clone().cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let step = chol.solve(&rhs);
            let trial = params.moved(step.as_slice());
            let trial_q: Vec<f64> = per_frame
                .iter()
                .zip(&q)
                .map(|((b, d, gq), &qt)| {
                    let dd = d * (1.0 + lambda);
                    if dd > 0.0 {
                        qt + (gq - b.dot(&step)) / dd
                    } else {
                        qt
                    }
                })
                .collect();
            let c = cost(&trial, frames, &trial_q);
            if c.is_finite() && c < current {
                let small = step.amax() < 1e-7 || c > current * (1.0 - 1e-8);
                params = trial;
                q = trial_q;
                current = c;
                lambda = (lambda * 0.1).max(1e-9);
                accepted = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            break;
        }
    }
    Some((params.canonical(), initial, current))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(truth: &JointParams, shape: &[Point3<f64>], wobble: f64) -> Vec<FramePoints> {
        (0..60)
            .map(|t| {
                let q = 0.8 * (f64::from(t) * 0.1).sin();
                shape
                    .iter()
                    .enumerate()
                    .map(|(i, s)| {
                        // A deterministic, zero-mean disturbance.
                        let e = Vector3::new(
                            (f64::from(t) * 1.3 + i as f64).sin(),
                            (f64::from(t) * 2.1 + i as f64 * 0.7).cos(),
                            (f64::from(t) * 0.7 - i as f64).sin(),
                        ) * wobble;
                        (*s, truth.predict(q, s) + e)
                    })
                    .collect()
            })
            .collect()
    }

    /// From a start 5 deg and 2 cm off, the refinement returns the true axis and pivot line
    /// of a revolute joint, and the true axis of a prismatic one.
    #[test]
    fn refinement_recovers_the_joint() {
        let shape = [
            Point3::new(0.1, 0.0, 0.0),
            Point3::new(0.0, 0.06, 0.02),
            Point3::new(-0.05, 0.0, 0.04),
            Point3::new(0.02, -0.03, -0.05),
        ];
        for revolute in [true, false] {
            let truth = JointParams {
                axis: Vector3::new(0.3, -0.5, 0.8).normalize(),
                pivot: Point3::new(0.05, 0.1, -0.02),
                reference: Isometry3::from_parts(
                    Translation3::new(0.2, 0.05, 0.1),
                    UnitQuaternion::from_scaled_axis(Vector3::new(0.1, 0.4, -0.2)),
                ),
                revolute,
            };
            let start = truth.moved(if revolute {
                &[0.06, -0.05, 0.02, 0.01, 0.03, 0.0, 0.02, 0.01, 0.0, -0.01]
            } else {
                &[0.06, -0.05, 0.03, 0.0, 0.02, 0.01, 0.0, -0.01]
            });
            let data = frames(&truth, &shape, 1e-4);
            let (found, before, after) = refine(&start, &data).expect("refined");
            assert!(after < before);
            let angle = found
                .axis
                .dot(&truth.axis)
                .abs()
                .min(1.0)
                .acos()
                .to_degrees();
            assert!(angle < 0.1, "revolute {revolute}: axis off by {angle} deg");
            if revolute {
                let v = found.pivot - truth.pivot;
                let across = (v - truth.axis * truth.axis.dot(&v)).norm();
                assert!(across < 1e-3, "pivot off the axis line by {across} m");
            }
        }
    }

    /// Fewer than three frames with points: nothing to refine.
    #[test]
    fn too_few_frames_are_left_alone() {
        let p = JointParams {
            axis: Vector3::z(),
            pivot: Point3::origin(),
            reference: Isometry3::identity(),
            revolute: true,
        };
        let one = vec![(Point3::new(0.1, 0.0, 0.0), Point3::new(0.0, 0.1, 0.0))];
        assert!(refine(&p, &[one.clone(), one, Vec::new()]).is_none());
    }
}
