//! Joint positions smoothed over time.
//!
//! The whole-tree fit estimates each frame's configuration from that frame's keypoints alone
//! and states each position's standard deviation. For a small or sparsely seen body that is
//! a few hundredths of a radian per frame at 1 mm of noise, and no per-frame estimate does
//! better. Joints move smoothly, though, so neighbouring frames tell about each other.
//!
//! [`smooth_positions`] is a fixed-interval Kalman smoother (Rauch, Tung and Striebel 1965)
//! of one joint's positions under a constant-velocity model: the position's acceleration is
//! white noise of intensity `q` per frame (continuous white-noise acceleration, sampled once
//! a frame), and each frame's position is a measurement with its stated variance. Frames with
//! no position are bridged. `q` is chosen by maximum likelihood (the Gaussian likelihood of
//! the filter's innovations) on a grid of ratios to the median measurement variance, so the
//! smoothing follows the data: a joint that moves fast gets a large `q` and is smoothed
//! little. The smoothed positions come with their own standard deviations.
//!
//! This is a prior on the motion, not a per-frame estimate: the raw positions stay the
//! model's `positions`, and the smoothed ones are given beside them.
//!
//! Written here rather than with a Kalman crate (adskalman 0.18 was considered): the state
//! has two entries, the measurement is one number with its own variance in every frame, and
//! the choice of `q` needs the innovations' likelihood, which that crate does not expose.

use kinetree_core::model::PositionLimits;
use kinetree_core::nalgebra::{Matrix2, Vector2};
use kinetree_core::{Error, Result};

/// The grid of `q`, as `log10` of `q` over the median measurement variance: from, to, step.
/// At the low end the smoothed path is nearly a straight line through the whole sequence;
/// at the high end it follows every measurement.
const LOG_Q_GRID: (f64, f64, f64) = (-12.0, 2.0, 0.25);

/// One joint's positions smoothed over the frames ([`smooth_positions`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothedPositions {
    /// Smoothed position at every frame, in the input's units; null before the first and
    /// after the last measured frame, and where the standard deviation exceeds the limit.
    pub positions: Vec<Option<f64>>,
    /// Standard deviation of each smoothed position (null where the position is).
    pub std: Vec<Option<f64>>,
    /// Square root of the chosen `q`: the standard deviation of the acceleration per frame,
    /// in the input's units per frame squared.
    pub acceleration_std: f64,
}

/// One value per frame, null where unknown.
pub type PositionColumn = Vec<Option<f64>>;

/// A joint's positions from the whole-tree fit smoothed ([`smooth_positions`]): frames whose
/// standard deviation is not a positive number are left out (the fit gives none), and the
/// limit on the smoothed deviation is the fit's own (`limits`: `max_std_rad` for a revolute
/// joint, `max_std_m` for a prismatic one). Returns the smoothed positions and their standard
/// deviations, all null for a joint with fewer than `limits.min_smoothed_frames` usable
/// frames.
///
/// # Errors
/// As [`smooth_positions`].
pub fn smooth_fitted_positions(
    positions: &[Option<f64>],
    std: &[Option<f64>],
    revolute: bool,
    limits: &PositionLimits,
) -> Result<(PositionColumn, PositionColumn)> {
    let weights: Vec<Option<f64>> = std
        .iter()
        .map(|s| s.filter(|s| s.is_finite() && *s > 0.0))
        .collect();
    let max_std = if revolute {
        limits.max_std_rad
    } else {
        limits.max_std_m
    };
    Ok(
        match smooth_positions(positions, &weights, max_std, limits.min_smoothed_frames)? {
            Some(s) => (s.positions, s.std),
            None => (vec![None; positions.len()], vec![None; positions.len()]),
        },
    )
}

/// The filter's state and covariance at one frame, before and after its measurement.
#[derive(Debug, Clone, Copy)]
struct Step {
    predicted: (Vector2<f64>, Matrix2<f64>),
    filtered: (Vector2<f64>, Matrix2<f64>),
}

