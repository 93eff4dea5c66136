//! Joint fitting for a single point's track: a door handle (revolute) or a drawer handle
//! (prismatic) followed by one tracked point, with no other point to cluster.

use kinetree_core::nalgebra::{Matrix3, Point3, Vector2, Vector3};
use kinetree_core::{Error, Result};
use serde::{Deserialize, Serialize};

/// The joint that explains one point's track.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum TrackJoint {
    /// The point moves on a circle: a revolute joint.
    Revolute {
        /// Unit axis (the circle's normal).
        axis: [f64; 3],
        /// Centre of the circle, on the axis.
        centre: [f64; 3],
        /// Radius, metres.
        radius_m: f64,
        /// Angle swept, radians.
        arc_rad: f64,
    },
    /// The point moves on a line: a prismatic joint.
    Prismatic {
        /// Unit axis (the line's direction).
        axis: [f64; 3],
        /// Travel along it, metres.
        travel_m: f64,
    },
}

/// A [`TrackJoint`] with the evidence behind it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackFit {
    /// The chosen joint.
    pub joint: TrackJoint,
    /// RMS distance of the samples from the fitted line, metres.
    pub line_rms_m: f64,
    /// RMS distance of the samples from the fitted circle, metres.
    pub circle_rms_m: f64,
    /// Joint position per sample: angle from the first sample (radians, unwrapped) or
    /// displacement along the axis (metres).
    pub positions: Vec<f64>,
}

/// Default `circle_gain` of [`fit_point_track`] (`kinetree fit-track --circle-gain`): the
/// circle is taken when the line leaves at least this many times its residual.
pub const CIRCLE_GAIN: f64 = 3.0;

