//! Memory estimates made before anything large is allocated, and the limit they are held to.
//!
//! The estimates are upper bounds fitted to measured peaks (`docs/decisions.md`,
//! `limits.max_memory_gib`); a request above the limit is refused with
//! [`Error::TooLarge`] stating both, and the limit is a parameter (`max_memory_gib` in
//! `[pipeline]`, `--max-memory` on the command line).

use crate::{Error, Result};

/// Default memory limit, GiB: a third of a 24 GiB workstation, enough for about 16 000
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
/// bytes a point squared, bounded here by 32), the tracks and their per-body copies with the
/// observations (bounded by 200 bytes each).
pub fn discovery_bytes(n_frames: u64, n_points: u64) -> f64 {
    let n = n_points as f64;
    32.0 * n * n + 200.0 * n_frames as f64 * n
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

/// Checks a limit's value.
///
/// # Errors
/// [`Error::InvalidParameter`] naming `name` unless it is finite and positive.
pub fn validate_limit(name: &str, max_gib: f64) -> Result<()> {
    if max_gib.is_finite() && max_gib > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name: name.into(),
            message: format!("must be a finite, positive number of GiB, got {max_gib}"),
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
            text.contains("11.9 GiB") && text.contains("8.0 GiB"),
            "{text}"
        );
        assert!(text.contains("--max-memory"), "{text}");
        check_memory("x", discovery_bytes(3, 20_000), 16.0).expect("raised limit");
        assert!(tracks_bytes(u64::MAX, u64::MAX).is_finite());
        assert!(validate_limit("max_memory_gib", f64::NAN).is_err());
        assert!(validate_limit("max_memory_gib", 0.0).is_err());
    }
}