/// Smooths one joint's `positions` over the frames, weighting each by its standard deviation
/// `std` (see the module documentation). A frame counts as measured when it has both a
/// position and a standard deviation; smoothed values are given from the first to the last
/// measured frame, where their standard deviation is at most `max_std`.
///
/// Returns `Ok(None)` with fewer than `min_frames` measured frames.
///
/// # Errors
/// [`Error::Shape`] when `positions` and `std` differ in length; [`Error::InvalidParameter`]
/// for a position that is not finite, a standard deviation that is not finite and positive,
/// a `max_std` that is not positive, or `min_frames` under 3 (the state has two entries).
///
/// Complexity: O(G T) for T frames and the G = 57 values of `q` tried.
pub fn smooth_positions(
    positions: &[Option<f64>],
    std: &[Option<f64>],
    max_std: f64,
    min_frames: usize,
) -> Result<Option<SmoothedPositions>> {
    if positions.len() != std.len() {
        return Err(Error::Shape {
            expected: format!("{} standard deviations, one per position", positions.len()),
            found: format!("{}", std.len()),
        });
    }
    if max_std.is_nan() || max_std <= 0.0 {
        return Err(Error::InvalidParameter {
            name: "max_std".into(),
            message: format!("must be positive, got {max_std}"),
        });
    }
    if min_frames < 3 {
        return Err(Error::InvalidParameter {
            name: "min_frames".into(),
            message: format!("must be at least 3, got {min_frames}"),
        });
    }
    let mut measured: Vec<Option<(f64, f64)>> = Vec::with_capacity(positions.len());
    for (t, (p, s)) in positions.iter().zip(std).enumerate() {
        if let Some(p) = p
            && !p.is_finite()
        {
            return Err(Error::InvalidParameter {
                name: "positions".into(),
                message: format!("frame {t}: not finite ({p})"),
            });
        }
        if let Some(s) = s
            && !(s.is_finite() && *s > 0.0)
        {
            return Err(Error::InvalidParameter {
                name: "std".into(),
                message: format!("frame {t}: must be finite and positive, got {s}"),
            });
        }
        measured.push(p.zip(*s).map(|(p, s)| (p, s * s)));
    }
    let frames: Vec<usize> = (0..measured.len())
        .filter(|&t| measured[t].is_some())
        .collect();
    let (Some(&first), Some(&last)) = (frames.first(), frames.last()) else {
        return Ok(None);
    };
    if frames.len() < min_frames {
        return Ok(None);
    }
    let span = &measured[first..=last];
    let mut variances: Vec<f64> = span.iter().flatten().map(|&(_, v)| v).collect();
    variances.sort_by(f64::total_cmp);
    let median_var = variances[variances.len() / 2];
    // A prior wide against the data, so the first measurements decide the state.
    let values: Vec<f64> = span.iter().flatten().map(|&(p, _)| p).collect();
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let prior_var = 100.0 * ((hi - lo).powi(2) + variances[variances.len() - 1]);

    let (from, to, step) = LOG_Q_GRID;
    let n_grid = ((to - from) / step).round() as usize + 1;
    let mut best: Option<(f64, f64)> = None;
    for g in 0..n_grid {
        let q = median_var * 10f64.powf(from + step * g as f64);
        let (_, log_likelihood) = filter(span, q, prior_var);
        // The first value of the grid wins a tie: deterministic.
        if best.is_none_or(|(l, _)| log_likelihood > l) {
            best = Some((log_likelihood, q));
        }
    }
    let Some((_, q)) = best else {
        return Ok(None);
    };
    let (steps, _) = filter(span, q, prior_var);
    let smoothed = smooth(&steps, q);
    let mut out_positions = vec![None; positions.len()];
    let mut out_std = vec![None; positions.len()];
    for (k, (x, p)) in smoothed.iter().enumerate() {
        let s = p[(0, 0)].max(0.0).sqrt();
        if s <= max_std {
            out_positions[first + k] = Some(x[0]);
            out_std[first + k] = Some(s);
        }
    }
    Ok(Some(SmoothedPositions {
        positions: out_positions,
        std: out_std,
        acceleration_std: q.sqrt(),
    }))
}

