//! The DoF testers: relative-motion columns with their noise, rank rules, joint typing.

use crate::axis::fixed_axis;
use crate::rank::{HiddenHinge, RankRule, rank_test, rank_test_uncentred, weighted_direction};
use kinetree_core::geom::{
    angle_about, canonical_sign, log_so3, perpendicular_basis, relative_poses,
};
use kinetree_core::nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use kinetree_core::{
    BodyPoses, DofInput, DofTester, Error, JointKind, PairDof, PoseQuality, RankTest, Result,
};
use serde::{Deserialize, Serialize};

/// Per-frame relative motion of body `b` in frame `a`, with the noise of every column.
#[derive(Debug, Clone)]
struct PairColumns {
    reference_frame: usize,
    /// Index of the reference frame among the columns.
    reference_index: usize,
    /// Displacement of `b`'s origin in `a`'s body frame, and its covariance (m^2).
    u: Vec<Vector3<f64>>,
    u_cov: Vec<Matrix3<f64>>,
    /// Axis-angle of the relative rotation, and its covariance (rad^2).
    rot: Vec<Vector3<f64>>,
    rot_cov: Vec<Matrix3<f64>>,
    q_rel: Vec<UnitQuaternion<f64>>,
    /// Covariance of every frame's relative rotation `a_from_b` itself (rad^2, in `a`'s
    /// frame), before the reference frame enters.
    rel_rot_cov: Vec<Matrix3<f64>>,
    y_ref: Vector3<f64>,
    /// Per frame: `a_from_b` (rotation, translation) and the body-frame (rotation, origin)
    /// covariances of `a` and `b` (m^2, rad^2), for the reference-free pivot test.
    x_abs: Vec<(Matrix3<f64>, Vector3<f64>)>,
    a_cov: Vec<(Matrix3<f64>, Matrix3<f64>)>,
    b_cov: Vec<(Matrix3<f64>, Matrix3<f64>)>,
}

fn quality(poses: &BodyPoses, a: Option<usize>, t: usize) -> Option<PoseQuality> {
    a.and_then(|b| poses.bodies[b].quality[t])
}

/// Per-body model error added to every pose's covariance: `(metres, radians)` std-devs.
type ModelError = (f64, f64);

fn pair_columns(
    poses: &BodyPoses,
    a: Option<usize>,
    b: usize,
    sigma: f64,
    model_error: ModelError,
) -> Result<PairColumns> {
    let n_bodies = poses.bodies.len();
    if b >= n_bodies || a.is_some_and(|a| a >= n_bodies || a == b) {
        return Err(Error::InvalidParameter {
            name: "pair".into(),
            message: format!("no pair ({a:?}, {b}) among {n_bodies} bodies"),
        });
    }
    if !(sigma.is_finite() && sigma > 0.0) {
        return Err(Error::InvalidParameter {
            name: "noise_sigma_m".into(),
            message: format!("must be finite and positive, got {sigma}"),
        });
    }
    let x = relative_poses(poses, a, b);
    let frames: Vec<usize> = (0..poses.n_frames).filter(|&t| x[t].is_some()).collect();
    if frames.len() < 2 {
        return Err(Error::Degenerate(format!(
            "frames {a:?} and body {b} have poses together in {} frame(s); two are needed",
            frames.len()
        )));
    }
    let s2 = sigma * sigma;
    let zero = Matrix3::zeros();
    let mut rot_cov = Vec::with_capacity(frames.len());
    let mut u_cov = Vec::with_capacity(frames.len());
    let mut x_abs = Vec::with_capacity(frames.len());
    let mut a_cov = Vec::with_capacity(frames.len());
    let mut b_cov = Vec::with_capacity(frames.len());
    for &t in &frames {
        let Some(xk) = x[t] else { continue };
        let r_x = xk.rotation.to_rotation_matrix().into_inner();
        let qa = quality(poses, a, t);
        let qb = quality(poses, Some(b), t);
        // Covariances in m^2 and rad^2: the noise propagated through the fit, plus the model
        // error of a body (none for the camera frame).
        let (er, em) = (
            Matrix3::identity() * model_error.1.powi(2),
            Matrix3::identity() * model_error.0.powi(2),
        );
        let (ja, oa) = qa.map_or((zero, zero), |q| {
            (
                q.rot_cov_per_sigma2 * s2 + er,
                q.origin_cov_per_sigma2 * s2 + em,
            )
        });
        let (jb, ob) = qb.map_or((zero, zero), |q| {
            (
                q.rot_cov_per_sigma2 * s2 + er,
                q.origin_cov_per_sigma2 * s2 + em,
            )
        });
        x_abs.push((r_x, xk.translation.vector));
        a_cov.push((ja, oa));
        b_cov.push((jb, ob));
        // Relative rotation error in a's frame: -alpha + R_x beta.
        rot_cov.push(ja + r_x * jb * r_x.transpose());
        // b's origin in a's frame: a's origin error, b's origin error, and a's rotation error
        // at the lever arm y.
        let y = xk.translation.vector.cross_matrix();
        u_cov.push(oa + r_x * ob * r_x.transpose() + y * ja * y.transpose());
    }
    // Reference: a common frame with the most precise relative rotation. The precision
    // depends only on which points are visible, so many frames tie exactly up to rounding;
    // breaking ties by rounding made the choice (and a borderline decision) change under a
    // rigid motion of the whole scene, and taking the earliest made it change when time ran
    // backwards. Among the tied frames, the one whose relative rotation is nearest all the
    // others' (least sum of squared angles) is taken: it depends on neither.
    let best = rot_cov
        .iter()
        .map(Matrix3::trace)
        .fold(f64::INFINITY, f64::min);
    let tied: Vec<usize> = (0..rot_cov.len())
        .filter(|&i| rot_cov[i].trace() <= best * (1.0 + 1e-9))
        .collect();
    let r = medoid_rotation(&frames, &x, &tied);
    let reference_frame = frames[r];
    let x_ref = x[reference_frame].ok_or_else(|| Error::Numerical("lost reference pose".into()))?;
    let y_ref = x_ref.translation.vector;
    let rel_rot_cov = rot_cov.clone();
    let mut u = Vec::with_capacity(frames.len());
    let mut rot = Vec::with_capacity(frames.len());
    let mut q_rel = Vec::with_capacity(frames.len());
    let rot_cov_ref = rot_cov[r];
    for (i, &t) in frames.iter().enumerate() {
        let Some(xk) = x[t] else { continue };
        u.push(xk.translation.vector - y_ref);
        let q: UnitQuaternion<f64> = xk.rotation * x_ref.rotation.inverse();
        let phi = log_so3(&q.to_rotation_matrix());
        // Q_k = R_k R_ref^T has left error eps_k - Q_k eps_ref, and log(exp(d) Q) moves by
        // J_l^-1(log Q) d: at large angles that amplifies the error (up to pi/2 at pi) and
        // turns it about the axis, which matters for the anisotropic errors of thin bodies.
        let qm = q.to_rotation_matrix().into_inner();
        let jinv = inverse_left_jacobian(&phi);
        let cov = rot_cov[i] + qm * rot_cov_ref * qm.transpose();
        rot_cov[i] = jinv * cov * jinv.transpose();
        rot.push(phi);
        q_rel.push(q);
    }
    Ok(PairColumns {
        reference_frame,
        reference_index: r,
        u,
        u_cov,
        rot,
        rot_cov,
        q_rel,
        rel_rot_cov,
        y_ref,
        x_abs,
        a_cov,
        b_cov,
    })
}

