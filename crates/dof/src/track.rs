//! Joint fitting for a single point's track: a door handle (revolute) or a drawer handle
//! (prismatic) followed by one tracked point, with no other point to cluster.

use kinetree_core::nalgebra::{Matrix3, Point3, Vector2, Vector3};
use kinetree_core::{Error, Result};
use serde::{Deserialize, Serialize};
use statrs::distribution::ContinuousCDF;

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
    /// RMS distance of the samples from the fitted circle, metres: never above the line's,
    /// which is a circle of infinite radius.
    pub circle_rms_m: f64,
    /// The per-coordinate noise the test used, metres: given, or estimated from the circle's
    /// residual.
    pub noise_sigma_m: f64,
    /// How improbable the line's extra residual over the circle's is if the track were
    /// straight and noisy: the F-test's p-value (or the chi-square test's, with the noise
    /// given). The circle is taken below the significance.
    pub p_value: f64,
    /// Joint position per sample: angle from the first sample (radians, unwrapped) or
    /// displacement along the axis (metres).
    pub positions: Vec<f64>,
}

/// How [`fit_point_track`] chooses between the line and the circle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackFitParams {
    /// Per-coordinate noise of the samples, metres; `None`: estimated from the circle's
    /// residual (an F-test instead of a chi-square test).
    pub noise_sigma_m: Option<f64>,
    /// The circle (revolute) is taken when the line's extra residual is less probable than
    /// this under noise alone (default [`TRACK_SIGNIFICANCE`]).
    pub significance: f64,
    /// ... and sweeps at least this angle, degrees (default [`TRACK_MIN_ARC_DEG`]): the
    /// rails of real drawers and sliding doors bend their handle's path by a few degrees,
    /// which a test on the residuals alone takes for a hinge.
    pub min_arc_deg: f64,
}

impl Default for TrackFitParams {
    fn default() -> Self {
        Self {
            noise_sigma_m: None,
            significance: TRACK_SIGNIFICANCE,
            min_arc_deg: TRACK_MIN_ARC_DEG,
        }
    }
}

/// Default [`TrackFitParams::min_arc_deg`] (`kinetree fit-track --min-arc-deg`;
/// `docs/decisions.md`).
pub const TRACK_MIN_ARC_DEG: f64 = 10.0;

/// Default [`TrackFitParams::significance`] (`kinetree fit-track --significance`;
/// `docs/decisions.md`).
pub const TRACK_SIGNIFICANCE: f64 = 1e-3;

/// Fewest samples: the circle has six parameters, and the F-test needs residual degrees of
/// freedom beyond them.
const MIN_SAMPLES: usize = 4;

/// Levenberg-Marquardt rounds of the geometric circle fit.
const CIRCLE_ROUNDS: usize = 100;

/// The circle in the plane `(u, v)` through `q` (the samples' in-plane coordinates) that
/// least-squares the distances `|q - c| - r`, from a start `(c, r)`, by Levenberg-Marquardt.
/// Returns `(c, r, sum of squared distances)`.
fn geometric_circle(q: &[Vector2<f64>], c: Vector2<f64>, r: f64) -> (Vector2<f64>, f64, f64) {
    let cost = |c: &Vector2<f64>, r: f64| q.iter().map(|p| ((p - c).norm() - r).powi(2)).sum();
    let (mut c, mut r) = (c, r);
    let mut best: f64 = cost(&c, r);
    let mut lambda = 1e-3;
    for _ in 0..CIRCLE_ROUNDS {
        let mut jtj = Matrix3::<f64>::zeros();
        let mut jtr = Vector3::<f64>::zeros();
        for p in q {
            let d = p - c;
            let dist = d.norm();
            if dist <= 0.0 {
                continue;
            }
            let row = Vector3::new(-d.x / dist, -d.y / dist, -1.0);
            jtj += row * row.transpose();
            jtr += row * (dist - r);
        }
        let mut improved = false;
        for _ in 0..10 {
            let damped = jtj + Matrix3::from_diagonal(&(jtj.diagonal() * lambda));
            let Some(step) = damped.lu().solve(&-jtr) else {
                break;
            };
            let (c2, r2) = (c + Vector2::new(step.x, step.y), r + step.z);
            let trial = cost(&c2, r2);
            if trial < best {
                (c, r, best) = (c2, r2, trial);
                lambda = (lambda / 10.0).max(1e-12);
                improved = true;
                break;
            }
            lambda *= 10.0;
        }
        if !improved || best <= 0.0 {
            break;
        }
    }
    (c, r, best)
}