/// The frame-to-frame transition of (position, velocity) and its process noise for
/// acceleration intensity `q` (continuous white noise over one frame).
fn transition(q: f64) -> (Matrix2<f64>, Matrix2<f64>) {
    let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
    let noise = Matrix2::new(q / 3.0, q / 2.0, q / 2.0, q);
    (f, noise)
}

/// The Kalman filter over `span` (its first and last frames measured): every frame's
/// predicted and filtered state, and the log-likelihood of the innovations after the first
/// two measurements (those two only place the state against the wide prior).
fn filter(span: &[Option<(f64, f64)>], q: f64, prior_var: f64) -> (Vec<Step>, f64) {
    let (f, noise) = transition(q);
    let mut steps = Vec::with_capacity(span.len());
    let mut x = Vector2::new(span[0].map_or(0.0, |(p, _)| p), 0.0);
    let mut p = Matrix2::identity() * prior_var;
    let mut seen = 0usize;
    let mut log_likelihood = 0.0;
    for (t, z) in span.iter().enumerate() {
        if t > 0 {
            x = f * x;
            p = f * p * f.transpose() + noise;
        }
        let predicted = (x, p);
        if let Some((value, variance)) = *z {
            let s = p[(0, 0)] + variance;
            let innovation = value - x[0];
            if seen >= 2 {
                log_likelihood -= 0.5 * (innovation * innovation / s + s.ln());
            }
            seen += 1;
            let gain = p.column(0) / s;
            x += gain * innovation;
            // Joseph form: stays symmetric and positive definite.
            let a = Matrix2::identity() - Matrix2::new(gain[0], 0.0, gain[1], 0.0);
            p = a * p * a.transpose() + gain * gain.transpose() * variance;
        }
        steps.push(Step {
            predicted,
            filtered: (x, p),
        });
    }
    (steps, log_likelihood)
}