/// Among the candidate columns `tied` (indices into `frames`), the one whose relative rotation
/// has the least sum of squared angles to every frame's (in frame order, a later candidate
/// is taken only when its sum is smaller by a relative `1e-12`).
///
/// Every candidate's sum is bounded below in constant time by sums over the frames of
/// polynomial coefficients ([`angle_sum_bounds`]), and exact sums are taken only for
/// candidates whose bound does not exceed the least sum found: with every frame a candidate
/// (no occlusion) the exact sums, `K^2` angles, took most of a long recording's discovery.
fn medoid_rotation(
    frames: &[usize],
    x: &[Option<kinetree_core::nalgebra::Isometry3<f64>>],
    tied: &[usize],
) -> usize {
    let rotations: Vec<UnitQuaternion<f64>> = frames
        .iter()
        .filter_map(|&t| x[t].map(|p| p.rotation))
        .collect();
    let exact = |i: usize| -> f64 {
        let q = rotations[i];
        rotations.iter().map(|o| q.angle_to(o).powi(2)).sum()
    };
    let lower = angle_sum_bounds(&rotations);
    let mut order: Vec<(f64, usize)> = tied.iter().map(|&i| (lower(&rotations[i]), i)).collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    // The bounds are accurate to a relative rounding (see `angle_sum_bounds`); a relative
    // 1e-9 of slack, and an absolute one for sums of angles near zero, cover it.
    let rounding = 64.0 * f64::EPSILON * rotations.len() as f64;
    let mut least = f64::INFINITY;
    let mut costs: Vec<(usize, f64)> = Vec::new();
    for &(bound, i) in &order {
        if bound * (1.0 - 1e-9) - rounding > least * (1.0 + 1e-9) {
            break;
        }
        let cost = exact(i);
        least = least.min(cost);
        costs.push((i, cost));
    }
    // In frame order, a candidate replaces the one kept when its sum is below the kept one's
    // by a relative 1e-12, so the one kept at the end is within that of the least. Walking
    // only the sums within 1e-9 of the least (all of them were summed: a skipped bound is
    // above that) ends at the same one: where the two walks part, each keeps a sum near 1e-9
    // above the least, and the next sum within 1e-12 of it replaces both.
    costs.retain(|&(_, c)| c <= least * (1.0 + 1e-9));
    costs.sort_by_key(|&(i, _)| i);
    let mut best: Option<(usize, f64)> = None;
    for (i, cost) in costs {
        if best.is_none_or(|(_, c)| cost < c * (1.0 - 1e-12)) {
            best = Some((i, cost));
        }
    }
    best.map_or(0, |(i, _)| i)
}

/// How many terms of `asin^2`'s series the bound of [`angle_sum_bounds`] takes (`s^2`, `s^4`,
/// `s^6`): on a 3-body mechanism a fourth term (`s^8`) made 20 000 and 50 000 frames 20 %
/// and 15 % slower for the same time at 200 000 (`docs/decisions.md`).
const BOUND_TERMS: usize = 3;

/// The series' coefficients: `asin(s)^2 = s^2 + s^4 / 3 + 8 s^6 / 45 + ...`.
const ASIN2_SERIES: [f64; BOUND_TERMS] = [1.0, 1.0 / 3.0, 8.0 / 45.0];

/// Exponents up to `2 BOUND_TERMS`, plus one, the base of [`Monomials::key`].
const EXPONENT_BASE: usize = 2 * BOUND_TERMS + 1;

/// Polynomials in the four coordinates of a quaternion, homogeneous of one degree: a
/// coefficient per monomial `q^alpha`, the monomials in a fixed order.
struct Monomials {
    /// Exponents of each monomial of each even degree `2, 4, ..., 2 BOUND_TERMS` (index
    /// `degree / 2 - 1`).
    exponents: [Vec<[usize; 4]>; BOUND_TERMS],
    /// Position of each monomial in its degree's list, at [`Monomials::key`].
    position: Vec<usize>,
}

impl Monomials {
    fn new() -> Self {
        let mut exponents: [Vec<[usize; 4]>; BOUND_TERMS] = Default::default();
        let mut position = vec![usize::MAX; EXPONENT_BASE.pow(4)];
        for (slot, list) in exponents.iter_mut().enumerate() {
            let d = 2 * (slot + 1);
            for a in 0..=d {
                for b in 0..=d - a {
                    for c in 0..=d - a - b {
                        let e = [a, b, c, d - a - b - c];
                        position[Self::key(&e)] = list.len();
                        list.push(e);
                    }
                }
            }
        }
        Self {
            exponents,
            position,
        }
    }

    /// The exponents `(a, b, c, d)` as one number in base [`EXPONENT_BASE`].
    fn key(e: &[usize; 4]) -> usize {
        ((e[0] * EXPONENT_BASE + e[1]) * EXPONENT_BASE + e[2]) * EXPONENT_BASE + e[3]
    }

    /// `p` (degree `2 (slot + 1)`) times `a` (degree 2), added into `out` (the next degree).
    fn multiply_into(&self, slot: usize, p: &[f64], a: &[f64], out: &mut [f64]) {
        for (e, &cp) in self.exponents[slot].iter().zip(p) {
            for (f, &ca) in self.exponents[0].iter().zip(a) {
                let sum = [e[0] + f[0], e[1] + f[1], e[2] + f[2], e[3] + f[3]];
                out[self.position[Self::key(&sum)]] += cp * ca;
            }
        }
    }

    /// The value of the polynomial `p` of degree `2 (slot + 1)` at `v`, from `v`'s powers.
    fn evaluate(&self, slot: usize, p: &[f64], powers: &[[f64; EXPONENT_BASE]; 4]) -> f64 {
        self.exponents[slot]
            .iter()
            .zip(p)
            .map(|(e, &c)| {
                c * powers[0][e[0]] * powers[1][e[1]] * powers[2][e[2]] * powers[3][e[3]]
            })
            .sum()
    }
}

/// A lower bound, for any unit quaternion `q`, of `sum_k angle(q, q_k)^2` over `rotations`,
/// in constant time per `q`. With `s_k^2 = 1 - <q, q_k>^2` (`s_k = sin(angle_k / 2)`), the
/// angle is `2 asin(s_k)`, and `asin^2` is a power series of positive terms, so
/// `angle_k^2 >= 4 (s^2 + s^4 / 3 + 8 s^6 / 45)`.
///
/// `s_k^2 = q^T (I - q_k q_k^T) q` is a quadratic form in `q`, so each `sum_k s_k^(2j)` is a
/// polynomial of degree `2j` in `q` whose coefficients are sums over `k`: 129 numbers in all.
/// The form's diagonal is taken as the sum of the other coordinates' squares, and the
/// rotations are first turned by the first one's inverse (which keeps every angle), so that a
/// tight cluster of rotations (a static pair) gives small coefficients instead of the
/// differences of large ones: the bound is then accurate to a relative rounding.
fn angle_sum_bounds(rotations: &[UnitQuaternion<f64>]) -> impl Fn(&UnitQuaternion<f64>) -> f64 {
    let turn = rotations
        .first()
        .map_or(UnitQuaternion::identity(), UnitQuaternion::inverse);
    let local = move |q: &UnitQuaternion<f64>| {
        let c = (turn * q).coords;
        [c[0], c[1], c[2], c[3]]
    };
    let m = Monomials::new();
    // Each degree-2 monomial: a square `q_i^2` (`(i, None)`) or a product `q_i q_j`.
    let quadratic: Vec<(usize, Option<usize>)> = m.exponents[0]
        .iter()
        .map(|e| {
            let mut ones = (0..4).filter(|&i| e[i] > 0);
            let i = ones.next().unwrap_or(0);
            (i, ones.next())
        })
        .collect();
    let mut sums: [Vec<f64>; BOUND_TERMS] =
        std::array::from_fn(|slot| vec![0.0; m.exponents[slot].len()]);
    // This frame's `s_k^2, s_k^4, ...` as polynomials in `q`.
    let mut terms: [Vec<f64>; BOUND_TERMS] =
        std::array::from_fn(|slot| vec![0.0; m.exponents[slot].len()]);
    for r in rotations {
        let v = local(r);
        // The quadratic form of `s_k^2`: q_i^2 with the other coordinates' squares, q_i q_j
        // (i < j) with -2 v_i v_j.
        for (entry, &(i, j)) in terms[0].iter_mut().zip(&quadratic) {
            *entry = match j {
                None => (0..4).filter(|&o| o != i).map(|o| v[o] * v[o]).sum(),
                Some(j) => -2.0 * v[i] * v[j],
            };
        }
        for slot in 1..BOUND_TERMS {
            let (lower, upper) = terms.split_at_mut(slot);
            upper[0].fill(0.0);
            m.multiply_into(slot - 1, &lower[slot - 1], &lower[0], &mut upper[0]);
        }
        for (sum, term) in sums.iter_mut().zip(&terms) {
            for (s, t) in sum.iter_mut().zip(term) {
                *s += t;
            }
        }
    }
    move |q: &UnitQuaternion<f64>| {
        let v = local(q);
        let mut powers = [[1.0f64; EXPONENT_BASE]; 4];
        for (i, row) in powers.iter_mut().enumerate() {
            for e in 1..EXPONENT_BASE {
                row[e] = row[e - 1] * v[i];
            }
        }
        (0..BOUND_TERMS)
            .map(|slot| 4.0 * ASIN2_SERIES[slot] * m.evaluate(slot, &sums[slot], &powers).max(0.0))
            .sum()
    }
}

