//! Whether each joint's recorded motion can tell its type from the others: the spread of the
//! coordinates that differ between the types, against their per-frame precision.
//!
//! A one-DoF joint that barely moved cannot be told from the other one-DoF type: a short arc
//! is a straight path within noise, and a short slide an arc about an axis near the bodies.
//! A ball joint whose rotations stay within noise off one axis moved as a hinge would; so
//! did a universal joint whose angle about one axis stays within noise. The bound is
//! [`PositionLimits::min_identifiable_spread_in_std`].
//!
//! The other way round, a hinge whose child turns off its axis by more than the keypoint
//! noise explains was typed a hinge only because the type decision allows each body a model
//! error (skin under markers, joint play): a ball or universal joint fits that motion too.
//! The bound is [`PositionLimits::min_off_axis_spread_in_std`].

use kinetree_core::model::{JointType, Model, PositionLimits};
use kinetree_core::nalgebra::{
    DMatrix, DVector, Matrix2, Matrix3, Point3, Rotation3, Unit, UnitQuaternion, Vector2, Vector3,
};
use kinetree_core::{NotIdentifiableBasis, Tracks, Warning};

/// Fewest frames with a coordinate and its standard deviation for a spread to be measured.
const MIN_FRAMES: usize = 3;

/// The RMS spread about their mean of the rows of `values` (each frame's coordinates), in
/// units of each frame's standard deviation: along each coordinate (`principal` false) or
/// along the principal directions of their scatter, each coordinate divided by its
/// standard deviation (`principal` true), largest first. `None` with fewer than [`MIN_FRAMES`] usable frames.
fn spreads(values: &[(Vec<f64>, Vec<f64>)], principal: bool) -> Option<Vec<f64>> {
    let width = values.first()?.0.len();
    if values.len() < MIN_FRAMES || width == 0 {
        return None;
    }
    let n = values.len() as f64;
    let mean: DVector<f64> = values
        .iter()
        .map(|(v, _)| DVector::from_column_slice(v))
        .sum::<DVector<f64>>()
        / n;
    if !principal {
        let mut out: Vec<f64> = (0..width)
            .map(|i| {
                let z2: f64 = values
                    .iter()
                    .map(|(v, s)| ((v[i] - mean[i]) / s[i]).powi(2))
                    .sum();
                (z2 / n).sqrt()
            })
            .collect();
        out.sort_by(|a, b| b.total_cmp(a));
        return Some(out);
    }
    let mut scatter = DMatrix::<f64>::zeros(width, width);
    for (v, s) in values {
        let z =
            (DVector::from_column_slice(v) - &mean).component_div(&DVector::from_column_slice(s));
        scatter += &z * z.transpose();
    }
    let mut out: Vec<f64> = scatter
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .map(|e| (e.max(0.0) / n).sqrt())
        .collect();
    out.sort_by(|a, b| b.total_cmp(a));
    Some(out)
}

/// Frames where the joint has every coordinate and a positive, finite standard deviation of
/// each: `(coordinates, standard deviations)`.
fn usable(joint: &kinetree_core::model::Joint) -> Vec<(Vec<f64>, Vec<f64>)> {
    let ok = |s: &[f64]| s.iter().all(|v| v.is_finite() && *v > 0.0);
    if joint.joint_type.n_coordinates() > 1 {
        joint
            .coordinates
            .iter()
            .zip(&joint.coordinate_std)
            .filter_map(|(v, s)| Some((v.clone()?, s.clone()?)))
            .filter(|(v, s)| v.len() == s.len() && ok(s))
            .collect()
    } else {
        joint
            .positions
            .iter()
            .zip(&joint.position_std)
            .filter_map(|(v, s)| Some((vec![(*v)?], vec![(*s)?])))
            .filter(|(_, s)| ok(s))
            .collect()
    }
}

