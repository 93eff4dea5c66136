//! Tracked keypoints: `T` frames of `N` 3D points, some occluded.

use crate::{Error, Result};
use nalgebra::Point3;

/// `T` frames of `N` 3D keypoints in the camera frame, in metres.
///
/// Stored frame-major (`frame`, `point`, `xyz`), the layout of a C-order `(T, N, 3)` array and
/// the one the pairwise-statistics kernel walks. An occluded observation has all three
/// coordinates NaN; [`Tracks::get`] turns that into `None`, so NaN never reaches an algorithm.
#[derive(Debug, Clone, PartialEq)]
pub struct Tracks {
    n_frames: usize,
    n_points: usize,
    xyz: Vec<f64>,
    labels: Option<Vec<String>>,
    frame_rate_hz: Option<f64>,
    precision_m: Option<f64>,
    warnings: Vec<crate::Warning>,
}

/// The fewest frames the method can use (a variance needs two observations).
pub const MIN_FRAMES: usize = 2;
/// The largest coordinate magnitude accepted: its square, summed over frames, stays far from
/// `f64`'s overflow at 1.8e308.
pub const MAX_COORDINATE: f64 = 1e100;
/// The fewest points the method can use (one rigid body needs three).
pub const MIN_POINTS: usize = 3;

/// `value` when it is finite and positive, else an error naming `name`.
fn finite_positive(name: &str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(Error::InvalidParameter {
            name: name.into(),
            message: format!("must be finite and positive, got {value}"),
        })
    }
}

impl Tracks {
    /// Builds tracks from a frame-major buffer of `n_frames * n_points * 3` coordinates.
    ///
    /// # Errors
    /// [`Error::Shape`] when the buffer length does not match, [`Error::TooFewFrames`] when
    /// `n_frames < 2`, [`Error::TooFewPoints`] when `n_points < 3`, [`Error::PartialNan`] for a
    /// triple with one or two NaN coordinates, [`Error::NonFinite`] for an infinite coordinate,
    /// [`Error::NoVisibleData`] when every triple is NaN.
    pub fn new(n_frames: usize, n_points: usize, xyz: Vec<f64>) -> Result<Self> {
        let expected = n_frames
            .checked_mul(n_points)
            .and_then(|v| v.checked_mul(3))
            .ok_or_else(|| Error::Shape {
                expected: "(T, N, 3) with T*N*3 addressable".into(),
                found: format!("({n_frames}, {n_points}, 3)"),
            })?;
        if xyz.len() != expected {
            return Err(Error::Shape {
                expected: format!("{n_frames} x {n_points} x 3 = {expected} values"),
                found: format!("{} values", xyz.len()),
            });
        }
        if n_frames < MIN_FRAMES {
            return Err(Error::TooFewFrames {
                found: n_frames,
                min: MIN_FRAMES,
            });
        }
        if n_points < MIN_POINTS {
            return Err(Error::TooFewPoints {
                found: n_points,
                min: MIN_POINTS,
            });
        }
        let mut any_visible = false;
        for (k, p) in xyz.chunks_exact(3).enumerate() {
            let nans = p.iter().filter(|v| v.is_nan()).count();
            let (frame, point) = (k / n_points, k % n_points);
            if nans == 3 {
                continue;
            }
            if nans > 0 {
                return Err(Error::PartialNan { frame, point });
            }
            if p.iter().any(|v| v.is_infinite()) {
                return Err(Error::NonFinite { frame, point });
            }
            if let Some(&value) = p.iter().find(|v| v.abs() > MAX_COORDINATE) {
                return Err(Error::CoordinateOverflow {
                    frame,
                    point,
                    value,
                });
            }
            any_visible = true;
        }
        if !any_visible {
            return Err(Error::NoVisibleData);
        }
        Ok(Self {
            n_frames,
            n_points,
            xyz,
            labels: None,
            frame_rate_hz: None,
            precision_m: None,
            warnings: Vec::new(),
        })
    }

    /// Builds tracks from per-frame, per-point optional positions.
    ///
    /// # Errors
    /// As [`Tracks::new`].
    pub fn from_points(frames: &[Vec<Option<Point3<f64>>>]) -> Result<Self> {
        let n_frames = frames.len();
        let n_points = frames.first().map_or(0, Vec::len);
        let mut xyz = Vec::with_capacity(n_frames * n_points * 3);
        for (t, f) in frames.iter().enumerate() {
            if f.len() != n_points {
                return Err(Error::Shape {
                    expected: format!("{n_points} points in every frame"),
                    found: format!("{} points in frame {t}", f.len()),
                });
            }
            for p in f {
                match p {
                    Some(p) => xyz.extend_from_slice(&[p.x, p.y, p.z]),
                    None => xyz.extend_from_slice(&[f64::NAN; 3]),
                }
            }
        }
        Self::new(n_frames, n_points, xyz)
    }

