//! Memory and work estimates made before anything large is allocated or started, and the
//! limits they are held to.
//!
//! The memory estimates are upper bounds fitted to measured peaks (`docs/decisions.md`,
//! `limits.max_memory_gib`), the work estimates are fitted to measured times
//! (`limits.max_minutes`); a request above its limit is refused with [`Error::TooLarge`]
//! stating both, and the limits are parameters (`max_memory_gib` and `max_minutes` in
//! `[pipeline]`, `--max-memory` and `--max-minutes` on the command line).

use crate::{Error, Result};

/// Default memory limit, GiB: a third of a 24 GiB workstation, enough for about 13 000
/// keypoints in one discovery.
pub const DEFAULT_MAX_MEMORY_GIB: f64 = 8.0;

const GIB: f64 = 1024.0 * 1024.0 * 1024.0;

/// Bytes a tracks array of `n_frames x n_points` takes (three `f64` coordinates and a
/// visibility flag per observation), as `f64` so that absurd sizes do not overflow.
pub fn tracks_bytes(n_frames: u64, n_points: u64) -> f64 {
    25.0 * n_frames as f64 * n_points as f64
}

/// Peak bytes of one discovery of `n_frames x n_points`: the pairwise statistics, the
/// dissimilarity matrix and the clusterer's copies grow with the pairs (measured up to 27
/// bytes a point squared with kodama's linkage; the frame-weighted average linkage's dense
/// rows add 16, so bounded here by 48), the tracks and their per-body copies with the
/// observations (bounded by 200 bytes each).
pub fn discovery_bytes(n_frames: u64, n_points: u64) -> f64 {
    let n = n_points as f64;
    48.0 * n * n + 200.0 * n_frames as f64 * n
}

/// Default work limit, minutes of estimated work: a discovery estimated to take longer is
/// refused before its expensive phase starts.
pub const DEFAULT_MAX_MINUTES: f64 = 30.0;

/// Pair-frames per second the pair statistics are estimated to run at (the pair kernel's
/// measured throughput on 2 cores is 0.7-1.3e9, `docs/benchmarks.md`).
const PAIR_FRAMES_PER_SECOND: f64 = 1e9;

/// Seconds per frame and cubed body the model phases are estimated to take (fitted to whole
/// discoveries of 3-77 bodies over 5-200 000 frames, `docs/decisions.md`,
/// `limits.max_minutes`).
const SECONDS_PER_FRAME_BODY3: f64 = 6e-6;

/// Estimated seconds of the pair statistics over `n_frames x n_points` (every pair in every
/// frame), as `f64` so that absurd sizes do not overflow.
pub fn pairs_seconds(n_frames: u64, n_points: u64) -> f64 {
    let n = n_points as f64;
    n_frames as f64 * n * (n - 1.0).max(0.0) / 2.0 / PAIR_FRAMES_PER_SECOND
}

/// Estimated seconds of a discovery's bodies, tree and whole-tree fit phases once the
/// clustering has found `n_bodies` bodies over `n_frames` frames. Their cost grows with the
/// frames and with the cube of the bodies: the bundle adjustment's reduced system is dense
/// in the joints' parameters, and each frame's term is a product over the frame's own.
pub fn model_seconds(n_frames: u64, n_bodies: u64) -> f64 {
    let b = n_bodies as f64;
    SECONDS_PER_FRAME_BODY3 * n_frames as f64 * b * b * b
}

/// Refuses `what` when its estimated `seconds` exceed `max_minutes`; `advice` says what
/// besides raising the limit may help.
///
/// # Errors
/// [`Error::TooLarge`] with the estimate and the limit, saying how to raise it.
pub fn check_work(what: &str, seconds: f64, max_minutes: f64, advice: &str) -> Result<()> {
    if seconds <= max_minutes * 60.0 {
        return Ok(());
    }
    let mut hint = "raise the limit with --max-minutes <minutes> or `max_minutes` in [pipeline] \
                    to run it anyway"
        .to_string();
    if !advice.is_empty() {
        hint = format!("{advice}; or {hint}");
    }
    Err(Error::TooLarge {
        what: what.into(),
        estimate: format_seconds(seconds),
        limit: format_seconds(max_minutes * 60.0),
        hint,
    })
}

fn format_seconds(seconds: f64) -> String {
    if seconds >= 7200.0 {
        format!("{:.1} hours of work", seconds / 3600.0)
    } else if seconds >= 120.0 {
        format!("{:.1} minutes of work", seconds / 60.0)
    } else if seconds >= 0.01 {
        format!("{seconds:.2} seconds of work")
    } else {
        format!("{seconds:.1e} seconds of work")
    }
}