/// How much a hinge would have turned the child of prismatic `joint` to move it as the slide
/// did, in units of the child's rotation precision: the slide's RMS travel about its mean,
/// over the farthest a hinge's axis could lie from the child's centroid and still pass near
/// both bodies (twice the sum of the two bodies' extents: each one's largest distance from
/// its centroid to a placed point), against a per-frame rotation standard deviation of
/// `sigma sqrt(2 / sum |p|^2)` over the child's placed points `p` (a rigid body's rotation
/// precision from its points' spread). A slide that small cannot be told from a short arc.
/// `None` without positions or placed points.
fn hinge_turn_in_std(model: &Model, joint: &kinetree_core::model::Joint) -> Option<f64> {
    let travel: Vec<f64> = joint.positions.iter().flatten().copied().collect();
    if travel.len() < MIN_FRAMES {
        return None;
    }
    let mean = travel.iter().sum::<f64>() / travel.len() as f64;
    let rms = (travel.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / travel.len() as f64).sqrt();
    let placed = |b: usize| -> Vec<f64> {
        model
            .bodies
            .get(b)
            .map(|b| {
                b.shape
                    .iter()
                    .flatten()
                    .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
                    .collect()
            })
            .unwrap_or_default()
    };
    let (child, parent) = (placed(joint.child), placed(joint.parent));
    let extent = |r: &[f64]| r.iter().copied().fold(0.0, f64::max);
    let reach = 2.0 * (extent(&child) + extent(&parent));
    let moment: f64 = child.iter().map(|r| r * r).sum();
    if reach <= 0.0 || moment <= 0.0 || model.noise.sigma_m <= 0.0 {
        return None;
    }
    let rotation_std = model.noise.sigma_m * (2.0 / moment).sqrt();
    Some(rms / reach / rotation_std)
}

/// The rotation of body `b` in `frame` (camera from body), its shape fitted to its visible
/// placed keypoints, with that rotation's covariance per sigma^2 in the body frame
/// ([`kinetree_core::geom::rotation_cov_per_sigma2`] of the visible shape points).
/// `None` under three such keypoints or for a spread too thin to fix every rotation.
fn body_rotation(
    model: &Model,
    tracks: &Tracks,
    b: usize,
    frame: usize,
) -> Option<(Rotation3<f64>, Matrix3<f64>)> {
    let body = model.bodies.get(b)?;
    let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = body
        .points
        .iter()
        .zip(&body.shape)
        .filter_map(|(&i, s)| Some(((*s).map(Point3::from)?, tracks.get(frame, i)?)))
        .unzip();
    if src.len() < 3 {
        return None;
    }
    let cov = kinetree_core::geom::rotation_cov_per_sigma2(&src)?;
    let pose = kinetree_core::geom::kabsch(&src, &dst)?;
    Some((pose.rotation.to_rotation_matrix(), cov))
}