/// Reference-free test for a fixed pivot: is there a point fixed in both bodies, `c` in
/// `a`'s frame and `w` in `b`'s, with `c = R_k w + y_k` in every frame? Weighted least squares
/// in `(c, w)` (one gauge direction along the axis, fixed by a tiny ridge), each frame weighted
/// by the covariance of the transformed pivot: pose noise of `a` at lever `c` plus pose noise
/// of `b` at lever `w`. Three passes (the weights depend on the pivot). Returns
/// `(chi^2 / dof, dof, c)` with `dof = 3K - 5` (one more than a spherical joint's `3K - 6`:
/// the revolute gauge; the bound is a quantile either way) and `c` the pivot in `a`'s frame. No reference frame enters, so the result does
/// not depend on which frame is the reference; a screw or a moving centre leaves a large
/// residual.
fn pivot_test(c: &PairColumns) -> Option<(f64, f64, Point3<f64>)> {
    use kinetree_core::nalgebra::{SMatrix, SVector};
    let k = c.x_abs.len();
    if k < 3 {
        return None;
    }
    let point_cov = |(rot, origin): &(Matrix3<f64>, Matrix3<f64>), p: &Vector3<f64>| {
        let px = p.cross_matrix();
        origin + px * rot * px.transpose()
    };
    let mut theta = SVector::<f64, 6>::zeros();
    let mut chi2 = 0.0;
    for pass in 0..3 {
        let cc: Vector3<f64> = theta.fixed_rows::<3>(0).into_owned();
        let ww: Vector3<f64> = theta.fixed_rows::<3>(3).into_owned();
        let mut normal = SMatrix::<f64, 6, 6>::zeros();
        let mut rhs = SVector::<f64, 6>::zeros();
        let mut rows = Vec::with_capacity(k);
        for f in 0..k {
            let (r, y) = &c.x_abs[f];
            let cov = if pass == 0 {
                Matrix3::identity()
            } else {
                point_cov(&c.a_cov[f], &cc) + r * point_cov(&c.b_cov[f], &ww) * r.transpose()
            };
            let w = cov.try_inverse().unwrap_or_else(Matrix3::zeros);
            let mut m = SMatrix::<f64, 3, 6>::zeros();
            m.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&Matrix3::identity());
            m.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-r));
            normal += m.transpose() * w * m;
            rhs += m.transpose() * w * y;
            rows.push((m, w));
        }
        let ridge = normal.trace().max(1e-300) * 1e-9;
        let reg = normal + SMatrix::<f64, 6, 6>::identity() * ridge;
        theta = reg.try_inverse()? * rhs;
        chi2 = rows
            .iter()
            .zip(&c.x_abs)
            .map(|((m, w), (_, y))| {
                let res = m * theta - y;
                res.dot(&(w * res))
            })
            .sum();
    }
    let dof = (3 * k - 5) as f64;
    let centre = Point3::new(theta[0], theta[1], theta[2]);
    chi2.is_finite().then_some((chi2 / dof, dof, centre))
}

/// [`pivot_test`] as a rank test of the centre: rank 0 when `chi^2 / dof` is within `slack`
/// times its `z`-quantile (a fixed centre), 1 otherwise; with the centre in `a`'s frame.
fn pivot_rank_test(c: &PairColumns, z: f64, slack: f64) -> Option<(RankTest, Point3<f64>)> {
    let (per_dof, dof, centre) = pivot_test(c)?;
    Some((chi2_rank_test(c, per_dof, dof, z, slack), centre))
}

/// A reference-free test's `chi^2 / dof` (over the frames of `c`) as a rank test: rank 0 when
/// it is within `slack` times its `z`-quantile, 1 otherwise.
fn chi2_rank_test(c: &PairColumns, per_dof: f64, dof: f64, z: f64, slack: f64) -> RankTest {
    let bound = slack * crate::rank::chi2_per_dof_quantile(dof, z);
    RankTest {
        singular_values: Vec::new(),
        whitened: Vec::new(),
        threshold: None,
        rank: usize::from(per_dof > bound),
        n_columns: c.x_abs.len(),
        chi2_per_dof: vec![per_dof],
        chi2_bound: vec![bound],
    }
}

/// Reference-free test for a universal joint: are there unit axes `n` fixed in `a` and `m`
/// fixed in `b` at a fixed angle, `n . R_k m = cos(angle)` in every frame (`R_k` = `a_from_b`'s
/// rotation)? Two intersecting axes, one turning with each body, keep that angle whatever
/// their two angles; a third rotation breaks it. Weighted least squares, each frame's residual
/// weighted by its variance from the relative rotation's covariance (`g^T C g`, with
/// `g = (R_k m) x n`), by alternating eigenvector steps in `n` and `m` from the linear
/// relaxation (the direction `N` of the 3 x 3 matrices with `<N, R_k>` most nearly constant,
/// split into `n m^T`). Returns `(chi^2 / dof, dof, n, m)` with `dof = K - 5`.
fn axes_test(c: &PairColumns) -> Option<(f64, f64, Vector3<f64>, Vector3<f64>)> {
    let k = c.x_abs.len();
    if k < 8 {
        return None;
    }
    // The residual has many local minima in the axes: a coarse search over the first axis,
    // each direction with its best second axis (the smallest direction of the weighted,
    // centred `R_k^T n`), and a descent from the best few.
    let mut scored: Vec<(f64, Vector3<f64>, Vector3<f64>)> =
        kinetree_core::geom::hemisphere(AXES_GRID)
            .into_iter()
            .filter_map(|n| {
                let pulled: Vec<Vector3<f64>> =
                    c.x_abs.iter().map(|(r, _)| r.transpose() * n).collect();
                let uniform = vec![1.0; k];
                let m = smallest_spread(&pulled, &uniform)?;
                let m = smallest_spread(&pulled, &axes_weights(c, &n, &m))?;
                Some((axes_chi2(c, &n, &m), n, m))
            })
            .filter(|(chi2, ..)| chi2.is_finite())
            .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Wrong basins are broad and fill the top of the list; the starts are the best
    // directions at least `AXES_SEPARATION_RAD` from each other.
    let mut starts: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::new();
    for &(_, n, m) in &scored {
        if starts.len() == AXES_STARTS {
            break;
        }
        if starts
            .iter()
            .all(|(s, _)| s.dot(&n).abs() < AXES_SEPARATION_RAD.cos())
        {
            starts.push((n, m));
        }
    }
    starts.extend(relaxed_axes(c));
    let mut best: Option<(f64, Vector3<f64>, Vector3<f64>)> = None;
    for (n, m) in starts {
        let found = refine_axes(c, n, m);
        if best.is_none_or(|b| found.0 < b.0) {
            best = Some(found);
        }
    }
    let (chi2, n, m) = best?;
    let dof = (k - 5) as f64;
    chi2.is_finite().then_some((chi2 / dof, dof, n, m))
}

/// Starts of [`axes_test`] from its linear relaxation: `n . R_k m` constant is `<N, R_k>`
/// constant for the rank-one `N = n m^T`, so each direction of the centred 9-vectors of the
/// rotations, smallest first, split by its largest singular value into `(n, m)`.
fn relaxed_axes(c: &PairColumns) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    use kinetree_core::nalgebra::{SMatrix, SVector};
    let k = c.x_abs.len() as f64;
    let flat = |r: &Matrix3<f64>| SVector::<f64, 9>::from_column_slice(r.as_slice());
    let mean: SVector<f64, 9> = c
        .x_abs
        .iter()
        .map(|(r, _)| flat(r))
        .sum::<SVector<f64, 9>>()
        / k;
    let scatter: SMatrix<f64, 9, 9> = c
        .x_abs
        .iter()
        .map(|(r, _)| {
            let d = flat(r) - mean;
            d * d.transpose()
        })
        .sum();
    let eig = scatter.symmetric_eigen();
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    order
        .into_iter()
        .filter_map(|e| {
            let split =
                Matrix3::from_column_slice(eig.eigenvectors.column(e).as_slice()).svd(true, true);
            let top = split.singular_values.imax();
            Some((
                split.u?.column(top).into_owned(),
                split.v_t?.row(top).transpose(),
            ))
        })
        .collect()
}