/// The Rauch-Tung-Striebel backward pass over the filter's `steps`: each frame's state and
/// covariance given every measurement.
fn smooth(steps: &[Step], q: f64) -> Vec<(Vector2<f64>, Matrix2<f64>)> {
    let (f, _) = transition(q);
    let Some(last) = steps.last() else {
        return Vec::new();
    };
    let mut out = vec![last.filtered; steps.len()];
    for t in (0..steps.len() - 1).rev() {
        let (xf, pf) = steps[t].filtered;
        let (xp, pp) = steps[t + 1].predicted;
        let Some(pp_inv) = pp.try_inverse() else {
            out[t] = (xf, pf);
            continue;
        };
        let c = pf * f.transpose() * pp_inv;
        let (xs, ps) = out[t + 1];
        let x = xf + c * (xs - xp);
        let p = pf + c * (ps - pp) * c.transpose();
        out[t] = (x, (p + p.transpose()) * 0.5);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A sine like the random mechanisms' joints: 0.3 Hz at 30 frames/s, 1 rad.
    fn sine(n: usize) -> Vec<f64> {
        (0..n)
            .map(|t| (std::f64::consts::TAU * 0.3 * t as f64 / 30.0).sin())
            .collect()
    }

    /// `truth` measured with noise of `sigma` to 2 `sigma` (varying over the frames), every
    /// fifth frame missing (not the first or last of 100 or 200): the positions and their
    /// standard deviations.
    fn measured(truth: &[f64], sigma: f64, seed: u64) -> (Vec<Option<f64>>, Vec<Option<f64>>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let unit = Normal::new(0.0, 1.0).expect("normal");
        let std: Vec<Option<f64>> = (0..truth.len())
            .map(|t| (t % 5 != 2).then(|| sigma * (1.0 + (t % 7) as f64 / 6.0)))
            .collect();
        let positions = truth
            .iter()
            .zip(&std)
            .map(|(x, s)| s.map(|s| x + s * unit.sample(&mut rng)))
            .collect();
        (positions, std)
    }

    fn rms(estimate: &[Option<f64>], truth: &[f64]) -> f64 {
        let e: Vec<f64> = estimate
            .iter()
            .zip(truth)
            .filter_map(|(e, t)| e.map(|e| e - t))
            .collect();
        (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt()
    }

    #[test]
    fn a_noisy_sine_comes_out_closer_to_the_truth_with_honest_deviations() {
        let truth = sine(200);
        let mut z2 = Vec::new();
        for seed in 0..20 {
            let (positions, std) = measured(&truth, 0.02, seed);
            let s = smooth_positions(&positions, &std, 0.5, 3)
                .expect("valid")
                .expect("enough frames");
            let raw = rms(&positions, &truth);
            let smoothed = rms(&s.positions, &truth);
            assert!(
                smoothed < 0.5 * raw,
                "seed {seed}: smoothed {smoothed} raw {raw}"
            );
            // Every frame between the first and last measured has a value, the missing
            // ones included.
            for ((e, sd), t) in s.positions.iter().zip(&s.std).zip(&truth) {
                let (Some(e), Some(sd)) = (e, sd) else {
                    panic!("seed {seed}: a frame without a value")
                };
                z2.push(((e - t) / sd).powi(2));
            }
        }
        let z = (z2.iter().sum::<f64>() / z2.len() as f64).sqrt();
        assert!((0.7..1.3).contains(&z), "errors in stated deviations {z}");
    }

    #[test]
    fn a_steady_ramp_is_smoothed_to_a_line_and_a_jump_is_followed() {
        let n = 100;
        let ramp: Vec<f64> = (0..n).map(|t| 0.01 * t as f64).collect();
        let (positions, std) = measured(&ramp, 0.01, 3);
        let s = smooth_positions(&positions, &std, 0.5, 3)
            .expect("valid")
            .expect("enough frames");
        let (raw, smoothed) = (rms(&positions, &ramp), rms(&s.positions, &ramp));
        assert!(smoothed < 0.3 * raw, "smoothed {smoothed} raw {raw}");
        // A step of 1 against noise of 0.001: the smoother must not blur it away.
        let step: Vec<f64> = (0..n).map(|t| if t < 50 { 0.0 } else { 1.0 }).collect();
        let positions: Vec<Option<f64>> = step.iter().map(|&x| Some(x)).collect();
        let s = smooth_positions(&positions, &vec![Some(0.001); n], 0.5, 3)
            .expect("valid")
            .expect("enough frames");
        let off = s
            .positions
            .iter()
            .zip(&step)
            .filter(|(e, t)| e.is_none_or(|e| (e - *t).abs() > 0.1))
            .count();
        assert!(off <= 2, "{off} frames off the step by over 0.1");
    }

    #[test]
    fn only_frames_between_the_first_and_last_measured_are_given() {
        let positions = [None, Some(0.0), Some(0.1), None, Some(0.3), None];
        let std = [Some(0.01), Some(0.01), Some(0.01), None, Some(0.01), None];
        let s = smooth_positions(&positions, &std, 0.5, 3)
            .expect("valid")
            .expect("three frames");
        assert_eq!(
            s.positions.iter().map(Option::is_some).collect::<Vec<_>>(),
            [false, true, true, true, true, false]
        );
        // The bridged frame lies between its neighbours.
        assert!(
            s.positions[3].is_some_and(|x| x > 0.1 && x < 0.3),
            "{:?}",
            s.positions
        );
        // A tight limit on the deviation leaves frames out.
        let tight = smooth_positions(&positions, &std, 1e-6, 3)
            .expect("valid")
            .expect("three frames");
        assert!(tight.positions.iter().all(Option::is_none));
    }

    #[test]
    fn too_few_frames_give_nothing_and_bad_input_is_refused() {
        // A position without a deviation does not count.
        let two = smooth_positions(
            &[Some(0.0), Some(1.0), Some(2.0)],
            &[Some(0.1), Some(0.1), None],
            0.5,
            3,
        );
        assert_eq!(two.expect("valid"), None);
        assert!(matches!(
            smooth_positions(&[Some(0.0); 3], &[Some(0.1); 3], 0.5, 2),
            Err(Error::InvalidParameter { .. })
        ));
        assert!(matches!(
            smooth_positions(&[Some(0.0)], &[], 0.5, 3),
            Err(Error::Shape { .. })
        ));
        assert!(matches!(
            smooth_positions(&[Some(f64::NAN); 3], &[Some(0.1); 3], 0.5, 3),
            Err(Error::InvalidParameter { name, .. }) if name == "positions"
        ));
        assert!(matches!(
            smooth_positions(&[Some(0.0); 3], &[Some(0.0); 3], 0.5, 3),
            Err(Error::InvalidParameter { name, .. }) if name == "std"
        ));
        assert!(matches!(
            smooth_positions(&[Some(0.0); 3], &[Some(f64::INFINITY); 3], 0.5, 3),
            Err(Error::InvalidParameter { name, .. }) if name == "std"
        ));
        assert!(matches!(
            smooth_positions(&[Some(0.0); 3], &[Some(0.1); 3], f64::NAN, 3),
            Err(Error::InvalidParameter { name, .. }) if name == "max_std"
        ));
    }

    #[test]
    fn fitted_positions_skip_unusable_deviations_and_take_the_limit_of_their_type() {
        let n = 50;
        let truth = sine(n);
        let (positions, mut std) = measured(&truth, 0.2, 11);
        let limits = PositionLimits::default();
        // A zero and a NaN deviation: left out, not an error.
        std[0] = Some(0.0);
        std[1] = Some(f64::NAN);
        let (revolute, revolute_std) =
            smooth_fitted_positions(&positions, &std, true, &limits).expect("valid");
        assert!(revolute[0].is_none() && revolute[1].is_none());
        assert!(revolute[10].is_some() && revolute_std[10].is_some_and(|s| s > 0.0));
        // Deviations of 0.2-0.4 pass the 0.5 rad limit smoothed, not the 0.1 m one.
        let (prismatic, _) =
            smooth_fitted_positions(&positions, &std, false, &limits).expect("valid");
        let kept = |v: &[Option<f64>]| v.iter().filter(|x| x.is_some()).count();
        assert!(kept(&prismatic) < kept(&revolute), "{prismatic:?}");
        // Too few usable frames: all null, of the input's length.
        let (none, none_std) = smooth_fitted_positions(
            &positions[..3],
            &[Some(0.1), None, Some(-1.0)],
            true,
            &limits,
        )
        .expect("valid");
        assert_eq!((none.len(), none_std.len()), (3, 3));
        assert!(none.iter().chain(&none_std).all(Option::is_none));
    }

    #[test]
    fn the_smoothing_does_not_depend_on_the_units() {
        let (positions, std) = measured(&sine(200), 0.02, 7);
        let a = smooth_positions(&positions, &std, 0.5, 3)
            .expect("valid")
            .expect("frames");
        let scale = 1000.0;
        let scaled = |v: &[Option<f64>]| v.iter().map(|x| x.map(|x| x * scale)).collect::<Vec<_>>();
        let b = smooth_positions(&scaled(&positions), &scaled(&std), 0.5 * scale, 3)
            .expect("valid")
            .expect("frames");
        for (x, y) in a.positions.iter().zip(&b.positions) {
            let (Some(x), Some(y)) = (x, y) else {
                panic!("missing value")
            };
            assert!((x * scale - y).abs() < 1e-6 * scale, "{x} {y}");
        }
    }
}
