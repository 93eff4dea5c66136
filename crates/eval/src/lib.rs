//! Metrics against ground truth: clustering agreement, axis and pivot errors, joint RMS.

pub mod conformance;
mod functional;
mod truth;

pub use functional::{FunctionalEval, functional_errors, sara_axis, score_centre};
pub use truth::{
    Evaluation, JointEval, JointMiss, ambiguous_points, body_map, check_comparable, evaluate,
    identifiable_ari,
};

use nalgebra::{Point3, Vector3};

/// Adjusted Rand index between a predicted labelling (negative = discarded; each discarded
/// point counts as its own cluster) and the truth. 1 for identical partitions, about 0 for
/// chance agreement.
///
/// Reference: Hubert and Arabie (1985), "Comparing partitions".
pub fn adjusted_rand_index(predicted: &[i64], truth: &[usize]) -> f64 {
    assert_eq!(
        predicted.len(),
        truth.len(),
        "labellings of different lengths"
    );
    let n = predicted.len();
    let mut next = predicted.iter().copied().max().unwrap_or(0).max(0) + 1;
    let pred: Vec<usize> = predicted
        .iter()
        .map(|&p| {
            if p >= 0 {
                p as usize
            } else {
                next += 1;
                (next - 1) as usize
            }
        })
        .collect();
    let kp = pred.iter().max().map_or(0, |m| m + 1);
    let kt = truth.iter().max().map_or(0, |m| m + 1);
    let mut table = vec![0u64; kp * kt];
    for (p, t) in pred.iter().zip(truth) {
        table[p * kt + t] += 1;
    }
    let c2 = |x: u64| (x * x.saturating_sub(1) / 2) as f64;
    let sum_ij: f64 = table.iter().map(|&x| c2(x)).sum();
    let a: f64 = (0..kp)
        .map(|p| c2(table[p * kt..(p + 1) * kt].iter().sum()))
        .sum();
    let b: f64 = (0..kt)
        .map(|t| c2((0..kp).map(|p| table[p * kt + t]).sum()))
        .sum();
    let total = c2(n as u64);
    if total == 0.0 {
        return 1.0;
    }
    let expected = a * b / total;
    let max = 0.5 * (a + b);
    if (max - expected).abs() < f64::EPSILON {
        return 1.0;
    }
    (sum_ij - expected) / (max - expected)
}

/// Angle in degrees between two axes, ignoring their signs (0 to 90).
pub fn axis_error_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let c = (a.dot(b).abs() / (a.norm() * b.norm())).min(1.0);
    c.acos().to_degrees()
}

/// Distance from `point` to the line through `line_point` along `line_dir`.
pub fn point_line_distance(
    point: &Point3<f64>,
    line_point: &Point3<f64>,
    line_dir: &Vector3<f64>,
) -> f64 {
    let d = line_dir.normalize();
    let v = point - line_point;
    (v - d * v.dot(&d)).norm()
}

/// How an estimated joint trajectory lines up with the truth: `truth ~ sign * estimate +
/// offset`, with the sign (+1 or -1) and offset that minimise the RMS difference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// +1 or -1.
    pub sign: f64,
    /// Constant offset, in the truth's units.
    pub offset: f64,
    /// RMS difference after the alignment.
    pub rms: f64,
}

/// The best [`Alignment`] over the frames where the estimate is known (+1 wins a tie). `None`
/// when no frame is known.
pub fn alignment(estimate: &[Option<f64>], truth: &[f64]) -> Option<Alignment> {
    let pairs: Vec<(f64, f64)> = estimate
        .iter()
        .zip(truth)
        .filter_map(|(e, t)| e.map(|e| (e, *t)))
        .collect();
    if pairs.is_empty() {
        return None;
    }
    let n = pairs.len() as f64;
    [1.0, -1.0]
        .iter()
        .map(|&sign| {
            let offset = pairs.iter().map(|(e, t)| t - sign * e).sum::<f64>() / n;
            let rms = (pairs
                .iter()
                .map(|(e, t)| (t - sign * e - offset).powi(2))
                .sum::<f64>()
                / n)
                .sqrt();
            Alignment { sign, offset, rms }
        })
        .min_by(|a, b| a.rms.total_cmp(&b.rms))
}

