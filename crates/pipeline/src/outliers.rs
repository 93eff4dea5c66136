//! Impossible samples: coordinates no recording in metres can hold, and one-sample jumps that
//! no motion explains (a tracker's glitch). They are dropped (made occluded) before anything
//! else, with a warning, so that one bad sample cannot change the structure.

use kinetree_core::{Result, Tracks, Warning};
use serde::{Deserialize, Serialize};

/// `[pipeline.outliers]`: which samples are impossible.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutlierParams {
    /// Whether impossible samples are dropped (default true).
    pub enabled: bool,
    /// A sample with a coordinate beyond this magnitude is impossible, metres (default 1e4:
    /// 10 km, far beyond any capture volume; C3D files hold 3e38 and similar for broken
    /// samples).
    pub max_coordinate_m: f64,
    /// A sample is a glitch when it leaves its track's previous and next visible samples by
    /// more than this many times the track's median speed (per frame, over samples in
    /// consecutive frames; times the frames between them) and those two samples are closer to each other than half of either jump:
    /// the point jumps away and straight back (default 20; a sine motion's peak speed is 1.6
    /// times its median, and a still point's noise jumps about 2 sigma).
    pub jump_factor: f64,
    /// ... and by more than this, metres (default 0.05): a still marker that flickers between
    /// two reconstructions a few millimetres apart jumps far beyond its own tiny speed but
    /// within the noise, and is no glitch.
    pub min_jump_m: f64,
    /// Fewest pairs of visible samples in consecutive frames a track needs for its speed,
    /// and with it its glitches, to be judged: a track seen in scattered frames is left as
    /// it is (default 5).
    pub min_steps: usize,
}

impl Default for OutlierParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_coordinate_m: 1e4,
            jump_factor: 20.0,
            min_jump_m: 0.05,
            min_steps: 5,
        }
    }
}

/// The most dropped samples a warning lists one by one (the count is always complete).
const LISTED: usize = 50;