/// Directions of [`axes_test`]'s coarse search over the first axis: about 4.5 deg apart (the
/// search's measurements are in `docs/decisions.md`, universal joints).
const AXES_GRID: usize = 1000;

/// Descents of [`axes_test`], from the best directions of its search...
const AXES_STARTS: usize = 12;

/// ... at least this far apart (radians, 10 deg).
const AXES_SEPARATION_RAD: f64 = 0.175;

/// Default of [`Chi2RankParams::universal_slack`] (`docs/decisions.md`).
pub const UNIVERSAL_SLACK: f64 = 1.25;

/// Default of [`Chi2RankParams::hidden_hinge_ratio`] (`docs/decisions.md`).
pub const HIDDEN_HINGE_RATIO: f64 = 1.8;

/// Default of [`Chi2RankParams::hidden_slide_ratio`] (`docs/decisions.md`,
/// `dof.hidden_slide_ratio`).
pub const HIDDEN_SLIDE_RATIO: f64 = 0.0;

/// Default of [`Chi2RankParams::hidden_hinge_min_angle_deg`] (`docs/decisions.md`).
pub const HIDDEN_HINGE_MIN_ANGLE_DEG: f64 = 5.0;

/// Most damped Gauss-Newton steps of each descent of [`axes_test`].
const AXES_ITERATIONS: usize = 100;

/// Each frame's weight in [`axes_test`] at the axes `n` (in `a`) and `m` (in `b`): the inverse
/// variance of `n . R_k m` from the relative rotation's covariance.
fn axes_weights(c: &PairColumns, n: &Vector3<f64>, m: &Vector3<f64>) -> Vec<f64> {
    c.x_abs
        .iter()
        .zip(&c.rel_rot_cov)
        .map(|((r, _), cov)| {
            let g = (r * m).cross(n);
            let var = g.dot(&(cov * g));
            if var > 0.0 && var.is_finite() {
                1.0 / var
            } else {
                0.0
            }
        })
        .collect()
}

/// [`axes_test`]'s `chi^2` at the axes `n` and `m`, the fixed angle at its weighted best.
fn axes_chi2(c: &PairColumns, n: &Vector3<f64>, m: &Vector3<f64>) -> f64 {
    let w = axes_weights(c, n, m);
    let values: Vec<f64> = c.x_abs.iter().map(|(r, _)| n.dot(&(r * m))).collect();
    let total: f64 = w.iter().sum();
    if total <= 0.0 {
        return f64::INFINITY;
    }
    let mean = values.iter().zip(&w).map(|(v, w)| v * w).sum::<f64>() / total;
    values
        .iter()
        .zip(&w)
        .map(|(v, w)| w * (v - mean).powi(2))
        .sum()
}

/// The unit vector `x` minimising `sum w (x . v - mean)^2`: the smallest direction of the
/// weighted scatter of `vs` about their weighted mean.
fn smallest_spread(vs: &[Vector3<f64>], w: &[f64]) -> Option<Vector3<f64>> {
    let total: f64 = w.iter().sum();
    if total <= 0.0 {
        return None;
    }
    let centre: Vector3<f64> = vs.iter().zip(w).map(|(v, w)| v * *w).sum::<Vector3<f64>>() / total;
    let spread: Matrix3<f64> = vs
        .iter()
        .zip(w)
        .map(|(v, w)| (v - centre) * (v - centre).transpose() * *w)
        .sum();
    let e = spread.symmetric_eigen();
    Some(e.eigenvectors.column(e.eigenvalues.imin()).into_owned())
}

