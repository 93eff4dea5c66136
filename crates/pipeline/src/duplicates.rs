//! Duplicate points: one marker's track stored twice under two names (a laboratory's labels
//! and a model's, say). Two copies share their noise, so they stay far closer than any two
//! markers can sit; kept both, they make a body of three points a degenerate pair and count
//! one marker twice in every fit. The later copy is left out, with a warning, before
//! anything else.

use kinetree_core::nalgebra::Point3;
use kinetree_core::{Result, Tracks, Warning};
use serde::{Deserialize, Serialize};

/// `[pipeline.duplicates]`: which points repeat another's track.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DuplicateParams {
    /// Whether duplicates are left out (default true).
    pub enabled: bool,
    /// Two points whose median distance over the frames both are seen in is at most this
    /// are one point, metres (default 5e-4: copies of one marker sit 0.02-0.05 mm apart in
    /// the recordings measured, while two markers cannot sit closer than their diameter, and
    /// two keypoints with independent noise of 0.3 mm or more stay about 0.6 mm apart or
    /// more; `docs/decisions.md`, `duplicates.within_m`).
    pub within_m: f64,
    /// Fewest frames both points must be seen in (default 3).
    pub min_frames: usize,
    /// Frames, evenly spaced, in which close pairs are looked for before their whole tracks
    /// are compared (default 32): copies are seen in the same frames, so a few frames find
    /// them, and the search stays linear in the points.
    pub probe_frames: usize,
}

impl Default for DuplicateParams {
    fn default() -> Self {
        Self {
            enabled: true,
            within_m: 5e-4,
            min_frames: 3,
            probe_frames: 32,
        }
    }
}