impl OutlierParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `pipeline.outliers.<key>`.
    pub fn validate(&self) -> Result<()> {
        use kinetree_core::limits::check_within;
        check_within(
            "pipeline.outliers.max_coordinate_m",
            self.max_coordinate_m,
            1e-3,
            1e300,
        )?;
        check_within("pipeline.outliers.jump_factor", self.jump_factor, 2.0, 1e12)?;
        check_within("pipeline.outliers.min_jump_m", self.min_jump_m, 0.0, 1e300)?;
        kinetree_core::limits::check_count(
            "pipeline.outliers.min_steps",
            self.min_steps,
            1,
            1_000_000,
        )
    }

    /// The impossible samples of `tracks`, as (frame, point), in frame-major order.
    pub fn impossible_samples(&self, tracks: &Tracks) -> Vec<(usize, usize)> {
        use rayon::prelude::*;
        // Each point's track is judged alone, so the points run in parallel; the sort makes
        // the list the same with any number of threads.
        let mut out: Vec<(usize, usize)> = (0..tracks.n_points())
            .into_par_iter()
            .flat_map_iter(|i| {
                let mut out = Vec::new();
                let mut track: Vec<(usize, [f64; 3])> = Vec::new();
                for t in 0..tracks.n_frames() {
                    if let Some(p) = tracks.get(t, i) {
                        let p = [p.x, p.y, p.z];
                        if p.iter().all(|c| c.abs() <= self.max_coordinate_m) {
                            track.push((t, p));
                        } else {
                            out.push((t, i));
                        }
                    }
                }
                out.extend(self.glitches(&track).into_iter().map(|t| (t, i)));
                out
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// Frames of one track's one-sample glitches.
    fn glitches(&self, track: &[(usize, [f64; 3])]) -> Vec<usize> {
        if track.len() < 3 {
            return Vec::new();
        }
        let dist = |a: &[f64; 3], b: &[f64; 3]| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        // The speed from samples in consecutive frames only: across a gap an oscillating
        // point may have gone and come back, so the distance over the gap understates it.
        let mut speeds: Vec<f64> = track
            .windows(2)
            .filter(|w| w[1].0 == w[0].0 + 1)
            .map(|w| dist(&w[0].1, &w[1].1))
            .collect();
        if speeds.len() < self.min_steps.max(1) {
            return Vec::new();
        }
        speeds.sort_by(f64::total_cmp);
        let median = speeds[speeds.len() / 2];
        let bound =
            |frames: usize| (self.jump_factor * median * frames as f64).max(self.min_jump_m);
        // `k` jumps from `a` and back to `b`.
        let away_and_back = |a: usize, k: usize, b: usize| {
            let (pa, pk, pb) = (&track[a].1, &track[k].1, &track[b].1);
            let (d_in, d_out) = (dist(pa, pk), dist(pk, pb));
            d_in > bound(track[k].0 - track[a].0)
                && d_out > bound(track[b].0 - track[k].0)
                && dist(pa, pb) < 0.5 * d_in.min(d_out)
        };
        // An end sample far from a neighbour that agrees with the one beyond it.
        let end_off = |e: usize, n: usize, m: usize| {
            let (pe, pn, pm) = (&track[e].1, &track[n].1, &track[m].1);
            dist(pe, pn) > bound(track[e].0.abs_diff(track[n].0))
                && dist(pn, pm) <= bound(track[n].0.abs_diff(track[m].0))
        };
        let last = track.len() - 1;
        let mut out = Vec::new();
        if end_off(0, 1, 2) {
            out.push(track[0].0);
        }
        out.extend(
            (1..last)
                .filter(|&k| away_and_back(k - 1, k, k + 1))
                .map(|k| track[k].0),
        );
        if end_off(last, last - 1, last - 2) {
            out.push(track[last].0);
        }
        out
    }

    /// `tracks` without their impossible samples, and the warning that lists them; `None`
    /// when there are none (or the check is off).
    ///
    /// # Errors
    /// [`kinetree_core::Error::Degenerate`] when every sample is impossible.
    pub fn clean(&self, tracks: &Tracks) -> Result<Option<(Tracks, Warning)>> {
        if !self.enabled {
            return Ok(None);
        }
        let samples = self.impossible_samples(tracks);
        if samples.is_empty() {
            return Ok(None);
        }
        let cleaned = tracks.without_samples(&samples).map_err(|e| match e {
            kinetree_core::Error::NoVisibleData => kinetree_core::Error::Degenerate(format!(
                "every visible sample is impossible ({} of them: coordinates beyond {} m or \
                 one-frame jumps); are the tracks in metres?",
                samples.len(),
                self.max_coordinate_m
            )),
            other => other,
        })?;
        let mut points: Vec<usize> = samples.iter().map(|&(_, i)| i).collect();
        points.sort_unstable();
        points.dedup();
        let warning = Warning::ImpossibleSamplesDropped {
            count: samples.len(),
            points,
            samples: samples.iter().take(LISTED).map(|&(t, i)| [t, i]).collect(),
        };
        Ok(Some((cleaned, warning)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinetree_core::nalgebra::Point3;

    fn moving(n_frames: usize) -> Vec<Vec<Option<Point3<f64>>>> {
        (0..n_frames)
            .map(|t| {
                let a = 0.05 * t as f64;
                (0..4)
                    .map(|i| {
                        let r = 0.1 + 0.05 * i as f64;
                        Some(Point3::new(r * a.cos(), r * a.sin(), 0.01 * i as f64))
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn glitches_and_huge_values_are_found_and_nothing_else() {
        let p = OutlierParams::default();
        let mut frames = moving(60);
        let clean = Tracks::from_points(&frames).expect("tracks");
        assert!(p.impossible_samples(&clean).is_empty());
        frames[10][1] = Some(Point3::new(10.0, 0.0, 0.0));
        frames[0][2] = Some(Point3::new(0.0, -3.0, 0.0));
        frames[59][3] = Some(Point3::new(3e38, 0.0, 0.0));
        frames[30][0] = None;
        frames[31][0] = Some(Point3::new(0.0, 0.0, 5.0));
        let bad = Tracks::from_points(&frames).expect("tracks");
        assert_eq!(
            p.impossible_samples(&bad),
            vec![(0, 2), (10, 1), (31, 0), (59, 3)]
        );
        let (cleaned, warning) = p.clean(&bad).expect("clean").expect("dropped");
        assert_eq!(cleaned.get(10, 1), None);
        assert_eq!(cleaned.get(11, 1), bad.get(11, 1));
        assert!(matches!(
            warning,
            Warning::ImpossibleSamplesDropped { count: 4, .. }
        ));
        let off = OutlierParams {
            enabled: false,
            ..p
        };
        assert!(off.clean(&bad).expect("clean").is_none());
        assert!(
            OutlierParams {
                jump_factor: f64::NAN,
                ..p
            }
            .validate()
            .is_err()
        );
    }
}