/// [`axes_test`]'s descent from the axes `n` and `m`: damped Gauss-Newton in the two axes'
/// tangent planes and the fixed angle's cosine, the weights taken at each step's start and a
/// step kept only when the `chi^2` (with its own weights) falls. Returns `(chi^2, n, m)`.
fn refine_axes(
    c: &PairColumns,
    mut n: Vector3<f64>,
    mut m: Vector3<f64>,
) -> (f64, Vector3<f64>, Vector3<f64>) {
    use kinetree_core::nalgebra::{SMatrix, SVector};
    let mut chi2 = axes_chi2(c, &n, &m);
    let mut lambda = 1e-3;
    for _ in 0..AXES_ITERATIONS {
        let w = axes_weights(c, &n, &m);
        let total: f64 = w.iter().sum();
        if total <= 0.0 {
            break;
        }
        let values: Vec<f64> = c.x_abs.iter().map(|(r, _)| n.dot(&(r * m))).collect();
        let cosine = values.iter().zip(&w).map(|(v, w)| v * w).sum::<f64>() / total;
        let (n1, n2) = perpendicular_basis(&n);
        let (m1, m2) = perpendicular_basis(&m);
        let mut normal = SMatrix::<f64, 5, 5>::zeros();
        let mut gradient = SVector::<f64, 5>::zeros();
        for (((r, _), v), w) in c.x_abs.iter().zip(&values).zip(&w) {
            let (in_a, in_b) = (r * m, r.transpose() * n);
            let j = SVector::<f64, 5>::new(
                in_a.dot(&n1),
                in_a.dot(&n2),
                in_b.dot(&m1),
                in_b.dot(&m2),
                -1.0,
            );
            normal += j * j.transpose() * *w;
            gradient += j * ((v - cosine) * w);
        }
        let mut improved = false;
        while lambda < 1e8 {
            let mut damped = normal;
            for i in 0..5 {
                damped[(i, i)] *= 1.0 + lambda;
            }
            let Some(step) = damped.try_inverse().map(|inv| -(inv * gradient)) else {
                lambda *= 10.0;
                continue;
            };
            let trial_n = (n + n1 * step[0] + n2 * step[1]).normalize();
            let trial_m = (m + m1 * step[2] + m2 * step[3]).normalize();
            let trial = axes_chi2(c, &trial_n, &trial_m);
            if trial < chi2 {
                improved = chi2 - trial > 1e-10 * chi2;
                (n, m, chi2) = (trial_n, trial_m, trial);
                lambda = (lambda * 0.1).max(1e-9);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (chi2, n, m)
}

/// [`axes_test`] as a rank test: rank 0 when `chi^2 / dof` is within `slack` times its
/// `z`-quantile (two intersecting axes), 1 otherwise; with the axis fixed in `a` (in `a`'s
/// frame) and the one fixed in `b` (in `b`'s).
fn axes_rank_test(
    c: &PairColumns,
    z: f64,
    slack: f64,
) -> Option<(RankTest, Vector3<f64>, Vector3<f64>)> {
    let (per_dof, dof, n, m) = axes_test(c)?;
    Some((chi2_rank_test(c, per_dof, dof, z, slack), n, m))
}

/// Inverse left Jacobian of SO(3) at `phi = theta a`:
/// `(theta/2) cot(theta/2) I + (1 - (theta/2) cot(theta/2)) a a^T - [phi/2]x`.
fn inverse_left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let half = phi.cross_matrix() * 0.5;
    if theta < 1e-6 {
        return Matrix3::identity() - half;
    }
    let a = phi / theta;
    let h = theta / 2.0;
    let c = h / h.tan();
    Matrix3::identity() * c + a * a.transpose() * (1.0 - c) - half
}

/// Settings shared by the testers: which frames count for the centre of rotation, and
/// whether a centre fixed in both bodies makes a pair that turns about more than one axis a
/// ball joint.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CentreSettings {
    min_angle_rad: f64,
    min_angle_in_std: f64,
    spherical: bool,
    universal: bool,
    universal_slack: f64,
}

/// RMS angle of a rotation test's first direction above the noise that its second shows:
/// `sqrt((s1^2 - s2^2) / K)` for singular values `s1`, `s2` over `K` columns (radians).
fn turning_angle(rotation: &RankTest) -> f64 {
    let s = &rotation.singular_values;
    let (Some(s1), Some(s2)) = (s.first(), s.get(1)) else {
        return 0.0;
    };
    ((s1 * s1 - s2 * s2).max(0.0) / rotation.n_columns.max(1) as f64).sqrt()
}

/// Types the joint between `a` and `b` from the rank decisions of `rule`.
fn classify(
    c: &PairColumns,
    a: Option<usize>,
    b: usize,
    rule: RankRule,
    centre_settings: CentreSettings,
) -> Result<PairDof> {
    let translation = rank_test(&c.u, &c.u_cov, 3, rule);
    let rotation = rank_test(&c.rot, &c.rot_cov, 3, rule);
    // A rotation the slack hides (a slender body turning about its long axis, whose rotation
    // is poorly known) makes a revolute joint prismatic or rigid. When the rotation stands
    // out against the measured noise level (`hidden_next_rank`), rank 1 is tried, and kept
    // only if it gives a revolute joint: a prismatic child whose poses carry a
    // motion-dependent bias (box corners occluded as it slides) shows such a rotation too,
    // but no fixed pivot explains its translation. Only the rotation is retried: on
    // translations, mis-modelled anisotropic noise made a prismatic child's line a plane.
    //
    // Below that bound, a rotation that stands out against the measured level by `ratio`
    // (a finger's distal phalanx: 1-2.5 cm, a few keypoints seen, flexing through 30-90 deg
    // with several degrees of rotation noise per frame) is tried too, and kept only as a
    // hinge that turns by at least `min_angle_rad` RMS above the noise: a slide carried by a
    // body that mixes points of both sides turns that body by a degree or two with the
    // slide, which a hinge about a far axis mimics.
    if let RankRule::Chi2 {
        z,
        min_excess,
        hidden_hinge: HiddenHinge {
            ratio,
            min_angle_rad,
        },
        ..
    } = rule
        && rotation.rank == 0
    {
        let by_bound = crate::rank::hidden_next_rank(&rotation, 3, z, min_excess);
        if by_bound
            || ratio > 0.0
                && crate::rank::hidden_next_rank_above(&rotation, 3, z, min_excess, ratio)
        {
            let mut turning = rotation.clone();
            turning.rank = 1;
            let retried =
                classify_ranks(c, a, b, rule, centre_settings, translation.clone(), turning)?;
            if matches!(retried.joint, JointKind::Revolute { .. })
                && (by_bound || turning_angle(&rotation) >= min_angle_rad)
            {
                return Ok(retried);
            }
        }
    }
    // A slide the slack hides between two bodies: rank 1 when the translation stands out
    // against its measured level as a hidden rotation must. Not against the camera: a
    // static body is what the other tests are measured from.
    if let RankRule::Chi2 {
        z,
        min_excess,
        hidden_slide_ratio,
        ..
    } = rule
        && hidden_slide_ratio > 0.0
        && a.is_some()
        && rotation.rank == 0
        && translation.rank == 0
        && crate::rank::hidden_next_rank_above(&translation, 3, z, min_excess, hidden_slide_ratio)
    {
        let mut sliding = translation.clone();
        sliding.rank = 1;
        return classify_ranks(c, a, b, rule, centre_settings, sliding, rotation);
    }
    classify_ranks(c, a, b, rule, centre_settings, translation, rotation)
}

/// [`classify`] with the translation and rotation rank tests decided.
fn classify_ranks(
    c: &PairColumns,
    a: Option<usize>,
    b: usize,
    rule: RankRule,
    centre_settings: CentreSettings,
    translation: RankTest,
    rotation: RankTest,
) -> Result<PairDof> {
    let mut centre = RankTest::empty();
    let mut centre_uncentred = RankTest::empty();
    let mut axes = RankTest::empty();
    let mut sliding = RankTest::empty();
    let mut joint = JointKind::MultiDof;
    let dof;
    let fit_ratio;
    match rotation.rank {
        0 => {
            dof = translation.rank;
            fit_ratio = rotation
                .next_rank_ratio()
                .max(translation.next_rank_ratio());
            if translation.rank == 0 {
                joint = JointKind::Rigid;
            } else if translation.rank == 1 {
                // Fit the line to the centred displacements, as the rank test did: the
                // uncentred columns are anchored at the reference frame's own noisy position.
                let mean: Vector3<f64> = c.u.iter().sum::<Vector3<f64>>() / c.u.len() as f64;
                let centred: Vec<Vector3<f64>> = c.u.iter().map(|u| u - mean).collect();
                let axis = weighted_direction(&centred, &c.u_cov)
                    .ok_or_else(|| Error::Numerical("prismatic axis".into()))?;
                joint = JointKind::Prismatic {
                    axis: canonical_sign(axis),
                };
            }
        }
        1 => {
            let log_axis = weighted_direction(&c.rot, &c.rot_cov);
            let rotations: Vec<Matrix3<f64>> = c.x_abs.iter().map(|(r, _)| *r).collect();
            let axis = canonical_sign(
                fixed_axis(&rotations, &c.rel_rot_cov, log_axis)
                    .or(log_axis)
                    .ok_or_else(|| Error::Numerical("rotation axis".into()))?,
            );
            // Basis of the plane perpendicular to the axis, for the centre columns.
            let (e1, e2) = perpendicular_basis(&axis);
            let basis = Matrix3::from_rows(&[e1.transpose(), e2.transpose(), axis.transpose()]);
            let mut w = Vec::new();
            let mut w_cov = Vec::new();
            let mut a_mat = Matrix3::zeros();
            let mut b_vec = Vector3::zeros();
            let mut z = Vec::with_capacity(c.u.len());
            let mut z_cov = Vec::with_capacity(c.u.len());
            let thetas: Vec<f64> = c.q_rel.iter().map(|q| angle_about(q, &axis)).collect();
            // Uncertainty of the fitted axis, (sum theta^2 Omega)^-1 across the axis: a tilt
            // times a large displacement looks like sliding.
            let across = Matrix3::identity() - axis * axis.transpose();
            let info: Matrix3<f64> = thetas
                .iter()
                .zip(&c.rot_cov)
                .map(|(t, cov)| cov.try_inverse().unwrap_or_else(Matrix3::zeros) * (t * t))
                .sum();
            let axis_cov = across * info.try_inverse().unwrap_or_else(Matrix3::zeros) * across;
            for (k, &theta) in thetas.iter().enumerate() {
                let m = c.q_rel[k].to_rotation_matrix().into_inner() - Matrix3::identity();
                let info = c.u_cov[k].try_inverse().unwrap_or_else(Matrix3::identity);
                a_mat += m.transpose() * info * m;
                b_vec += m.transpose() * info * c.u[k];
                let mut zc = Matrix3::identity();
                zc[(0, 0)] = axis.dot(&(c.u_cov[k] * axis)) + c.u[k].dot(&(axis_cov * c.u[k]));
                z.push(Vector3::new(axis.dot(&c.u[k]), 0.0, 0.0));
                z_cov.push(zc);
                let rot_std = c.rot_cov[k].symmetric_eigenvalues().max().max(0.0).sqrt();
                let min_angle = centre_settings
                    .min_angle_rad
                    .max(centre_settings.min_angle_in_std * rot_std);
                if theta.abs() < min_angle {
                    continue;
                }
                let gain = 2.0 * (theta.abs() / 2.0).sin();
                if let Ok(pinv) = m.pseudo_inverse(0.5 * gain) {
                    let v = pinv * c.u[k];
                    // Noise of w = (R - I)^+ u: from u (this frame's and the reference's,
                    // which P varies per frame so centring cannot remove it) and from the
                    // rotation error inside (R - I), whose derivative is P [R v]x.
                    let r_v = (c.q_rel[k] * v).cross_matrix();
                    let jac = pinv * r_v;
                    let cov_w = pinv * (c.u_cov[k] + c.u_cov[c.reference_index]) * pinv.transpose()
                        + jac * (c.rot_cov[k] + c.rot_cov[c.reference_index]) * jac.transpose();
                    let wk = basis * v;
                    let mut cov = basis * cov_w * basis.transpose();
                    // Only the two in-plane coordinates carry data.
                    for i in 0..3 {
                        cov[(2, i)] = if i == 2 { 1.0 } else { 0.0 };
                        cov[(i, 2)] = if i == 2 { 1.0 } else { 0.0 };
                    }
                    w.push(Vector3::new(wk.x, wk.y, 0.0));
                    w_cov.push(cov);
                }
            }
            centre_uncentred = rank_test_uncentred(&w, &w_cov, 2, rule);
            match rule {
                RankRule::Chi2 { z: zq, slack, .. } => {
                    // One reference-free test covers a moving centre and sliding.
                    if let Some((test, _)) = pivot_rank_test(c, zq, slack) {
                        centre = test;
                    }
                }
                RankRule::Whitened { .. } => {
                    centre = rank_test(&w, &w_cov, 2, rule);
                    sliding = rank_test(&z, &z_cov, 1, rule);
                }
            }
            dof = (1 + centre.rank + sliding.rank).min(6);
            fit_ratio = rotation
                .next_rank_ratio()
                .max(centre.next_rank_ratio())
                .max(sliding.next_rank_ratio());
            if centre.rank == 0 && sliding.rank == 0 {
                // Least-squares centre: u_k = (R_k - I)(y_ref - c), regularised along the
                // axis so the pivot is the point of the axis level with b's origin.
                let scale = a_mat.trace().max(1e-300);
                let reg = a_mat + axis * axis.transpose() * scale;
                let v = reg
                    .try_inverse()
                    .map(|inv| inv * b_vec)
                    .unwrap_or_else(Vector3::zeros);
                joint = JointKind::Revolute {
                    axis,
                    pivot: Point3::from(c.y_ref - v),
                };
            }
        }
        _ => {
            let mut multi = (
                (rotation.rank + translation.rank).min(6),
                rotation.next_rank_ratio(),
            );
            // More than one rotation: a centre fixed in both bodies makes it a ball joint,
            // judged by the same reference-free chi-square as a revolute joint's pivot.
            if let RankRule::Chi2 { z: zq, slack, .. } = rule
                && centre_settings.spherical
                && let Some((test, centre_in_a)) = pivot_rank_test(c, zq, slack)
            {
                if test.rank == 0 {
                    joint = JointKind::Spherical {
                        centre: centre_in_a,
                    };
                    multi = (3, multi.1.max(test.next_rank_ratio()));
                    // Fewer DoF when the data allow: two intersecting axes, one in each body.
                    if centre_settings.universal
                        && let Some((two, n, m)) =
                            axes_rank_test(c, zq, centre_settings.universal_slack)
                    {
                        if two.rank == 0 {
                            let axis = canonical_sign(n);
                            let child_axis = if axis.dot(&n) < 0.0 { -m } else { m };
                            joint = JointKind::Universal {
                                axis,
                                child_axis,
                                centre: centre_in_a,
                            };
                            multi = (2, multi.1.max(two.next_rank_ratio()));
                        }
                        axes = two;
                    }
                }
                centre = test;
            }
            (dof, fit_ratio) = multi;
        }
    }
    let distance_m = a.and_then(|_| {
        let mut d: Vec<f64> = c.x_abs.iter().map(|(_, t)| t.norm()).collect();
        d.sort_by(f64::total_cmp);
        d.get(d.len() / 2).copied()
    });
    let ball = a.and_then(|_| ball_fit(&c.x_abs));
    Ok(PairDof {
        a,
        b,
        reference_frame: c.reference_frame,
        translation,
        rotation,
        centre,
        sliding,
        centre_uncentred,
        axes,
        dof,
        joint,
        fit_ratio,
        distance_m,
        ball_fit_rms_m: ball.map(|b| b.0),
        ball_reach_m: ball.map(|b| b.1),
    })
}

/// [`PairDof::ball_fit_rms_m`] and [`PairDof::ball_reach_m`] of the relative poses
/// `a_from_b` in `x_abs`: the point `c` in `a`'s frame and `w` in `b`'s that minimise
/// `sum_k |c - R_k w - y_k|^2` (one gauge direction along a hinge's axis, fixed by a tiny
/// ridge, which takes the point nearest the origins), the RMS of the residuals, and the larger
/// of `|c|` and `|w|`. Unweighted, unlike [`pivot_test`]: distances to compare between pairs,
/// not a test against noise.
fn ball_fit(x_abs: &[(Matrix3<f64>, Vector3<f64>)]) -> Option<(f64, f64)> {
    use kinetree_core::nalgebra::{SMatrix, SVector};
    let k = x_abs.len();
    if k < 3 {
        return None;
    }
    // Normal equations of the rows [I, -R_k] (c, w) = y_k, summed over the frames.
    let mut sum_r = Matrix3::zeros();
    let mut sum_y = Vector3::zeros();
    let mut sum_rty = Vector3::zeros();
    for (r, y) in x_abs {
        sum_r += r;
        sum_y += y;
        sum_rty += r.transpose() * y;
    }
    let n = k as f64;
    let mut normal = SMatrix::<f64, 6, 6>::zeros();
    normal
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(Matrix3::identity() * n));
    normal
        .fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(Matrix3::identity() * n));
    normal.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-sum_r));
    normal
        .fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-sum_r.transpose()));
    let mut rhs = SVector::<f64, 6>::zeros();
    rhs.fixed_rows_mut::<3>(0).copy_from(&sum_y);
    rhs.fixed_rows_mut::<3>(3).copy_from(&(-sum_rty));
    let ridge = n * 1e-9;
    let theta = (normal + SMatrix::<f64, 6, 6>::identity() * ridge).try_inverse()? * rhs;
    let (c, w) = (
        theta.fixed_rows::<3>(0).into_owned(),
        theta.fixed_rows::<3>(3).into_owned(),
    );
    let ss: f64 = x_abs
        .iter()
        .map(|(r, y)| (c - r * w - y).norm_squared())
        .sum();
    let rms = (ss / n).sqrt();
    let reach = c.norm().max(w.norm());
    (rms.is_finite() && reach.is_finite()).then_some((rms, reach))
}