    /// Attaches one label per point (marker names, for example).
    ///
    /// # Errors
    /// [`Error::Shape`] when the count differs from the number of points.
    pub fn with_labels(mut self, labels: Vec<String>) -> Result<Self> {
        if labels.len() != self.n_points {
            return Err(Error::Shape {
                expected: format!("{} labels", self.n_points),
                found: format!("{} labels", labels.len()),
            });
        }
        self.labels = Some(labels);
        Ok(self)
    }

    /// Attaches what the reader noticed (unused labels, say); a discovery starts its
    /// warnings with them.
    pub fn with_warnings(mut self, warnings: Vec<crate::Warning>) -> Self {
        self.warnings = warnings;
        self
    }

    /// What the reader noticed.
    pub fn warnings(&self) -> &[crate::Warning] {
        &self.warnings
    }

    /// Attaches the frame rate in hertz.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] unless the rate is finite and positive.
    pub fn with_frame_rate(mut self, frame_rate_hz: f64) -> Result<Self> {
        self.frame_rate_hz = Some(finite_positive("frame_rate_hz", frame_rate_hz)?);
        Ok(self)
    }

    /// Attaches the step of the grid the file stored the coordinates on, in metres (a C3D
    /// file's integer scale, a text file's last decimal): rounding to it leaves every
    /// coordinate an error of up to half a step, which no noise estimate can go below.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] unless the step is finite and positive.
    pub fn with_precision(mut self, step_m: f64) -> Result<Self> {
        self.precision_m = Some(finite_positive("precision_m", step_m)?);
        Ok(self)
    }

    /// The step of the grid the coordinates were stored on, metres, when the reader knows it
    /// ([`Tracks::with_precision`]).
    pub fn precision_m(&self) -> Option<f64> {
        self.precision_m
    }

    /// Number of frames `T`.
    pub fn n_frames(&self) -> usize {
        self.n_frames
    }

    /// Number of points `N`.
    pub fn n_points(&self) -> usize {
        self.n_points
    }

    /// Point labels, when known.
    pub fn labels(&self) -> Option<&[String]> {
        self.labels.as_deref()
    }

    /// Frame rate in hertz, when known.
    pub fn frame_rate_hz(&self) -> Option<f64> {
        self.frame_rate_hz
    }

    /// Position of `point` in `frame`, `None` when occluded or out of range.
    #[inline]
    pub fn get(&self, frame: usize, point: usize) -> Option<Point3<f64>> {
        if frame >= self.n_frames || point >= self.n_points {
            return None;
        }
        let k = (frame * self.n_points + point) * 3;
        let x = self.xyz[k];
        if x.is_nan() {
            None
        } else {
            Some(Point3::new(x, self.xyz[k + 1], self.xyz[k + 2]))
        }
    }

    /// Every point of `frame`, `None` where occluded (every point `None` when `frame` is out
    /// of range): the per-frame input of a fit.
    pub fn frame_points(&self, frame: usize) -> Vec<Option<Point3<f64>>> {
        (0..self.n_points).map(|i| self.get(frame, i)).collect()
    }

    /// Whether `point` is visible in `frame`.
    #[inline]
    pub fn is_visible(&self, frame: usize, point: usize) -> bool {
        self.get(frame, point).is_some()
    }

    /// The raw coordinates of one frame (`N * 3` values, NaN where occluded).
    pub fn frame_raw(&self, frame: usize) -> &[f64] {
        let n = self.n_points * 3;
        &self.xyz[frame * n..(frame + 1) * n]
    }

    /// The whole frame-major buffer (`T * N * 3` values, NaN where occluded).
    pub fn raw(&self) -> &[f64] {
        &self.xyz
    }

    /// Number of frames in which each point is visible, read in one pass over the frames
    /// (the buffer's order): counting point by point strides across every frame, a cache
    /// miss per frame and point.
    pub fn visible_counts(&self) -> Vec<usize> {
        let mut counts = vec![0; self.n_points];
        if self.n_points == 0 {
            return counts;
        }
        for frame in self.xyz.chunks_exact(3 * self.n_points) {
            for (count, p) in counts.iter_mut().zip(frame.chunks_exact(3)) {
                *count += usize::from(!p[0].is_nan());
            }
        }
        counts
    }