impl DuplicateParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `pipeline.duplicates.<key>`.
    pub fn validate(&self) -> Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_within("pipeline.duplicates.within_m", self.within_m, 0.0, 1.0)?;
        check_count(
            "pipeline.duplicates.min_frames",
            self.min_frames,
            1,
            1_000_000,
        )?;
        check_count(
            "pipeline.duplicates.probe_frames",
            self.probe_frames,
            1,
            1_000_000,
        )
    }

    /// The points that repeat an earlier point's track, as `(kept, dropped)` pairs in the
    /// order of the dropped points; a point that repeats a dropped one names that one's kept
    /// point.
    pub fn duplicates(&self, tracks: &Tracks) -> Vec<(usize, usize)> {
        let (t_all, n) = (tracks.n_frames(), tracks.n_points());
        if t_all == 0 || n < 2 {
            return Vec::new();
        }
        let probes = self.probe_frames.min(t_all);
        let mut candidates: Vec<(usize, usize)> = Vec::new();
        for k in 0..probes {
            let t = k * t_all / probes;
            // Sorted along the axis the points spread most along (planar data may hold one
            // coordinate constant), only points within `within_m` along it can be that close.
            let points: Vec<(usize, Point3<f64>)> = (0..n)
                .filter_map(|i| tracks.get(t, i).map(|p| (i, p)))
                .collect();
            let spread = |a: usize| {
                let (lo, hi) = points
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(lo, hi), (_, p)| {
                        (lo.min(p[a]), hi.max(p[a]))
                    });
                hi - lo
            };
            let axis = (0..3)
                .max_by(|&a, &b| spread(a).total_cmp(&spread(b)))
                .unwrap_or(0);
            let mut seen: Vec<(f64, usize, Point3<f64>)> =
                points.iter().map(|&(i, p)| (p[axis], i, p)).collect();
            seen.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            for (a, &(xa, i, pa)) in seen.iter().enumerate() {
                for &(xb, j, pb) in &seen[a + 1..] {
                    if xb - xa > self.within_m {
                        break;
                    }
                    if (pa - pb).norm() <= self.within_m {
                        candidates.push((i.min(j), i.max(j)));
                    }
                }
            }
        }
        candidates.sort_unstable();
        candidates.dedup();
        let mut kept_of: Vec<Option<usize>> = vec![None; n];
        let mut out = Vec::new();
        for (i, j) in candidates {
            if kept_of[j].is_some() || !self.same_track(tracks, i, j) {
                continue;
            }
            let kept = kept_of[i].unwrap_or(i);
            kept_of[j] = Some(kept);
            out.push((kept, j));
        }
        out.sort_unstable_by_key(|&(_, j)| j);
        out
    }

    /// Whether points `i` and `j` stay within `within_m` (median over the frames both are
    /// seen in, at least `min_frames` of them).
    fn same_track(&self, tracks: &Tracks, i: usize, j: usize) -> bool {
        let mut d: Vec<f64> = (0..tracks.n_frames())
            .filter_map(|t| {
                let (a, b) = (tracks.get(t, i)?, tracks.get(t, j)?);
                Some((a - b).norm())
            })
            .collect();
        if d.len() < self.min_frames {
            return false;
        }
        d.sort_by(f64::total_cmp);
        d[d.len() / 2] <= self.within_m
    }

    /// `tracks` with every duplicate left out (occluded in every frame), and the warning that
    /// names them; `None` when there are none (or the check is off).
    ///
    /// # Errors
    /// Those of [`Tracks::without_samples`] (none when a point is kept for each duplicate).
    pub fn clean(&self, tracks: &Tracks) -> Result<Option<(Tracks, Warning)>> {
        if !self.enabled {
            return Ok(None);
        }
        let pairs = self.duplicates(tracks);
        if pairs.is_empty() {
            return Ok(None);
        }
        let samples: Vec<(usize, usize)> = (0..tracks.n_frames())
            .flat_map(|t| {
                pairs
                    .iter()
                    .filter(move |&&(_, j)| tracks.get(t, j).is_some())
                    .map(move |&(_, j)| (t, j))
            })
            .collect();
        let cleaned = tracks.without_samples(&samples)?;
        let warning = Warning::PointsDuplicated {
            points: pairs.iter().map(|&(_, j)| j).collect(),
            of: pairs.iter().map(|&(i, _)| i).collect(),
            within_m: self.within_m,
        };
        Ok(Some((cleaned, warning)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Four points turning about the origin; point 4 a copy of point 1 off by `offset`
    /// metres along x plus a wobble of amplitude `noise`, point 5 one off by `offset` along
    /// y, seen in two frames of three.
    fn with_copy(offset: f64, noise: f64) -> Tracks {
        let frames: Vec<Vec<Option<Point3<f64>>>> = (0..60)
            .map(|t| {
                let a = 0.05 * t as f64;
                let mut row: Vec<Option<Point3<f64>>> = (0..4)
                    .map(|i| {
                        let r = 0.1 + 0.05 * i as f64;
                        Some(Point3::new(r * a.cos(), r * a.sin(), 0.02 * i as f64))
                    })
                    .collect();
                // A deterministic wobble, different for the copy, standing for its own noise.
                let wobble = noise * ((7 * t) as f64).sin();
                let p1 = row[1].expect("seen");
                row.push(Some(
                    p1 + kinetree_core::nalgebra::Vector3::new(offset + wobble, 0.0, 0.0),
                ));
                row.push(
                    (t % 3 != 0)
                        .then(|| p1 + kinetree_core::nalgebra::Vector3::new(0.0, offset, 0.0)),
                );
                row
            })
            .collect();
        Tracks::from_points(&frames).expect("tracks")
    }

    #[test]
    fn copies_of_a_track_are_left_out_and_named() {
        let p = DuplicateParams::default();
        let tracks = with_copy(3e-5, 0.0);
        assert_eq!(p.duplicates(&tracks), vec![(1, 4), (1, 5)]);
        let (cleaned, warning) = p.clean(&tracks).expect("clean").expect("some");
        assert_eq!(cleaned.visible_count(4), 0);
        assert_eq!(cleaned.visible_count(5), 0);
        assert_eq!(cleaned.visible_count(1), tracks.visible_count(1));
        assert_eq!(warning.points_left_out(), &[4, 5]);
        assert!(warning.to_string().contains("[1, 1]"), "{warning}");
    }

    #[test]
    fn points_apart_or_with_their_own_noise_are_kept() {
        let p = DuplicateParams::default();
        // A millimetre apart: two markers, not one.
        assert!(p.duplicates(&with_copy(1e-3, 0.0)).is_empty());
        // Close on average, but with noise of its own well above the bound.
        let noisy = p.duplicates(&with_copy(0.0, 2e-3));
        assert!(noisy.iter().all(|&(_, j)| j != 4), "{noisy:?}");
        assert_eq!(noisy, vec![(1, 5)]);
        let off = DuplicateParams {
            enabled: false,
            ..p
        };
        assert!(off.clean(&with_copy(3e-5, 0.0)).expect("clean").is_none());
    }

    #[test]
    fn bad_parameters_are_named() {
        let bad = DuplicateParams {
            within_m: f64::NAN,
            ..DuplicateParams::default()
        };
        let e = bad.validate().expect_err("nan").to_string();
        assert!(e.contains("pipeline.duplicates.within_m"), "{e}");
        let bad = DuplicateParams {
            probe_frames: 0,
            ..DuplicateParams::default()
        };
        let e = bad.validate().expect_err("zero").to_string();
        assert!(e.contains("pipeline.duplicates.probe_frames"), "{e}");
    }
}