fn check_positive(name: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: name.into(),
            message: format!("must be finite and positive, got {v}"),
        })
    }
}

/// Parameters of [`SvdRank`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SvdRankParams {
    /// A direction counts when its RMS amplitude exceeds this many noise std-devs.
    pub kappa: f64,
    /// Frames whose relative rotation is below this angle (radians) are skipped for the centre
    /// of rotation, where `(R - I)` is ill-conditioned...
    pub min_centre_angle_rad: f64,
    /// ... and so are frames whose rotation is below this many rotation-noise std-devs.
    pub min_centre_angle_in_std: f64,
}

impl Default for SvdRankParams {
    fn default() -> Self {
        Self {
            kappa: 3.0,
            min_centre_angle_rad: 0.05,
            min_centre_angle_in_std: 5.0,
        }
    }
}

impl SvdRankParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a non-positive or non-finite value.
    pub fn validate(&self) -> Result<()> {
        check_positive("kappa", self.kappa)?;
        check_positive("min_centre_angle_rad", self.min_centre_angle_rad)?;
        check_positive("min_centre_angle_in_std", self.min_centre_angle_in_std)
    }
}

/// The paper's SVD rank tests (Sec. III-B) with noise-derived thresholds.
///
/// For body `b` relative to frame `a` (camera or body), over the frames where both have a
/// pose, let `X_k = a_from_b(k)` and let `r` be the common frame with the most precise
/// relative rotation. Four matrices are tested:
/// - translation columns `u_k = y_k - y_r`, the displacement of `b`'s origin (its centroid)
///   in `a`'s body frame: rank 0 rigid, 1 prismatic, 2 for a circle;
/// - rotation columns `log(R_k R_r^T)` (axis-angle through quaternions): rank 1 for a fixed
///   axis;
/// - centre columns `(R_k R_r^T - I)^+ u_k` over frames with enough rotation: rank 0 when
///   the centre of rotation is fixed (since `u_k = (R - I)(y_r - c)`);
/// - sliding, the translation along the rotation axis: rank 1 for a screw or cylindrical
///   motion.
///
/// Ranks follow [`RankRule::Whitened`]: each column is divided by its worst-direction noise
/// std-dev, propagated from the per-frame pose covariances
/// ([`kinetree_core::PoseQuality`]) times `noise_sigma_m^2`.
///
/// Complexity: O(T) per pair.
#[derive(Debug, Clone)]
pub struct SvdRank {
    params: SvdRankParams,
}

impl SvdRank {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: SvdRankParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl DofTester for SvdRank {
    fn name(&self) -> &str {
        "svd_rank"
    }