/// Fits a line and a circle to the visible samples of one point and keeps the circle
/// (revolute) when it explains the track `circle_gain` times better ([`CIRCLE_GAIN`] by
/// default), the line (prismatic) otherwise.
///
/// - Line: the principal direction of the samples (3x3 symmetric eigenproblem).
/// - Circle: the plane of the samples (smallest principal direction as the normal), then an
///   algebraic circle fit in that plane (Kasa 1976: least squares on
///   `x^2 + y^2 + D x + E y + F = 0`), which is exact for noise-free data.
///
/// Both use only the geometry, so the noise level is not needed. A track whose arc is short
/// is nearly straight and is called prismatic, as no method could tell.
///
/// # Errors
/// [`Error::Degenerate`] with fewer than 3 samples or a track that does not move;
/// [`Error::InvalidParameter`] for a `circle_gain` that is not finite and at least 1.
pub fn fit_point_track(samples: &[Point3<f64>], circle_gain: f64) -> Result<TrackFit> {
    if !(circle_gain.is_finite() && circle_gain >= 1.0) {
        return Err(Error::InvalidParameter {
            name: "circle_gain".into(),
            message: format!("must be finite and at least 1, got {circle_gain}"),
        });
    }
    if samples.len() < 3 {
        return Err(Error::Degenerate(format!(
            "a track needs 3 samples to fit a joint, got {}",
            samples.len()
        )));
    }
    let n = samples.len() as f64;
    let mean = samples.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let cov = samples
        .iter()
        .map(|p| (p.coords - mean) * (p.coords - mean).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let eig = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let spread = eig.eigenvalues[order[0]].max(0.0).sqrt();
    if !(spread.is_finite() && spread > 1e-9) {
        return Err(Error::Degenerate(
            "the tracked point does not move; no joint can be fitted".into(),
        ));
    }
    let dir = eig.eigenvectors.column(order[0]).into_owned();
    let u = dir;
    let v = eig.eigenvectors.column(order[1]).into_owned();
    let normal = eig.eigenvectors.column(order[2]).into_owned();
    let line_rms = (samples
        .iter()
        .map(|p| {
            let d = p.coords - mean;
            (d - dir * d.dot(&dir)).norm_squared()
        })
        .sum::<f64>()
        / n)
        .sqrt();
    // Circle in the plane spanned by u, v.
    let plane: Vec<Vector2<f64>> = samples
        .iter()
        .map(|p| {
            let d = p.coords - mean;
            Vector2::new(d.dot(&u), d.dot(&v))
        })
        .collect();
    let mut ata = Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for q in &plane {
        let row = Vector3::new(q.x, q.y, 1.0);
        ata += row * row.transpose();
        atb += row * -(q.x * q.x + q.y * q.y);
    }
    let circle = ata.lu().solve(&atb).and_then(|s| {
        let c = Vector2::new(-s.x / 2.0, -s.y / 2.0);
        let r2 = c.norm_squared() - s.z;
        (r2 > 0.0 && r2.is_finite()).then(|| (c, r2.sqrt()))
    });
    let (circle_rms, centre2, radius) = match circle {
        Some((c, r)) => {
            let rms = (samples
                .iter()
                .zip(&plane)
                .map(|(p, q)| {
                    let off_plane = (p.coords - mean).dot(&normal);
                    let in_plane = (q - c).norm() - r;
                    off_plane * off_plane + in_plane * in_plane
                })
                .sum::<f64>()
                / n)
                .sqrt();
            (rms, c, r)
        }
        None => (f64::INFINITY, Vector2::zeros(), f64::INFINITY),
    };
    if circle_rms * circle_gain <= line_rms {
        let centre = mean + u * centre2.x + v * centre2.y;
        let mut angles: Vec<Option<f64>> = plane
            .iter()
            .map(|q| Some((q.y - centre2.y).atan2(q.x - centre2.x)))
            .collect();
        kinetree_core::geom::unwrap_angles(&mut angles);
        let angles: Vec<f64> = angles.into_iter().flatten().collect();
        // Measured from the first sample.
        let a0 = angles[0];
        let positions: Vec<f64> = angles.iter().map(|a| a - a0).collect();
        let (lo, hi) = positions
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &a| {
                (l.min(a), h.max(a))
            });
        // u x v = normal orientation fixes the sign of the angles.
        let axis = u.cross(&v).normalize();
        Ok(TrackFit {
            joint: TrackJoint::Revolute {
                axis: axis.into(),
                centre: centre.into(),
                radius_m: radius,
                arc_rad: hi - lo,
            },
            line_rms_m: line_rms,
            circle_rms_m: circle_rms,
            positions,
        })
    } else {
        let first = samples[0].coords;
        let positions: Vec<f64> = samples
            .iter()
            .map(|p| (p.coords - first).dot(&dir))
            .collect();
        let (lo, hi) = positions
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &a| {
                (l.min(a), h.max(a))
            });
        Ok(TrackFit {
            joint: TrackJoint::Prismatic {
                axis: dir.into(),
                travel_m: hi - lo,
            },
            line_rms_m: line_rms,
            circle_rms_m: circle_rms,
            positions,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_arc_and_line_are_recovered() {
        let axis = Vector3::new(0.2, -0.3, 1.0).normalize();
        let u = axis.cross(&Vector3::x()).normalize();
        let v = axis.cross(&u);
        let centre = Vector3::new(0.1, 0.2, 0.3);
        let arc: Vec<Point3<f64>> = (0..50)
            .map(|k| {
                let a = 1.2 * k as f64 / 49.0;
                Point3::from(centre + 0.4 * (u * a.cos() + v * a.sin()))
            })
            .collect();
        let fit = fit_point_track(&arc, CIRCLE_GAIN).expect("fit");
        let TrackJoint::Revolute {
            axis: a,
            centre: c,
            radius_m,
            arc_rad,
        } = fit.joint
        else {
            panic!("{fit:?}");
        };
        assert!(Vector3::from(a).dot(&axis).abs() > 1.0 - 1e-9);
        assert!((Vector3::from(c) - centre).norm() < 1e-9);
        assert!((radius_m - 0.4).abs() < 1e-9 && (arc_rad - 1.2).abs() < 1e-9);
        assert!((fit.positions[49].abs() - 1.2).abs() < 1e-9);
        let line: Vec<Point3<f64>> = (0..20)
            .map(|k| Point3::from(centre + u * (0.01 * k as f64)))
            .collect();
        let fit = fit_point_track(&line, CIRCLE_GAIN).expect("fit");
        assert!(
            matches!(fit.joint, TrackJoint::Prismatic { travel_m, .. } if (travel_m - 0.19).abs() < 1e-9)
        );
        assert!(fit_point_track(&line[..2], CIRCLE_GAIN).is_err());
        assert!(fit_point_track(&[Point3::origin(); 5], CIRCLE_GAIN).is_err());
        // A gain no rounding-level circle residual can meet calls the arc a line; a gain
        // under 1 or not finite is refused.
        let strict = fit_point_track(&arc, 1e30).expect("fit");
        assert!(
            matches!(strict.joint, TrackJoint::Prismatic { .. }),
            "{strict:?}"
        );
        for bad in [0.5, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                fit_point_track(&arc, bad),
                Err(Error::InvalidParameter { .. })
            ));
        }
    }
}