    /// Number of frames in which `point` is visible.
    pub fn visible_count(&self, point: usize) -> usize {
        (0..self.n_frames)
            .filter(|&t| self.is_visible(t, point))
            .count()
    }

    /// Fraction of all (frame, point) observations that are occluded.
    pub fn occluded_fraction(&self) -> f64 {
        let hidden = self.xyz.chunks_exact(3).filter(|p| p[0].is_nan()).count();
        hidden as f64 / (self.n_frames * self.n_points) as f64
    }

    /// `out` (tracks derived from these) with these tracks' labels, frame rate and warnings.
    fn described(&self, mut out: Self) -> Self {
        out.labels.clone_from(&self.labels);
        out.frame_rate_hz = self.frame_rate_hz;
        out.precision_m = self.precision_m;
        out.warnings.clone_from(&self.warnings);
        out
    }

    /// The same tracks restricted to `frames` (in the given order).
    ///
    /// # Errors
    /// As [`Tracks::new`] (too few frames, no visible data), or [`Error::InvalidParameter`] for
    /// an index out of range.
    pub fn select_frames(&self, frames: &[usize]) -> Result<Self> {
        let mut xyz = Vec::with_capacity(frames.len() * self.n_points * 3);
        for &t in frames {
            if t >= self.n_frames {
                return Err(Error::InvalidParameter {
                    name: "frames".into(),
                    message: format!("frame {t} out of range (T = {})", self.n_frames),
                });
            }
            xyz.extend_from_slice(self.frame_raw(t));
        }
        Ok(self.described(Self::new(frames.len(), self.n_points, xyz)?))
    }

    /// The same tracks restricted to `points` (in the given order), their labels with them;
    /// the reader's warnings stay with the whole tracks.
    ///
    /// # Errors
    /// As [`Tracks::new`] (too few points, no visible data), or [`Error::InvalidParameter`]
    /// for an index out of range.
    pub fn select_points(&self, points: &[usize]) -> Result<Self> {
        if let Some(&i) = points.iter().find(|&&i| i >= self.n_points) {
            return Err(Error::InvalidParameter {
                name: "points".into(),
                message: format!("point {i} out of range (N = {})", self.n_points),
            });
        }
        if points.len() < MIN_POINTS {
            return Err(Error::TooFewPoints {
                found: points.len(),
                min: MIN_POINTS,
            });
        }
        let mut xyz = Vec::with_capacity(self.n_frames * points.len() * 3);
        for t in 0..self.n_frames {
            let frame = self.frame_raw(t);
            for &i in points {
                xyz.extend_from_slice(&frame[3 * i..3 * i + 3]);
            }
        }
        // Every copied triple passed `new`'s checks already; only visibility can be lost.
        if xyz.iter().all(|v| v.is_nan()) {
            return Err(Error::NoVisibleData);
        }
        Ok(Self {
            n_frames: self.n_frames,
            n_points: points.len(),
            xyz,
            labels: self
                .labels
                .as_ref()
                .map(|l| points.iter().map(|&i| l[i].clone()).collect()),
            frame_rate_hz: self.frame_rate_hz,
            precision_m: self.precision_m,
            warnings: Vec::new(),
        })
    }

    /// The same tracks with the (frame, point) `samples` made occluded.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for a sample out of range; [`Error::NoVisibleData`] when
    /// nothing visible is left.
    pub fn without_samples(&self, samples: &[(usize, usize)]) -> Result<Self> {
        let mut xyz = self.xyz.clone();
        for &(t, i) in samples {
            if t >= self.n_frames || i >= self.n_points {
                return Err(Error::InvalidParameter {
                    name: "samples".into(),
                    message: format!(
                        "frame {t}, point {i} out of range ({} x {})",
                        self.n_frames, self.n_points
                    ),
                });
            }
            let k = (t * self.n_points + i) * 3;
            xyz[k..k + 3].copy_from_slice(&[f64::NAN; 3]);
        }
        Ok(self.described(Self::new(self.n_frames, self.n_points, xyz)?))
    }