    fn test_pair(&self, input: &DofInput<'_>, a: Option<usize>, b: usize) -> Result<PairDof> {
        let c = pair_columns(input.poses, a, b, input.noise_sigma_m, (0.0, 0.0))?;
        classify(
            &c,
            a,
            b,
            RankRule::Whitened {
                kappa: self.params.kappa,
            },
            CentreSettings {
                min_angle_rad: self.params.min_centre_angle_rad,
                min_angle_in_std: self.params.min_centre_angle_in_std,
                spherical: false,
                universal: false,
                universal_slack: UNIVERSAL_SLACK,
            },
        )
    }
}

/// Parameters of [`Chi2Rank`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Chi2RankParams {
    /// Standard normal quantile of each test.
    pub z: f64,
    /// Tolerance factor on `chi^2 / dof` for what the noise model leaves out (reference-shape
    /// error, linearisation). On random 3- and 7-joint mechanisms, 1.5 rejected true sliding-free
    /// revolute joints (chi^2/dof 2.5-3.8 against a bound of 2.5); 2.5 and 4 gave the same
    /// results.
    pub slack: f64,
    /// As [`SvdRankParams::min_centre_angle_rad`].
    pub min_centre_angle_rad: f64,
    /// As [`SvdRankParams::min_centre_angle_in_std`].
    pub min_centre_angle_in_std: f64,
    /// Model error of every body's position, metres (std-dev per axis), added to the noise
    /// propagated through each pose fit: what a real joint adds to the ideal one (hub play,
    /// wobble, markers on skin). 0 for simulated mechanisms.
    pub model_error_m: f64,
    /// Model error of every body's orientation, radians (std-dev per axis).
    pub model_error_rad: f64,
    /// A rotation test's rank-0 residual per degree of freedom must exceed this for a
    /// rotation the slack hides to be looked for (default [`crate::MIN_EXCESS`], the nominal
    /// noise level).
    pub min_excess: f64,
    /// Whether a pair turning about more than one axis is a spherical joint when a centre
    /// fixed in both bodies explains its motion (the revolute joint's pivot test); `false`
    /// calls it multi-DoF, as `svd_rank` does (default true).
    pub spherical: bool,
    /// Whether such a pair is a universal joint when two intersecting axes, one fixed in each
    /// body, explain its rotations (`spherical` must be on; default true).
    pub universal: bool,
    /// Tolerance factor on the two-axis test's `chi^2 / dof`, as `slack` on the others
    /// (default 1.25: its noise model leaves out no reference frame or linearisation; see
    /// `docs/decisions.md`).
    pub universal_slack: f64,
    /// A rotation test that stops at rank 0 under its chi-square bound is retried at rank 1
    /// when its rank-0 residual per degree of freedom exceeds this many times its rank-1
    /// residual (the measured noise level) and a nested F-test at `z` rejects rank 0; the
    /// retry stands only as a hinge that turns by at least `hidden_hinge_min_angle_deg`.
    /// Default 1.8; 0 turns the rule off (`docs/decisions.md`, `dof.hidden_hinge_ratio`).
    pub hidden_hinge_ratio: f64,
    /// Least RMS angle of such a hinge's rotation above the noise, degrees (default 5).
    pub hidden_hinge_min_angle_deg: f64,
    /// A translation between two bodies that stops at rank 0, with no rotation, under its
    /// chi-square bound is retried at rank 1 (a slide) when its rank-0 residual per degree
    /// of freedom exceeds this many times its rank-1 residual (the measured noise level) and
    /// a nested F-test at `z` rejects rank 0: a gripper's finger sliding a few noise levels.
    /// Default 0, off (`docs/decisions.md`, `dof.hidden_slide_ratio`: on the hands sweep it
    /// gains and loses joints by turns; 1.8, as `hidden_hinge_ratio`, is the measured choice).
    pub hidden_slide_ratio: f64,
}

impl Default for Chi2RankParams {
    fn default() -> Self {
        Self {
            z: 4.0,
            slack: 2.5,
            min_centre_angle_rad: 0.05,
            min_centre_angle_in_std: 5.0,
            model_error_m: 0.0,
            model_error_rad: 0.0,
            min_excess: crate::MIN_EXCESS,
            spherical: true,
            universal: true,
            universal_slack: UNIVERSAL_SLACK,
            hidden_hinge_ratio: HIDDEN_HINGE_RATIO,
            hidden_hinge_min_angle_deg: HIDDEN_HINGE_MIN_ANGLE_DEG,
            hidden_slide_ratio: HIDDEN_SLIDE_RATIO,
        }
    }
}

impl Chi2RankParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a non-positive or non-finite value (a negative or
    /// non-finite model error).
    pub fn validate(&self) -> Result<()> {
        check_positive("z", self.z)?;
        check_positive("slack", self.slack)?;
        check_positive("universal_slack", self.universal_slack)?;
        check_positive("min_centre_angle_rad", self.min_centre_angle_rad)?;
        check_positive("min_centre_angle_in_std", self.min_centre_angle_in_std)?;
        for (name, v) in [
            ("model_error_m", self.model_error_m),
            ("model_error_rad", self.model_error_rad),
            ("min_excess", self.min_excess),
            ("hidden_hinge_ratio", self.hidden_hinge_ratio),
            ("hidden_slide_ratio", self.hidden_slide_ratio),
            (
                "hidden_hinge_min_angle_deg",
                self.hidden_hinge_min_angle_deg,
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::InvalidParameter {
                    name: name.into(),
                    message: format!("must be finite and at least 0, got {v}"),
                });
            }
        }
        Ok(())
    }
}

/// The same four tests as [`SvdRank`], decided by chi-square with the full per-frame noise
/// covariance ([`RankRule::Chi2`]). A thin body's rotation is well determined about two axes
/// and poorly about its long axis; scalar whitening by the worst axis hides real motion about
/// the good axes, while the Mahalanobis fit weighs each direction by its own precision.
///
/// Complexity: O(T) per pair (a few dozen 3 x 3 iterations per frame).
#[derive(Debug, Clone)]
pub struct Chi2Rank {
    params: Chi2RankParams,
}

impl Chi2Rank {
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: Chi2RankParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { params })
    }
}

impl DofTester for Chi2Rank {
    fn name(&self) -> &str {
        "chi2_rank"
    }

    fn test_pair(&self, input: &DofInput<'_>, a: Option<usize>, b: usize) -> Result<PairDof> {
        let c = pair_columns(
            input.poses,
            a,
            b,
            input.noise_sigma_m,
            (self.params.model_error_m, self.params.model_error_rad),
        )?;
        classify(
            &c,
            a,
            b,
            RankRule::Chi2 {
                z: self.params.z,
                slack: self.params.slack,
                min_excess: self.params.min_excess,
                hidden_hinge: HiddenHinge {
                    ratio: self.params.hidden_hinge_ratio,
                    min_angle_rad: self.params.hidden_hinge_min_angle_deg.to_radians(),
                },
                hidden_slide_ratio: self.params.hidden_slide_ratio,
            },
            CentreSettings {
                min_angle_rad: self.params.min_centre_angle_rad,
                min_angle_in_std: self.params.min_centre_angle_in_std,
                spherical: self.params.spherical,
                universal: self.params.universal,
                universal_slack: self.params.universal_slack,
            },
        )
    }