/// How far the child of revolute `joint` turns off a hinge's axis relative to its parent,
/// in keypoint-noise standard deviations: each frame's relative rotation, taken from the
/// mean relative rotation, is split into a turn about the axis (fixed in the parent; the
/// first principal direction of those rotations) and a swing across it; the swings, whitened by the two bodies' rotation covariance in that
/// frame, are taken about their mean, and the RMS along their largest principal direction is
/// returned. About 1 for a hinge whose only off-axis motion is noise. `None` with fewer than [`MIN_FRAMES`] frames where both bodies are posed.
fn off_axis_spread_in_std(
    model: &Model,
    tracks: &Tracks,
    joint: &kinetree_core::model::Joint,
) -> Option<f64> {
    let sigma = model.noise.sigma_m;
    if !(sigma.is_finite() && sigma > 0.0) {
        return None;
    }
    // Relative rotation (child in parent) and its left-perturbation covariance in the
    // parent's frame, per frame where both bodies are posed.
    let mut rel: Vec<(Rotation3<f64>, Matrix3<f64>)> = Vec::new();
    for t in 0..tracks.n_frames() {
        let (Some((rp, cp)), Some((rc, cc))) = (
            body_rotation(model, tracks, joint.parent, t),
            body_rotation(model, tracks, joint.child, t),
        ) else {
            continue;
        };
        let r = rp.inverse() * rc;
        let m = r.matrix();
        rel.push((r, (cp + m * cc * m.transpose()) * sigma * sigma));
    }
    if rel.len() < MIN_FRAMES {
        return None;
    }
    // The chordal mean: on a hinge, the relative rotations turned about the axis to their
    // mean angle, so that every frame's rotation from it is a pure turn about the axis.
    let sum: Matrix3<f64> = rel.iter().map(|(r, _)| r.matrix()).sum();
    let svd = sum.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    d[(2, 2)] = (u * v_t).determinant().signum();
    let mean = Rotation3::from_matrix_unchecked(u * d * v_t);
    // The axis that explains most of the turns from the mean (their rotation vectors' first
    // principal direction): the hinge that fits these data best, so that an error in the
    // fitted axis does not count as motion off it.
    let turns: Matrix3<f64> = rel
        .iter()
        .map(|(r, _)| {
            let w = (r * mean.inverse()).scaled_axis();
            w * w.transpose()
        })
        .sum();
    let eig = turns.symmetric_eigen();
    let axis = Unit::try_new(
        eig.eigenvectors.column(eig.eigenvalues.imax()).into_owned(),
        1e-9,
    )?;
    // A basis across the axis.
    let e1 = axis
        .cross(&Vector3::x())
        .try_normalize(1e-6)
        .unwrap_or_else(|| {
            axis.cross(&Vector3::y())
                .try_normalize(1e-6)
                .unwrap_or_else(Vector3::z)
        });
    let e2 = axis.cross(&e1);
    let basis = kinetree_core::nalgebra::Matrix3x2::from_columns(&[e1, e2]);
    let mut swings: Vec<(Vector2<f64>, Matrix2<f64>)> = Vec::with_capacity(rel.len());
    for (r, cov) in &rel {
        let q = UnitQuaternion::from_rotation_matrix(&(r * mean.inverse()));
        let along = axis.dot(&q.imag());
        let twist = UnitQuaternion::try_new(
            kinetree_core::nalgebra::Quaternion::from_parts(q.w, axis.into_inner() * along),
            1e-12,
        )
        .unwrap_or_else(UnitQuaternion::identity);
        let swing = (q * twist.inverse()).scaled_axis();
        swings.push((basis.transpose() * swing, basis.transpose() * cov * basis));
    }
    let n = swings.len() as f64;
    let centre: Vector2<f64> = swings.iter().map(|(s, _)| s).sum::<Vector2<f64>>() / n;
    let mut scatter = Matrix2::zeros();
    for (s, cov) in &swings {
        let l = cov.cholesky()?;
        let z = l.l().solve_lower_triangular(&(s - centre))?;
        scatter += z * z.transpose() / n;
    }
    let eig = scatter.symmetric_eigenvalues();
    Some(eig.max().max(0.0).sqrt())
}