/// RMS difference between an estimated joint trajectory and the truth after the best sign
/// (+1 or -1) and constant offset, over frames where the estimate is known. `None` when no
/// frame is known.
pub fn aligned_rms(estimate: &[Option<f64>], truth: &[f64]) -> Option<f64> {
    alignment(estimate, truth).map(|a| a.rms)
}

/// How well an estimated joint trajectory's stated precision matches its errors: the RMS of
/// the reported standard deviations (the precision the data allowed, by the model's own
/// account) and the RMS of the errors in those units (about 1 when the estimate is as good
/// as its precision says; above 1 when the model's parameters are off), over the frames
/// with both a position and a standard deviation, after the [`alignment`] of all known
/// frames. `None` when no frame has both.
pub fn precision_check(
    estimate: &[Option<f64>],
    std: &[Option<f64>],
    truth: &[f64],
) -> Option<(f64, f64)> {
    let a = alignment(estimate, truth)?;
    let (mut n, mut s2, mut z2) = (0.0, 0.0, 0.0);
    for ((e, s), t) in estimate.iter().zip(std).zip(truth) {
        if let (Some(e), Some(s)) = (e, s)
            && *s > 0.0
        {
            n += 1.0;
            s2 += s * s;
            z2 += ((t - a.sign * e - a.offset) / s).powi(2);
        }
    }
    (n > 0.0).then(|| ((s2 / n).sqrt(), (z2 / n).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ari_is_one_for_relabelled_partition_and_low_for_a_merge() {
        let truth = [0, 0, 0, 1, 1, 1, 2, 2, 2];
        assert!((adjusted_rand_index(&[5, 5, 5, 3, 3, 3, 0, 0, 0], &truth) - 1.0).abs() < 1e-12);
        let merged = adjusted_rand_index(&[0, 0, 0, 0, 0, 0, 2, 2, 2], &truth);
        assert!(merged < 0.7, "{merged}");
        let discarded = adjusted_rand_index(&[0, 0, -1, 1, 1, 1, 2, 2, 2], &truth);
        assert!(discarded < 1.0);
    }

    #[test]
    fn aligned_rms_removes_sign_and_offset() {
        let truth: Vec<f64> = (0..10).map(|k| k as f64 * 0.1).collect();
        let est: Vec<Option<f64>> = truth.iter().map(|t| Some(-t + 3.0)).collect();
        assert!(aligned_rms(&est, &truth).is_some_and(|r| r < 1e-12));
        let bad: Vec<Option<f64>> = truth.iter().map(|t| Some(t * t)).collect();
        assert!(aligned_rms(&bad, &truth).is_some_and(|r| r > 0.01));
    }

    #[test]
    fn precision_check_measures_errors_in_their_stated_units() {
        let truth: Vec<f64> = (0..40).map(|k| k as f64 * 0.05).collect();
        // Errors of +-0.02 against a stated 0.01 (two deviations each), sign flipped.
        let est: Vec<Option<f64>> = truth
            .iter()
            .enumerate()
            .map(|(k, t)| Some(-(t + if k % 2 == 0 { 0.02 } else { -0.02 })))
            .collect();
        let std = vec![Some(0.01); truth.len()];
        let (s, z) = precision_check(&est, &std, &truth).expect("known");
        assert!(
            (s - 0.01).abs() < 1e-12 && (z - 2.0).abs() < 1e-9,
            "{s} {z}"
        );
        assert!(precision_check(&est, &vec![None; truth.len()], &truth).is_none());
    }

    #[test]
    fn axis_error_ignores_sign() {
        let a = Vector3::new(0.0, 0.0, 1.0);
        assert!(axis_error_deg(&a, &-a) < 1e-9);
        assert!((axis_error_deg(&a, &Vector3::new(1.0, 0.0, 0.0)) - 90.0).abs() < 1e-9);
    }
}
