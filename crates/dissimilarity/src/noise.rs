//! Estimating the keypoint noise level from the data.

use kinetree_core::stats::chi2_per_dof_quantile;
use kinetree_core::{Error, PairStats, Result, Segmentation, condensed_index};

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Estimates the per-coordinate noise std-dev (metres) from pair statistics alone.
///
/// Rigid pairs have distance variances `2 sigma^2 chi^2_d / d`: a narrow band in log-variance
/// (width about `sqrt(2/d)`) at the bottom of the distribution, since a moving pair can only
/// have more variance. The estimator scans log-variances upward for the first window of width
/// `4 sqrt(2/d)` holding at least `max(3, N/2)` pairs (every point has at least two rigid
/// partners, so the band holds at least `N` pairs), moves to the densest window starting within
/// one width of it, and takes that window's median.
///
/// When at least that many pairs keep their distance to machine precision (`std <= 1e-12`
/// of the distance: noise-free data), the estimate is a floor of `1e-6` of their typical
/// distance instead. The floor sits above the precision of the later stages' iterations
/// (reference shapes, fits that stop at a step tolerance): at `1e-9`, a noise-free mechanism
/// of 2 cm slides found by the invariance tests' deep pass gave 3 of its 7 joints as
/// multi-DoF, and which 3 depended on the order of the points; at `1e-6` all 7 are right in
/// either order.
///
/// This is a first guess; [`refine_noise_sigma`] improves it once bodies are known.
///
/// # Errors
/// [`Error::Degenerate`] when too few pairs have a usable variance.
pub fn estimate_noise_sigma(stats: &PairStats) -> Result<f64> {
    let mut z: Vec<(f64, f64)> = stats
        .var_m2
        .iter()
        .zip(&stats.count)
        .filter(|(v, c)| **c >= 3 && v.is_finite() && **v > 0.0)
        .map(|(v, c)| {
            let d = f64::from(*c - 1);
            // E[ln(chi^2_d / d)] is about -1/d: remove that bias.
            (v.ln() + 1.0 / d, (2.0 / d).sqrt())
        })
        .collect();
    let need = (stats.n_points / 2).max(3);
    // Noise-free data (a simulator without noise): rigid pairs keep their distance to machine
    // precision and the log-variance band below is empty, so report a floor instead of
    // mistaking moving pairs for the band.
    let mut exact: Vec<f64> = stats
        .var_m2
        .iter()
        .zip(&stats.count)
        .zip(&stats.mean_m)
        .filter(|((v, c), m)| {
            **c >= 3 && v.is_finite() && m.is_finite() && **m > 0.0 && v.sqrt() <= 1e-12 * **m
        })
        .map(|(_, m)| *m)
        .collect();
    let seen_often = stats.count.iter().filter(|&&c| c >= 3).count();
    // Some pairs exact and some moving: noise-free motion. All exact: constant data, handled
    // below as an error (there is nothing to tell the noise from).
    if exact.len() >= need && exact.len() < seen_often {
        return Ok(1e-6 * median(&mut exact));
    }
    if z.is_empty() && seen_often > 0 {
        return Err(Error::Degenerate(format!(
            "cannot estimate the noise level: all {seen_often} pairs seen in 3+ frames keep exactly constant distances (noise-free or constant data); give the noise level explicitly"
        )));
    }
    if z.len() < need {
        return Err(Error::Degenerate(format!(
            "cannot estimate the noise level: only {} pairs are seen together in 3+ frames (need {need})",
            z.len()
        )));
    }
    z.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut widths: Vec<f64> = z.iter().map(|p| p.1).collect();
    let w = 4.0 * median(&mut widths);
    let zs: Vec<f64> = z.iter().map(|p| p.0).collect();
    let count_from = |i: usize| zs[i..].partition_point(|&v| v <= zs[i] + w);
    let first = (0..zs.len()).find(|&i| count_from(i) >= need).unwrap_or(0);
    let end = zs.partition_point(|&v| v <= zs[first] + w);
    let best = (first..end.max(first + 1))
        .max_by_key(|&i| (count_from(i), std::cmp::Reverse(i)))
        .unwrap_or(first);
    let mut window: Vec<f64> = zs[best..best + count_from(best)].to_vec();
    let var_d = median(&mut window).exp();
    Ok((var_d / 2.0).sqrt())
}

/// A pair whose variance is above the robust noise level by more than this many standard
/// deviations of `chi^2_d / d` is left out of the pooled estimate of [`refine_noise_sigma`].
const POOL_Z: f64 = 3.0;

/// Lower quartile of `chi^2_d / d` (Wilson-Hilferty).
fn chi2_lower_quartile_over_dof(d: f64) -> f64 {
    let c = 2.0 / (9.0 * d);
    (1.0 - c - 0.674_489_75 * c.sqrt()).max(1e-6).powi(3)
}