/// Checks that the real parameter `name` is finite and within `[lo, hi]`.
///
/// # Errors
/// [`Error::InvalidParameter`] naming `name` with the range.
pub fn check_within(name: &str, v: f64, lo: f64, hi: f64) -> Result<()> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: name.into(),
            message: format!("must be within [{lo}, {hi}], got {v}"),
        })
    }
}

/// Checks that the count `name` is within `lo..=hi`.
///
/// # Errors
/// [`Error::InvalidParameter`] naming `name` with the range.
pub fn check_count(name: &str, v: usize, lo: usize, hi: usize) -> Result<()> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: name.into(),
            message: format!("must be within [{lo}, {hi}], got {v}"),
        })
    }
}

/// Checks a memory limit's value.
///
/// # Errors
/// [`Error::InvalidParameter`] naming `name` unless it is finite and positive.
pub fn validate_limit(name: &str, max_gib: f64) -> Result<()> {
    validate_positive(name, max_gib, "GiB")
}

/// Checks a work limit's value.
///
/// # Errors
/// [`Error::InvalidParameter`] naming `name` unless it is finite and positive.
pub fn validate_minutes(name: &str, max_minutes: f64) -> Result<()> {
    validate_positive(name, max_minutes, "minutes")
}

fn validate_positive(name: &str, v: f64, unit: &str) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: name.into(),
            message: format!("must be a finite, positive number of {unit}, got {v}"),
        })
    }
}

/// Refuses `what` when its estimated `bytes` exceed `max_gib`.
///
/// # Errors
/// [`Error::TooLarge`] with the estimate and the limit, saying how to raise it.
pub fn check_memory(what: &str, bytes: f64, max_gib: f64) -> Result<()> {
    if bytes <= max_gib * GIB {
        return Ok(());
    }
    Err(Error::TooLarge {
        what: what.into(),
        estimate: format_bytes(bytes),
        limit: format_bytes(max_gib * GIB),
        hint: "raise the limit with --max-memory <GiB> or `max_memory_gib` in [pipeline] \
               if the machine has the memory"
            .into(),
    })
}

fn format_bytes(bytes: f64) -> String {
    if bytes >= GIB / 10.0 {
        format!("{:.1} GiB", bytes / GIB)
    } else {
        format!("{:.1} MiB", bytes / (1024.0 * 1024.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn estimates_above_the_limit_are_refused_naming_both() {
        check_memory("x", discovery_bytes(100, 1000), DEFAULT_MAX_MEMORY_GIB).expect("small");
        let e = check_memory(
            "discovering 3 frames x 20000 points",
            discovery_bytes(3, 20_000),
            DEFAULT_MAX_MEMORY_GIB,
        )
        .expect_err("20000 points");
        let text = e.to_string();
        assert!(
            text.contains("17.9 GiB") && text.contains("8.0 GiB"),
            "{text}"
        );
        assert!(text.contains("--max-memory"), "{text}");
        check_memory("x", discovery_bytes(3, 20_000), 24.0).expect("raised limit");
        assert!(tracks_bytes(u64::MAX, u64::MAX).is_finite());
        assert!(validate_limit("max_memory_gib", f64::NAN).is_err());
        assert!(validate_limit("max_memory_gib", 0.0).is_err());
    }

    #[test]
    fn work_above_the_limit_is_refused_naming_both_and_the_advice() {
        // The 200 000-frame 3-body recording took 31 s; its estimate is within 10 % of it.
        let long = model_seconds(200_000, 3);
        assert!((long - 32.4).abs() < 0.1, "{long}");
        check_work("x", long, DEFAULT_MAX_MINUTES, "").expect("half a minute");
        let e = check_work(
            "fitting 500 bodies",
            model_seconds(5, 500),
            30.0,
            "give the noise",
        )
        .expect_err("500 bodies");
        let text = e.to_string();
        assert!(text.contains("62.5 minutes of work"), "{text}");
        assert!(text.contains("30.0 minutes of work"), "{text}");
        assert!(text.contains("give the noise; or raise"), "{text}");
        assert!(text.contains("--max-minutes"), "{text}");
        // Pair statistics grow with the frames and the square of the points.
        assert!((pairs_seconds(1000, 20_001) / pairs_seconds(1000, 10_001) - 4.0).abs() < 1e-3);
        assert_eq!(pairs_seconds(5, 1), 0.0);
        assert!(pairs_seconds(u64::MAX, u64::MAX).is_finite());
        assert!(validate_minutes("max_minutes", f64::INFINITY).is_err());
        assert!(validate_minutes("max_minutes", -1.0).is_err());
        validate_minutes("max_minutes", 0.5).expect("half a minute");
    }
}