    fn model_error_rad(&self) -> f64 {
        self.params.model_error_rad
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinetree_core::nalgebra::{Isometry3, Translation3, Unit};

    /// Rotations about a wobbling axis through a range of angles, as a hinge with pose noise
    /// gives them, or spread over every direction.
    fn rotations(n: usize, spread: bool) -> Vec<Option<Isometry3<f64>>> {
        (0..n)
            .map(|k| {
                let t = k as f64;
                let axis = if spread {
                    Vector3::new((1.3 * t).sin(), (2.1 * t).cos(), (0.7 * t).sin() + 0.2)
                } else {
                    Vector3::new(0.01 * (3.7 * t).sin(), 1.0, 0.01 * (5.3 * t).cos())
                };
                let angle = if spread {
                    3.0 * (0.37 * t).sin()
                } else {
                    1.2 * (0.05 * t).sin()
                };
                let q = UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), angle);
                Some(Isometry3::from_parts(Translation3::identity(), q))
            })
            .collect()
    }

    /// Rotations within about 1e-4 rad of a fixed turn, as the camera against a static body
    /// gives them.
    fn cluster(n: usize) -> Vec<Option<Isometry3<f64>>> {
        let base = UnitQuaternion::from_euler_angles(0.7, -1.1, 2.3);
        (0..n)
            .map(|k| {
                let t = k as f64;
                let wobble = Vector3::new((1.7 * t).sin(), (2.9 * t).cos(), (0.3 * t).sin()) * 1e-4;
                let q = base * UnitQuaternion::from_scaled_axis(wobble);
                Some(Isometry3::from_parts(Translation3::identity(), q))
            })
            .collect()
    }

    /// The columns [`axes_test`] reads of `n` frames of relative rotations `turn(k)`, each
    /// perturbed by an independent rotation of `noise` rad per axis (a fixed xorshift
    /// generator's Gaussian draws) with that covariance.
    fn turned(n: usize, noise: f64, turn: impl Fn(f64) -> UnitQuaternion<f64>) -> PairColumns {
        let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut gauss = move || {
            let (u, v) = (uniform().max(1e-300), uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        let x_abs: Vec<(Matrix3<f64>, Vector3<f64>)> = (0..n)
            .map(|k| {
                let e = Vector3::new(gauss(), gauss(), gauss()) * noise;
                let r = UnitQuaternion::from_scaled_axis(e) * turn(k as f64);
                (r.to_rotation_matrix().into_inner(), Vector3::zeros())
            })
            .collect();
        PairColumns {
            reference_frame: 0,
            reference_index: 0,
            u: Vec::new(),
            u_cov: Vec::new(),
            rot: Vec::new(),
            rot_cov: Vec::new(),
            q_rel: Vec::new(),
            rel_rot_cov: vec![Matrix3::identity() * noise * noise; n],
            y_ref: Vector3::zeros(),
            x_abs,
            a_cov: Vec::new(),
            b_cov: Vec::new(),
        }
    }

    /// About a ball joint (`c` in `a`, `w` in `b`) the fit's RMS is zero to rounding and its
    /// centre is `c` and `w`, at their distances from the origins; with the
    /// child's end of the centre wobbling on a circle of radius `e` the RMS is `e` (its
    /// best fixed point is the circle's centre); along a slide it is the slide's spread.
    #[test]
    fn the_ball_fit_measures_how_far_a_pair_is_from_a_ball_joint() {
        let c = Vector3::new(0.1, -0.05, 0.2);
        let w = Vector3::new(-0.02, 0.15, 0.03);
        let rotation = |k: usize| {
            let t = k as f64;
            UnitQuaternion::from_euler_angles(
                0.7 * (0.05 * t).sin(),
                0.4 * (0.08 * t).cos(),
                0.1 * t,
            )
            .to_rotation_matrix()
            .into_inner()
        };
        let pair = |wobble: f64, slide: f64| -> Vec<(Matrix3<f64>, Vector3<f64>)> {
            (0..400)
                .map(|k| {
                    let r = rotation(k);
                    let phase = 0.3 * k as f64;
                    let e = Vector3::new(phase.cos(), phase.sin(), 0.0) * wobble
                        + Vector3::x() * slide * (0.02 * k as f64).sin();
                    // c + e = R w + y: the ends meet up to `e`.
                    (r, c + e - r * w)
                })
                .collect()
        };
        let (exact, reach) = ball_fit(&pair(0.0, 0.0)).expect("fit");
        assert!(exact < 1e-9, "{exact}");
        // The centre's larger distance from the two origins: |c| here.
        assert!((reach - c.norm().max(w.norm())).abs() < 1e-6, "{reach}");
        let wobbling = ball_fit(&pair(0.01, 0.0)).expect("fit").0;
        assert!((wobbling - 0.01).abs() < 1e-3, "{wobbling}");
        let sliding = ball_fit(&pair(0.0, 0.1)).expect("fit").0;
        assert!(sliding > 0.05 && sliding < 0.08, "{sliding}");
        assert!(ball_fit(&pair(0.0, 0.0)[..2]).is_none());
    }

    #[test]
    fn the_axes_test_finds_a_universal_joint_and_rejects_a_ball() {
        let first = Vector3::new(1.0, 0.2, -0.1).normalize();
        let offset = UnitQuaternion::from_euler_angles(0.3, -0.5, 1.1);
        // The child's own axis: perpendicular to the first at zero.
        let second = offset.inverse() * Vector3::new(-0.2, 1.0, 0.0).normalize();
        let axis_angle =
            |a: Vector3<f64>, q: f64| UnitQuaternion::from_axis_angle(&Unit::new_normalize(a), q);
        let c = turned(300, 0.005, |t| {
            axis_angle(first, 0.6 * (0.07 * t).sin())
                * offset
                * axis_angle(second, 0.5 * (0.11 * t + 1.0).sin())
        });
        let (per_dof, dof, n, m) = axes_test(&c).expect("test");
        // As low as a descent from the true axes: the starts found the best minimum.
        let (from_truth, ..) = refine_axes(&c, first, second);
        assert!(
            per_dof * dof <= from_truth * (1.0 + 1e-6),
            "{per_dof} {from_truth}"
        );
        assert!((0.7..1.4).contains(&per_dof), "chi^2/dof {per_dof}");
        assert!(n.dot(&first).abs() > 0.9998, "first axis {n}");
        assert!(m.dot(&second).abs() > 0.9998, "second axis {m}");
        let (test, _, _) = axes_rank_test(&c, 4.0, 2.5).expect("rank test");
        assert_eq!(test.rank, 0);
        // A ball joint turning about all three axes breaks the fixed angle.
        let ball = turned(300, 0.005, |t| {
            UnitQuaternion::from_scaled_axis(Vector3::new(
                0.5 * (0.07 * t).sin(),
                0.4 * (0.11 * t).cos(),
                0.3 * (0.05 * t + 2.0).sin(),
            ))
        });
        let (test, _, _) = axes_rank_test(&ball, 4.0, 2.5).expect("rank test");
        assert_eq!(test.rank, 1, "{:?}", test.chi2_per_dof);
    }

    #[test]
    fn the_bound_is_tight_on_a_cluster_of_rotations() {
        let x = cluster(300);
        let qs: Vec<UnitQuaternion<f64>> = x.iter().flatten().map(|p| p.rotation).collect();
        let bound = angle_sum_bounds(&qs);
        for q in qs.iter().step_by(17) {
            let sum: f64 = qs.iter().map(|o| q.angle_to(o).powi(2)).sum();
            let b = bound(q);
            assert!(b <= sum * (1.0 + 1e-9), "{b} above {sum}");
            assert!(b >= sum * (1.0 - 1e-6), "{b} far below {sum}");
        }
        let frames: Vec<usize> = (0..x.len()).collect();
        let sums: Vec<f64> = qs
            .iter()
            .map(|q| qs.iter().map(|o| q.angle_to(o).powi(2)).sum())
            .collect();
        let mut expected = 0;
        for i in 0..sums.len() {
            if sums[i] < sums[expected] * (1.0 - 1e-12) {
                expected = i;
            }
        }
        assert_eq!(medoid_rotation(&frames, &x, &frames), expected);
    }

    #[test]
    fn the_bound_never_exceeds_the_sum_and_the_medoid_is_the_brute_force_one() {
        for spread in [false, true] {
            let x = rotations(400, spread);
            let frames: Vec<usize> = (0..x.len()).collect();
            let qs: Vec<UnitQuaternion<f64>> = x.iter().flatten().map(|p| p.rotation).collect();
            let sums: Vec<f64> = qs
                .iter()
                .map(|q| qs.iter().map(|o| q.angle_to(o).powi(2)).sum())
                .collect();
            let bound = angle_sum_bounds(&qs);
            for (q, &sum) in qs.iter().zip(&sums) {
                let b = bound(q);
                assert!(
                    b <= sum * (1.0 + 1e-12) + 1e-9,
                    "bound {b} above the sum {sum}"
                );
                // Within a factor even for angles near pi (4 + 4/3 against pi^2).
                assert!(b >= 0.5 * sum, "{b} {sum}");
            }
            for tied in [frames.clone(), frames.iter().copied().step_by(7).collect()] {
                let mut expected = tied[0];
                for &i in &tied {
                    if sums[i] < sums[expected] * (1.0 - 1e-12) {
                        expected = i;
                    }
                }
                assert_eq!(medoid_rotation(&frames, &x, &tied), expected);
            }
        }
    }
}