/// Re-estimates the noise level from the pairs inside each body of a segmentation, robustly:
/// each pair implies `sigma_d^2 = s^2 / q25(d)`, with `q25(d)` the lower quartile of
/// `chi^2_d / d`. Under the null a quarter of those values fall below the true `sigma_d^2`,
/// so their 25th percentile estimates it. Moving pairs in a wrongly merged body only add
/// variance, so the estimate holds with up to 75 % of such pairs (the median, for
/// comparison, was measured 10-14 % high on 20-body scenes with merged bodies). The pairs
/// within `POOL_Z` standard deviations of that value are then pooled, each weighted by its
/// degrees of freedom, for the final estimate: on a draw of 640 mechanisms at 1 mm and 30 %
/// occlusion its spread is 1.02 % (mean 0.999 of the truth) against 1.32 % for the robust
/// value alone (`docs/decisions.md`, `kinetree_dissimilarity::POOL_Z`). Returns `None` when
/// no body has a usable pair.
pub fn refine_noise_sigma(stats: &PairStats, segmentation: &Segmentation) -> Option<f64> {
    let n = stats.n_points;
    // (variance, degrees of freedom) of every usable pair inside a body.
    let mut pairs = Vec::new();
    for members in segmentation.members() {
        for (a, &i) in members.iter().enumerate() {
            for &j in &members[a + 1..] {
                let k = condensed_index(n, i, j);
                let (c, v) = (stats.count[k], stats.var_m2[k]);
                if c >= 3 && v.is_finite() {
                    pairs.push((v, f64::from(c - 1)));
                }
            }
        }
    }
    if pairs.is_empty() {
        return None;
    }
    let mut r: Vec<f64> = pairs
        .iter()
        .map(|&(v, d)| v / chi2_lower_quartile_over_dof(d))
        .collect();
    r.sort_by(f64::total_cmp);
    let robust = r[(r.len() - 1) / 4];
    if robust <= 0.0 {
        return None;
    }
    // The pairs that agree with the robust value, pooled: a quantile of a few dozen pairs that
    // share their keypoints' noise is a noisy estimate (a 6-keypoint slider on an 8-keypoint
    // base: 8 % low, and the rigid slider looked like two), the pooled variance of the
    // consistent pairs a precise one. Moving pairs of a wrongly merged body lie far above
    // and are left out.
    let (mut sum, mut dof) = (0.0, 0.0);
    for &(v, d) in &pairs {
        if v / robust <= chi2_per_dof_quantile(d, POOL_Z) {
            sum += d * v;
            dof += d;
        }
    }
    let var_d = if dof > 0.0 { sum / dof } else { robust };
    (var_d > 0.0).then(|| (var_d / 2.0).sqrt())
}

/// Noise level for keypoints on soft, only roughly rigid bodies (motion capture on skin,
/// markers rigid to 1-5 mm): the median over points of each point's *second*-smallest pair
/// distance std-dev, divided by `sqrt 2`.
///
/// [`estimate_noise_sigma`] looks for a mode of pairs sharing one variance; on skin markers
/// the rigid pairs spread over a decade of variance (0.9-2.8 mm std-dev on one recording,
/// 0.07-4.8 mm on another) and make up about 6 % of the pairs, so the mode lands among moving
/// pairs (5-20 mm estimated on the five recordings in experiments/real). Here a point needs
/// only two partners on its own body (a marker triad suffices), and the median over points
/// ignores the minority without any. On rigid synthetic bodies it reads low (the second
/// smallest of about ten sample std-devs), so it is not the default.
///
/// The estimate is at least `1e-6` of the typical distance of those pairs, as
/// [`estimate_noise_sigma`]'s floor for noise-free data: markers a body model writes out
/// (no noise, float32 coordinates) keep their distances to float rounding, about `1e-8` m,
/// below what the later stages' iterations resolve.
///
/// # Errors
/// [`Error::Degenerate`] when fewer than three points have two pairs seen in 3+ frames, or
/// the result is zero (constant data).
pub fn estimate_noise_sigma_nearest_rigid(stats: &PairStats) -> Result<f64> {
    let n = stats.n_points;
    // Each point's second most rigid pair: its distance std-dev and mean distance.
    let (mut second, mut distance): (Vec<f64>, Vec<f64>) = (0..n)
        .filter_map(|i| {
            let mut s: Vec<(f64, f64)> = (0..n)
                .filter(|&j| j != i)
                .map(|j| condensed_index(n, i, j))
                .filter(|&k| {
                    stats.count[k] >= 3
                        && stats.var_m2[k].is_finite()
                        && stats.mean_m[k].is_finite()
                })
                .map(|k| (stats.var_m2[k].max(0.0).sqrt(), stats.mean_m[k]))
                .collect();
            if s.len() < 2 {
                return None;
            }
            s.sort_by(|a, b| a.0.total_cmp(&b.0));
            Some(s[1])
        })
        .unzip();
    if second.len() < 3 {
        return Err(Error::Degenerate(format!(
            "cannot estimate the noise level: only {} points have two partners seen in 3+ frames",
            second.len()
        )));
    }
    let sigma = median(&mut second) / std::f64::consts::SQRT_2;
    let floor = 1e-6 * median(&mut distance);
    if sigma > 0.0 {
        Ok(sigma.max(floor))
    } else if floor > 0.0 && stats.var_m2.iter().any(|&v| v.is_finite() && v > 0.0) {
        // Some pairs move: noise-free motion, not constant data.
        Ok(floor)
    } else {
        Err(Error::Degenerate(
            "cannot estimate the noise level: the points keep exactly constant distances (noise-free or constant data); give the noise level explicitly".into(),
        ))
    }
}