    /// The same tracks with every position mapped through `f` (a change of frame or units).
    ///
    /// # Errors
    /// As [`Tracks::new`], when `f` produces non-finite values.
    pub fn map_points(&self, f: impl Fn(Point3<f64>) -> Point3<f64>) -> Result<Self> {
        let mut xyz = self.xyz.clone();
        for p in xyz.chunks_exact_mut(3) {
            if p[0].is_nan() {
                continue;
            }
            let q = f(Point3::new(p[0], p[1], p[2]));
            p.copy_from_slice(&[q.x, q.y, q.z]);
        }
        Ok(self.described(Self::new(self.n_frames, self.n_points, xyz)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Tracks {
        let mut xyz: Vec<f64> = (0..4 * 3 * 3).map(|k| k as f64 * 0.01).collect();
        xyz[(3 + 2) * 3..(3 + 2) * 3 + 3].copy_from_slice(&[f64::NAN; 3]); // frame 1, point 2
        Tracks::new(4, 3, xyz).expect("valid")
    }

    #[test]
    fn selected_points_keep_their_tracks_and_labels_in_the_given_order() {
        let t = sample()
            .with_labels(vec!["a".into(), "b".into(), "c".into()])
            .expect("labels");
        let s = t.select_points(&[2, 0, 1]).expect("select");
        assert_eq!(s.n_points(), 3);
        assert_eq!(
            s.labels(),
            Some(&["c".to_string(), "a".into(), "b".into()][..])
        );
        for f in 0..4 {
            assert_eq!(s.get(f, 0), t.get(f, 2));
            assert_eq!(s.get(f, 1), t.get(f, 0));
        }
        assert!(matches!(
            t.select_points(&[0, 1, 3]),
            Err(Error::InvalidParameter { .. })
        ));
        assert!(matches!(
            t.select_points(&[0, 1]),
            Err(Error::TooFewPoints { .. })
        ));
        // Points never seen: a selection of only them has nothing visible.
        let mut xyz: Vec<f64> = (0..2 * 6 * 3).map(|k| k as f64 * 0.01).collect();
        for f in 0..2 {
            xyz[(f * 6 + 3) * 3..(f * 6 + 6) * 3].fill(f64::NAN);
        }
        let hidden = Tracks::new(2, 6, xyz).expect("valid");
        assert!(matches!(
            hidden.select_points(&[3, 4, 5]),
            Err(Error::NoVisibleData)
        ));
        assert!(hidden.select_points(&[0, 4, 5]).is_ok());
    }

    #[test]
    fn the_frame_rate_and_the_grid_step_go_with_selections_and_bad_ones_are_named() {
        let t = sample()
            .with_frame_rate(100.0)
            .and_then(|t| t.with_precision(1e-4))
            .expect("valid");
        for s in [
            t.select_points(&[2, 0, 1]).expect("points"),
            t.select_frames(&[3, 1]).expect("frames"),
        ] {
            assert_eq!(
                (s.frame_rate_hz(), s.precision_m()),
                (Some(100.0), Some(1e-4))
            );
        }
        for (bad, name) in [
            (sample().with_precision(0.0), "precision_m"),
            (sample().with_precision(f64::NAN), "precision_m"),
            (sample().with_frame_rate(-1.0), "frame_rate_hz"),
        ] {
            assert!(
                matches!(&bad, Err(Error::InvalidParameter { name: n, .. }) if n == name),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn get_hides_nan_and_counts_visibility() {
        let t = sample();
        assert_eq!(t.get(1, 2), None);
        assert_eq!(t.get(0, 1), Some(Point3::new(0.03, 0.04, 0.05)));
        assert_eq!(t.get(9, 0), None, "out of range is None, not a panic");
        assert_eq!(t.visible_count(2), 3);
        let counts = t.visible_counts();
        assert_eq!(counts.len(), t.n_points());
        for (i, &c) in counts.iter().enumerate() {
            assert_eq!(c, t.visible_count(i), "point {i}");
        }
        assert!((t.occluded_fraction() - 1.0 / 12.0).abs() < 1e-12);
    }

    #[test]
    fn select_frames_and_map_points_keep_occlusion() {
        let t = sample();
        let s = t.select_frames(&[3, 1]).expect("select");
        assert_eq!(s.n_frames(), 2);
        assert_eq!(s.get(0, 0), t.get(3, 0));
        assert_eq!(s.get(1, 2), None);
        assert!(matches!(
            t.select_frames(&[0, 7]),
            Err(Error::InvalidParameter { .. })
        ));
        assert!(matches!(
            t.select_frames(&[0]),
            Err(Error::TooFewFrames { .. })
        ));
        let mm = t
            .map_points(|p| Point3::from(p.coords * 1000.0))
            .expect("scale");
        assert_eq!(mm.get(1, 2), None);
        let (a, b) = (
            mm.get(2, 1).expect("visible"),
            t.get(2, 1).expect("visible"),
        );
        assert!((a.coords - b.coords * 1000.0).norm() < 1e-9);
        assert!(matches!(
            t.map_points(|_| Point3::new(f64::INFINITY, 0.0, 0.0)),
            Err(Error::NonFinite { .. })
        ));
    }
}