/// Fits a line and a circle to the visible samples of one point and keeps the circle
/// (revolute) when the line's extra residual is too large for noise (`params`), the line
/// (prismatic) otherwise.
///
/// - Line: the principal direction of the samples (3x3 symmetric eigenproblem).
/// - Circle: in the plane of the samples (smallest principal direction as the normal), the
///   circle that least-squares the geometric distances, by Levenberg-Marquardt from the
///   better of an algebraic fit (Kasa 1976, exact for noise-free data) and a circle of huge
///   radius along the line; its residual adds the distances from the plane. A circle that
///   does not beat the line is the line (a circle of infinite radius).
/// - Choice: with `k = 2n` residuals (two per sample), the line's `k - 4` degrees of freedom
///   and the circle's `k - 6`, the F-test `F = ((RSS_line - RSS_circle) / 2) / (RSS_circle /
///   (k - 6))` against `F(2, k - 6)`; with the noise given, `(RSS_line - RSS_circle) /
///   sigma^2` against `chi^2(2)`. Tracking errors drift slowly, so consecutive residuals are
///   correlated: with `rho` their lag-one correlation (of the better model's residual
///   vectors), the statistic is divided, and the residual degrees of freedom are divided, by
///   `(1 + rho) / (1 - rho)`. The circle is taken when the p-value is below
///   `params.significance` and it sweeps at least `params.min_arc_deg`. A short arc within
///   noise of a line stays prismatic, as no test can tell.
///
/// # Errors
/// [`Error::Degenerate`] with fewer than 4 samples or a track that does not move;
/// [`Error::InvalidParameter`] for a significance outside `(0, 1)`, a noise level that is
/// not finite and positive, or a minimum arc outside `[0, 360]` degrees.
pub fn fit_point_track(samples: &[Point3<f64>], params: &TrackFitParams) -> Result<TrackFit> {
    if !(params.significance > 0.0 && params.significance < 1.0) {
        return Err(Error::InvalidParameter {
            name: "significance".into(),
            message: format!("must be in (0, 1), got {}", params.significance),
        });
    }
    if !(params.min_arc_deg.is_finite() && (0.0..=360.0).contains(&params.min_arc_deg)) {
        return Err(Error::InvalidParameter {
            name: "min_arc_deg".into(),
            message: format!("must be within [0, 360], got {}", params.min_arc_deg),
        });
    }
    if let Some(s) = params.noise_sigma_m
        && !(s.is_finite() && s > 0.0)
    {
        return Err(Error::InvalidParameter {
            name: "noise_sigma_m".into(),
            message: format!("must be finite and positive, got {s}"),
        });
    }
    if samples.len() < MIN_SAMPLES {
        return Err(Error::Degenerate(format!(
            "a track needs {MIN_SAMPLES} samples to fit a joint, got {}",
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
    let line_rss: f64 = samples
        .iter()
        .map(|p| {
            let d = p.coords - mean;
            (d - dir * d.dot(&dir)).norm_squared()
        })
        .sum();
    // Circle in the plane spanned by u, v.
    let plane: Vec<Vector2<f64>> = samples
        .iter()
        .map(|p| {
            let d = p.coords - mean;
            Vector2::new(d.dot(&u), d.dot(&v))
        })
        .collect();
    let off_plane: f64 = samples
        .iter()
        .map(|p| (p.coords - mean).dot(&normal).powi(2))
        .sum();
    let mut ata = Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for q in &plane {
        let row = Vector3::new(q.x, q.y, 1.0);
        ata += row * row.transpose();
        atb += row * -(q.x * q.x + q.y * q.y);
    }
    let algebraic = ata.lu().solve(&atb).and_then(|s| {
        let c = Vector2::new(-s.x / 2.0, -s.y / 2.0);
        let r2 = c.norm_squared() - s.z;
        (r2 > 0.0 && r2.is_finite()).then(|| (c, r2.sqrt()))
    });
    // A circle that nearly is the line: centre far off it, on either side.
    let far = 1e3 * spread;
    let starts = algebraic.into_iter().chain([
        (Vector2::new(0.0, far), far),
        (Vector2::new(0.0, -far), far),
    ]);
    let circle = starts
        .map(|(c, r)| geometric_circle(&plane, c, r))
        .filter(|(c, r, rss)| c.iter().all(|x| x.is_finite()) && r.is_finite() && rss.is_finite())
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map(|(c, r, rss)| (c, r, rss + off_plane))
        .filter(|(_, _, rss)| *rss < line_rss);
    let circle_rss = circle.map_or(line_rss, |(_, _, rss)| rss);
    // Residual vectors of the best model in time order: how correlated consecutive ones
    // are (tracking errors and model error drift slowly), lag one.
    let residual: Vec<Vector2<f64>> = match circle {
        Some((c, r, _)) => samples
            .iter()
            .zip(&plane)
            .map(|(p, q)| {
                let d = q - c;
                Vector2::new((p.coords - mean).dot(&normal), d.norm() - r)
            })
            .collect(),
        None => samples
            .iter()
            .map(|p| {
                let d = p.coords - mean;
                Vector2::new(d.dot(&normal), d.dot(&v))
            })
            .collect(),
    };
    let lag: f64 = residual.windows(2).map(|w| w[0].dot(&w[1])).sum();
    let power: f64 = residual.iter().map(|r| r.norm_squared()).sum();
    let rho = if power > 0.0 {
        (lag / power).clamp(0.0, 0.99)
    } else {
        0.0
    };
    let inflation = (1.0 + rho) / (1.0 - rho);
    let k = 2.0 * n;
    let gain = (line_rss - circle_rss).max(0.0);
    let (noise_sigma_m, p_value) = match params.noise_sigma_m {
        Some(sigma) => {
            let chi2 = statrs::distribution::ChiSquared::new(2.0)
                .map_err(|e| Error::Numerical(format!("chi-square distribution: {e}")))?;
            (sigma, 1.0 - chi2.cdf(gain / (sigma * sigma) / inflation))
        }
        None => {
            let sigma = (circle_rss / (k - 6.0)).sqrt();
            let p = if circle_rss <= 0.0 {
                if gain > 0.0 { 0.0 } else { 1.0 }
            } else {
                let f = (gain / 2.0) / (circle_rss / (k - 6.0)) / inflation;
                let dof = (k / inflation - 6.0).max(1.0);
                let dist = statrs::distribution::FisherSnedecor::new(2.0, dof)
                    .map_err(|e| Error::Numerical(format!("F distribution: {e}")))?;
                1.0 - dist.cdf(f)
            };
            (sigma, p)
        }
    };
    let (line_rms, circle_rms) = ((line_rss / n).sqrt(), (circle_rss / n).sqrt());
    // Each sample's angle about the circle's centre from the first sample's, unwrapped, and
    // the arc they sweep.
    let turns = circle.map(|(centre2, _, _)| {
        let mut angles: Vec<Option<f64>> = plane
            .iter()
            .map(|q| Some((q.y - centre2.y).atan2(q.x - centre2.x)))
            .collect();
        kinetree_core::geom::unwrap_angles(&mut angles);
        let angles: Vec<f64> = angles.into_iter().flatten().collect();
        let a0 = angles[0];
        let positions: Vec<f64> = angles.iter().map(|a| a - a0).collect();
        let (lo, hi) = positions
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &a| {
                (l.min(a), h.max(a))
            });
        (positions, hi - lo)
    });
    match (circle, turns) {
        (Some((centre2, radius, _)), Some((positions, arc)))
            if p_value < params.significance && arc >= params.min_arc_deg.to_radians() =>
        {
            let centre = mean + u * centre2.x + v * centre2.y;
            // u x v = normal orientation fixes the sign of the angles.
            let axis = u.cross(&v).normalize();
            Ok(TrackFit {
                joint: TrackJoint::Revolute {
                    axis: axis.into(),
                    centre: centre.into(),
                    radius_m: radius,
                    arc_rad: arc,
                },
                line_rms_m: line_rms,
                circle_rms_m: circle_rms,
                noise_sigma_m,
                p_value,
                positions,
            })
        }
        _ => {
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
                noise_sigma_m,
                p_value,
                positions,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A circle of radius 0.4 about `axis` through `centre`, swept through `arc` radians in
    /// `n` samples.
    fn arc(n: usize, arc: f64) -> (Vector3<f64>, Vector3<f64>, Vec<Point3<f64>>) {
        let axis = Vector3::new(0.2, -0.3, 1.0).normalize();
        let u = axis.cross(&Vector3::x()).normalize();
        let v = axis.cross(&u);
        let centre = Vector3::new(0.1, 0.2, 0.3);
        let points = (0..n)
            .map(|k| {
                let a = arc * k as f64 / (n - 1) as f64;
                Point3::from(centre + 0.4 * (u * a.cos() + v * a.sin()))
            })
            .collect();
        (axis, centre, points)
    }

    fn noisy(points: &[Point3<f64>], sigma: f64, seed: u64) -> Vec<Point3<f64>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, sigma).expect("normal");
        points
            .iter()
            .map(|p| p + Vector3::from_fn(|_, _| normal.sample(&mut rng)))
            .collect()
    }

    #[test]
    fn exact_arc_and_line_are_recovered() {
        let (axis, centre, points) = arc(50, 1.2);
        let fit = fit_point_track(&points, &TrackFitParams::default()).expect("fit");
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
        let u = axis.cross(&Vector3::x()).normalize();
        let line: Vec<Point3<f64>> = (0..20)
            .map(|k| Point3::from(centre + u * (0.01 * k as f64)))
            .collect();
        let fit = fit_point_track(&line, &TrackFitParams::default()).expect("fit");
        assert!(
            matches!(fit.joint, TrackJoint::Prismatic { travel_m, .. } if (travel_m - 0.19).abs() < 1e-9)
        );
        assert!(fit_point_track(&line[..3], &TrackFitParams::default()).is_err());
        assert!(fit_point_track(&[Point3::origin(); 5], &TrackFitParams::default()).is_err());
    }

    /// With 1 mm of noise: an arc of 60 deg is a hinge whether the noise is given or
    /// estimated, and its radius comes out within a few millimetres; a straight slide stays
    /// a slide with its circle no worse than its line; an arc of 5 deg, though its curve is
    /// many noise levels deep, is below the least arc and stays a slide.
    #[test]
    fn noisy_arcs_and_lines_are_told_apart_by_the_noise_and_the_arc() {
        let (_, _, points) = arc(200, 60f64.to_radians());
        for noise_sigma_m in [None, Some(0.001)] {
            let params = TrackFitParams {
                noise_sigma_m,
                ..TrackFitParams::default()
            };
            let fit = fit_point_track(&noisy(&points, 0.001, 1), &params).expect("fit");
            let TrackJoint::Revolute { radius_m, .. } = fit.joint else {
                panic!("{noise_sigma_m:?}: {fit:?}");
            };
            assert!((radius_m - 0.4).abs() < 0.005, "{radius_m}");
            assert!(fit.p_value < 1e-9);
            assert!(
                (fit.noise_sigma_m - 0.001).abs() < 2e-4,
                "{}",
                fit.noise_sigma_m
            );
        }
        let straight: Vec<Point3<f64>> = (0..200)
            .map(|k| Point3::new(0.002 * k as f64, 0.1, 0.0))
            .collect();
        for seed in 0..5 {
            let fit = fit_point_track(&noisy(&straight, 0.001, seed), &TrackFitParams::default())
                .expect("fit");
            assert!(matches!(fit.joint, TrackJoint::Prismatic { .. }), "{fit:?}");
            assert!(fit.circle_rms_m <= fit.line_rms_m);
        }
        let (_, _, short) = arc(200, 5f64.to_radians());
        let fit =
            fit_point_track(&noisy(&short, 1e-5, 3), &TrackFitParams::default()).expect("fit");
        assert!(
            fit.p_value < 1e-9,
            "the curve is significant: {}",
            fit.p_value
        );
        assert!(matches!(fit.joint, TrackJoint::Prismatic { .. }), "{fit:?}");
        let lenient = TrackFitParams {
            min_arc_deg: 2.0,
            ..TrackFitParams::default()
        };
        let fit = fit_point_track(&noisy(&short, 1e-5, 3), &lenient).expect("fit");
        assert!(matches!(fit.joint, TrackJoint::Revolute { .. }), "{fit:?}");
    }

    #[test]
    fn bad_parameters_are_refused_by_name() {
        let (_, _, points) = arc(20, 1.0);
        let bad = [
            (
                "significance",
                TrackFitParams {
                    significance: 0.0,
                    ..TrackFitParams::default()
                },
            ),
            (
                "significance",
                TrackFitParams {
                    significance: f64::NAN,
                    ..TrackFitParams::default()
                },
            ),
            (
                "noise_sigma_m",
                TrackFitParams {
                    noise_sigma_m: Some(0.0),
                    ..TrackFitParams::default()
                },
            ),
            (
                "min_arc_deg",
                TrackFitParams {
                    min_arc_deg: -1.0,
                    ..TrackFitParams::default()
                },
            ),
        ];
        for (name, params) in bad {
            match fit_point_track(&points, &params) {
                Err(Error::InvalidParameter { name: n, .. }) => assert_eq!(n, name),
                other => panic!("{name}: {other:?}"),
            }
        }
    }
}