/// A `joint_not_identifiable` warning for every joint of `model` whose fitted coordinates
/// (`positions`, `coordinates` and their standard deviations, as the whole-tree fit wrote
/// them) spread too little to tell its type from the alternatives, `limits`'
/// `min_identifiable_spread_in_std` being the bound:
/// - revolute: its angle's spread (alternative: prismatic, as a short arc is a straight
///   path within noise);
/// - prismatic: how much a hinge near both bodies would have turned its child over the
///   slide's travel, with its axis as far off as it can pass near both bodies (alternative:
///   revolute);
/// - spherical: the rotations' second principal spread (alternatives: revolute and
///   universal: a ball that turned about one axis, within noise, moved as a hinge);
/// - universal: the smaller of its two angles' spreads (revolute).
///
/// Joints without standard deviations (multi-DoF, rigid, or not followed by the fit) are
/// not judged.
///
/// When the type decision allowed each body a model error (`model_error_rad` > 0), a
/// revolute joint also gets a warning naming the spherical and universal types when its
/// child turns off the axis by at least `limits`' `min_off_axis_spread_in_std` noise
/// standard deviations in `tracks` (the bodies posed from their own keypoints). Without an
/// allowance such motion fails the rank tests, and what remains of it comes from poses that
/// noise moves beyond their linear precision (slender or centimetre-sized bodies).
pub fn identifiability_warnings(
    model: &Model,
    tracks: &Tracks,
    limits: &PositionLimits,
    model_error_rad: f64,
) -> Vec<Warning> {
    let bound = limits.min_identifiable_spread_in_std;
    let mut out = Vec::new();
    for joint in &model.joints {
        if model_error_rad > 0.0
            && joint.joint_type == JointType::Revolute
            && let Some(off) = off_axis_spread_in_std(model, tracks, joint)
            && off >= limits.min_off_axis_spread_in_std
        {
            out.push(Warning::JointNotIdentifiable {
                parent: joint.parent,
                child: joint.child,
                joint_type: joint.joint_type,
                alternatives: vec![JointType::Spherical, JointType::Universal],
                spread_in_std: off,
                bound_in_std: limits.min_off_axis_spread_in_std,
                basis: NotIdentifiableBasis::WithinModelError,
            });
        }
        let values = usable(joint);
        let (spread, alternatives) = match joint.joint_type {
            JointType::Revolute => {
                let Some(s) = spreads(&values, false) else {
                    continue;
                };
                (s[0], vec![JointType::Prismatic])
            }
            JointType::Prismatic => {
                let Some(turn) = hinge_turn_in_std(model, joint) else {
                    continue;
                };
                (turn, vec![JointType::Revolute])
            }
            JointType::Spherical => {
                let Some(s) = spreads(&values, true) else {
                    continue;
                };
                if s.len() < 3 {
                    continue;
                }
                (s[1], vec![JointType::Revolute, JointType::Universal])
            }
            JointType::Universal => {
                let Some(s) = spreads(&values, false) else {
                    continue;
                };
                (s[s.len() - 1], vec![JointType::Revolute])
            }
            JointType::MultiDof | JointType::Rigid => continue,
        };
        if spread < bound {
            out.push(Warning::JointNotIdentifiable {
                parent: joint.parent,
                child: joint.child,
                joint_type: joint.joint_type,
                alternatives,
                spread_in_std: spread,
                bound_in_std: bound,
                basis: NotIdentifiableBasis::SmallMotion,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames of `width` coordinates: coordinate `i` swings by `amplitude[i]` (in std) with
    /// std 1.
    fn swings(amplitude: &[f64], frames: usize) -> Vec<(Vec<f64>, Vec<f64>)> {
        (0..frames)
            .map(|t| {
                let phase = t as f64 * 0.1;
                let v = amplitude
                    .iter()
                    .enumerate()
                    .map(|(i, a)| a * (phase * (1.0 + i as f64)).sin())
                    .collect();
                (v, vec![1.0; amplitude.len()])
            })
            .collect()
    }

    #[test]
    fn spreads_follow_the_swing_and_its_principal_directions() {
        let s = spreads(&swings(&[10.0, 0.0, 2.0], 400), false).expect("spreads");
        // A sine of amplitude a has RMS a / sqrt(2) about its mean.
        assert!((s[0] - 10.0 / 2f64.sqrt()).abs() < 0.2, "{s:?}");
        assert!((s[1] - 2.0 / 2f64.sqrt()).abs() < 0.1, "{s:?}");
        assert!(s[2] < 1e-12, "{s:?}");
        let p = spreads(&swings(&[10.0, 10.0, 0.0], 400), true).expect("principal");
        assert!(p[1] > 5.0 && p[2] < 1e-9, "{p:?}");
        assert!(spreads(&swings(&[1.0], 2), false).is_none());
    }
}
