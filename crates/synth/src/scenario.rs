//! Scenarios: a mechanism, joint trajectories, a camera, occlusion and noise, from a seed.

use crate::mechanism::Mechanism;
use kinetree_core::{Error, Result, Tracks};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// A joint's position over time; `t` in seconds from the first frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Trajectory {
    /// Constant acceleration from rest: `final_value * (t / duration)^2` (a constant torque).
    Quadratic {
        /// Position at the last frame.
        final_value: f64,
    },
    /// `offset + amplitude * sin(2 pi frequency_hz t + phase_rad)`.
    Sine {
        /// Offset.
        offset: f64,
        /// Amplitude.
        amplitude: f64,
        /// Frequency, hertz.
        frequency_hz: f64,
        /// Phase, radians.
        phase_rad: f64,
    },
}

impl Trajectory {
    /// Position at time `t` of a sequence lasting `duration` seconds.
    pub fn at(&self, t: f64, duration: f64) -> f64 {
        match *self {
            Trajectory::Quadratic { final_value } => final_value * (t / duration).powi(2),
            Trajectory::Sine {
                offset,
                amplitude,
                frequency_hz,
                phase_rad,
            } => offset + amplitude * (std::f64::consts::TAU * frequency_hz * t + phase_rad).sin(),
        }
    }
}

/// A pinhole camera looking from `eye` at `target`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Camera centre in world coordinates, metres.
    pub eye: [f64; 3],
    /// Point looked at.
    pub target: [f64; 3],
    /// World direction that appears up.
    pub up: [f64; 3],
    /// Full horizontal field of view, degrees.
    pub fov_h_deg: f64,
    /// Full vertical field of view, degrees.
    pub fov_v_deg: f64,
}

impl Camera {
    /// A camera at `eye` looking at `target` with the world's z axis up and the given full
    /// fields of view in degrees.
    pub fn looking_at(eye: [f64; 3], target: [f64; 3], fov_h_deg: f64, fov_v_deg: f64) -> Self {
        Self {
            eye,
            target,
            up: [0.0, 0.0, 1.0],
            fov_h_deg,
            fov_v_deg,
        }
    }

    /// `camera_from_world`: x right, y down, z forward (the usual computer-vision axes).
    pub fn cam_from_world(&self) -> Isometry3<f64> {
        let eye = Point3::from(self.eye);
        let target = Point3::from(self.target);
        let z = (target - eye).normalize();
        let x = z.cross(&Vector3::from(self.up)).normalize();
        let y = z.cross(&x);
        let r = nalgebra::Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
        let rot = nalgebra::UnitQuaternion::from_matrix(&r);
        let t = -(rot * eye.coords);
        Isometry3::from_parts(t.into(), rot)
    }
}

/// Everything needed to simulate one data set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    /// The mechanism.
    pub mechanism: Mechanism,
    /// One trajectory per joint coordinate (three for a spherical joint), in the order of
    /// [`Mechanism::coordinate_offsets`].
    pub trajectories: Vec<Trajectory>,
    /// Number of frames.
    pub n_frames: usize,
    /// Frame rate, hertz.
    pub frame_rate_hz: f64,
    /// The camera.
    pub camera: Camera,
    /// Per-coordinate Gaussian noise std-dev, metres.
    pub noise_sigma_m: f64,
    /// Extra random occlusion: the fraction of (frame, point) observations dropped, in bursts
    /// of 5 frames on average, on top of self-occlusion and the field of view.
    pub dropout: f64,
    /// Seed of every random choice.
    pub seed: u64,
    /// Whether bodies hide points behind them (ray casting against every box). Without it,
    /// only the field of view and `dropout` hide points; keypoints may then lie inside boxes.
    #[serde(default = "default_true")]
    pub self_occlusion: bool,
    /// Bodies seen only in part of the frames (a link buried between its neighbours): outside
    /// their windows, every keypoint of the body is hidden, on top of the other occlusion.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub partly_seen: Vec<PartlySeen>,
    /// Soft-tissue artefact: every keypoint drifts from its place on its body by a slow
    /// offset, each coordinate (in the body's frame) a sum of two sines of 0.1-0.5 Hz whose
    /// amplitudes add up to this many metres (0: keypoints rigid with their bodies).
    #[serde(default)]
    pub soft_tissue_m: f64,
}

fn default_true() -> bool {
    true
}

/// A body seen only in windows of frames ([`Scenario::partly_seen`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartlySeen {
    /// The body.
    pub body: usize,
    /// Fraction of the frames in its windows, in `[0, 1]`.
    pub fraction: f64,
    /// Number of windows (at least 1): the recording is cut into this many equal spans, and
    /// each holds one window of `fraction` of its span at a random offset.
    pub windows: usize,
}

/// One coordinate's slow drift: two sines (amplitude, frequency in hertz, phase).
type Drift = [(f64, f64, f64); 2];

/// Each keypoint's soft-tissue drift per coordinate ([`Scenario::soft_tissue_m`]), empty
/// without one. Its own random stream, so a scenario without soft tissue simulates as it
/// would without the option.
fn soft_tissue(s: &Scenario, n: usize) -> Vec<[Drift; 3]> {
    if s.soft_tissue_m <= 0.0 {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed ^ 0x50F7_715E);
    (0..n)
        .map(|_| {
            std::array::from_fn(|_| {
                let share = rng.random_range(0.3..0.7);
                let mut sine = |part: f64| {
                    (
                        s.soft_tissue_m * part,
                        rng.random_range(0.1..0.5),
                        rng.random_range(0.0..std::f64::consts::TAU),
                    )
                };
                [sine(share), sine(1.0 - share)]
            })
        })
        .collect()
}

/// A keypoint's drift at time `t`, seconds.
fn drift_at(d: &[Drift; 3], t: f64) -> Vector3<f64> {
    Vector3::from_fn(|a, _| {
        d[a].iter()
            .map(|(amp, f, ph)| amp * (std::f64::consts::TAU * f * t + ph).sin())
            .sum()
    })
}

/// Per body, whether it may be seen at each frame ([`Scenario::partly_seen`]); `None` for
/// bodies seen throughout. Its own random stream, so a scenario without such bodies simulates
/// as it would without the option.
fn seen_windows(s: &Scenario) -> Result<Vec<Option<Vec<bool>>>> {
    let mut out = vec![None; s.mechanism.bodies.len()];
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed ^ 0x005E_E10F_B0D1);
    for p in &s.partly_seen {
        if p.body >= out.len() || !(0.0..=1.0).contains(&p.fraction) || p.windows == 0 {
            return Err(Error::Config(format!(
                "partly_seen: body {} of {}, fraction {} (must be in [0, 1]), windows {} (at \
                 least 1)",
                p.body,
                out.len(),
                p.fraction,
                p.windows
            )));
        }
        let mut seen = vec![false; s.n_frames];
        let w = p.windows.min(s.n_frames.max(1));
        for k in 0..w {
            let (start, end) = (k * s.n_frames / w, (k + 1) * s.n_frames / w);
            let span = end - start;
            let len = ((p.fraction * span as f64).round() as usize).min(span);
            let offset = if span > len {
                rng.random_range(0..=span - len)
            } else {
                0
            };
            seen[start + offset..start + offset + len].fill(true);
        }
        out[p.body] = Some(seen);
    }
    Ok(out)
}

/// The truth behind a simulated data set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundTruth {
    /// Body of every keypoint.
    pub point_body: Vec<usize>,
    /// Joint coordinates, `[coordinate][frame]`, laid out by
    /// [`Mechanism::coordinate_offsets`]: one row per revolute or prismatic joint (its
    /// position), three per spherical joint (its rotation vector).
    pub joint_positions: Vec<Vec<f64>>,
    /// The mechanism.
    pub mechanism: Mechanism,
    /// `camera_from_world`.
    pub cam_from_world: Isometry3<f64>,
    /// Fraction of observations occluded.
    pub occluded_fraction: f64,
    /// Frames in which each keypoint is visible.
    pub visible_frames: Vec<usize>,
    /// Frames in which each keypoint, in view, is hidden behind another body.
    pub occluded_by_other_body: Vec<usize>,
    /// Every keypoint in its body's frame (the world frame at the zero configuration),
    /// metres.
    pub body_points: Vec<Point3<f64>>,
}

impl GroundTruth {
    /// Joint `j`'s unit axis in the camera frame at `frame`.
    pub fn axis_in_camera(&self, j: usize, frame: usize) -> Vector3<f64> {
        let q: Vec<f64> = self.joint_positions.iter().map(|p| p[frame]).collect();
        let poses = self.mechanism.forward(&q);
        let spec = &self.mechanism.joints[j];
        (self.cam_from_world * poses[spec.parent] * Vector3::from(spec.axis)).normalize()
    }

    /// A point on joint `j`'s axis in the camera frame at `frame`.
    pub fn anchor_in_camera(&self, j: usize, frame: usize) -> Point3<f64> {
        let q: Vec<f64> = self.joint_positions.iter().map(|p| p[frame]).collect();
        let poses = self.mechanism.forward(&q);
        let spec = &self.mechanism.joints[j];
        self.cam_from_world * poses[spec.parent] * Point3::from(spec.anchor)
    }

    /// The positions of joint `j` when it has one coordinate (revolute or prismatic), by
    /// frame; `None` for a spherical joint or a joint that does not exist.
    pub fn single_positions(&self, j: usize) -> Option<&Vec<f64>> {
        let spec = self.mechanism.joints.get(j)?;
        (spec.joint_type.n_coordinates() == 1)
            .then(|| {
                self.joint_positions
                    .get(self.mechanism.coordinate_offsets()[j])
            })
            .flatten()
    }

    /// Number of bodies.
    pub fn n_bodies(&self) -> usize {
        self.mechanism.bodies.len()
    }
}

/// A simulated data set.
#[derive(Debug, Clone)]
pub struct SynthData {
    /// Noisy, occluded keypoint tracks in the camera frame.
    pub tracks: Tracks,
    /// The truth.
    pub truth: GroundTruth,
}

/// Keypoints of every body (world coordinates at zero configuration) and their body.
fn keypoints(m: &Mechanism, rng: &mut ChaCha8Rng) -> (Vec<Point3<f64>>, Vec<usize>) {
    let mut pts = Vec::new();
    let mut body = Vec::new();
    for (b, spec) in m.bodies.iter().enumerate() {
        for (k, c) in spec.shape.corners().iter().enumerate() {
            if !spec.skip_corners.contains(&k) {
                pts.push(*c);
                body.push(b);
            }
        }
        let h = Vector3::from(spec.shape.half_extents);
        for _ in 0..spec.extra_points {
            // A random point on a random face.
            let axis = rng.random_range(0..3);
            let mut u = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            u[axis] = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            pts.push(Point3::from(
                Vector3::from(spec.shape.centre) + u.component_mul(&h),
            ));
            body.push(b);
        }
        for _ in 0..spec.interior_points {
            let u = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            pts.push(Point3::from(
                Vector3::from(spec.shape.centre) + u.component_mul(&h),
            ));
            body.push(b);
        }
        for p in &spec.marked_points {
            pts.push(Point3::from(*p));
            body.push(b);
        }
    }
    (pts, body)
}

/// Simulates a scenario: forward kinematics, visibility by ray casting against every box and
/// the field of view, burst dropout, then Gaussian noise.
///
/// # Errors
/// [`Error::Config`] for an invalid mechanism or mismatched trajectories, and the errors of
/// [`Tracks::new`] (for example when nothing is visible).
pub fn simulate(s: &Scenario) -> Result<SynthData> {
    s.mechanism.validate()?;
    let n_coordinates = s.mechanism.n_coordinates();
    if s.trajectories.len() != n_coordinates {
        return Err(Error::Config(format!(
            "{} joints need {} trajectories (one per coordinate), found {}",
            s.mechanism.joints.len(),
            n_coordinates,
            s.trajectories.len()
        )));
    }
    if !(s.frame_rate_hz > 0.0 && s.noise_sigma_m >= 0.0 && (0.0..1.0).contains(&s.dropout)) {
        return Err(Error::Config(
            "frame_rate_hz must be > 0, noise_sigma_m >= 0 and dropout in [0, 1)".into(),
        ));
    }
    if !(s.soft_tissue_m.is_finite() && (0.0..=1.0).contains(&s.soft_tissue_m)) {
        return Err(Error::Config(format!(
            "soft_tissue_m must be in [0, 1] m, got {}",
            s.soft_tissue_m
        )));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
    let (pts, point_body) = keypoints(&s.mechanism, &mut rng);
    let n = pts.len();
    let drift = soft_tissue(s, n);
    let duration = (s.n_frames.max(2) - 1) as f64 / s.frame_rate_hz;
    let joint_positions: Vec<Vec<f64>> = s
        .trajectories
        .iter()
        .map(|tr| {
            (0..s.n_frames)
                .map(|k| tr.at(k as f64 / s.frame_rate_hz, duration))
                .collect()
        })
        .collect();
    let cam = s.camera.cam_from_world();
    let eye = Point3::from(s.camera.eye);
    let (tan_h, tan_v) = (
        (s.camera.fov_h_deg.to_radians() / 2.0).tan(),
        (s.camera.fov_v_deg.to_radians() / 2.0).tan(),
    );
    let noise = Normal::new(0.0, s.noise_sigma_m.max(0.0))
        .map_err(|e| Error::Config(format!("noise: {e}")))?;
    let p_exit = 0.2;
    let p_enter = if s.dropout > 0.0 {
        (s.dropout * p_exit / (1.0 - s.dropout)).min(1.0)
    } else {
        0.0
    };
    let mut dropped = vec![false; n];
    for d in &mut dropped {
        *d = rng.random_bool(s.dropout);
    }
    let windows = seen_windows(s)?;
    let mut frames = Vec::with_capacity(s.n_frames);
    let mut occluded_by_other_body = vec![0usize; n];
    for k in 0..s.n_frames {
        let q: Vec<f64> = joint_positions.iter().map(|p| p[k]).collect();
        let poses = s.mechanism.forward(&q);
        let body_from_world: Vec<Isometry3<f64>> = poses.iter().map(|p| p.inverse()).collect();
        let mut frame = Vec::with_capacity(n);
        for i in 0..n {
            if k > 0 {
                let flip = if dropped[i] { p_exit } else { p_enter };
                if rng.random_bool(flip) {
                    dropped[i] = !dropped[i];
                }
            }
            let t = k as f64 / s.frame_rate_hz;
            let moved = pts[i] + drift.get(i).map_or(Vector3::zeros(), |d| drift_at(d, t));
            let world = poses[point_body[i]] * moved;
            let pc = cam * world;
            let in_view =
                pc.z > 1e-6 && (pc.x / pc.z).abs() <= tan_h && (pc.y / pc.z).abs() <= tan_v;
            let hides = |b: usize| {
                let o = body_from_world[b] * eye;
                let d = body_from_world[b] * world - o;
                s.mechanism.bodies[b]
                    .shape
                    .segment_entry(&o, &d, 1e-7)
                    .is_some_and(|e| e < 1.0 - 1e-9)
            };
            let own = point_body[i];
            let by_other = in_view
                && s.self_occlusion
                && (0..s.mechanism.bodies.len()).any(|b| b != own && hides(b));
            let occluded = by_other || (in_view && s.self_occlusion && hides(own));
            if by_other {
                occluded_by_other_body[i] += 1;
            }
            let noisy = Point3::new(
                pc.x + noise.sample(&mut rng),
                pc.y + noise.sample(&mut rng),
                pc.z + noise.sample(&mut rng),
            );
            let in_window = windows[own].as_ref().is_none_or(|w| w[k]);
            frame.push((in_view && !occluded && !dropped[i] && in_window).then_some(noisy));
        }
        frames.push(frame);
    }
    let tracks = Tracks::from_points(&frames)?.with_frame_rate(s.frame_rate_hz)?;
    let occluded_fraction = tracks.occluded_fraction();
    let visible_frames = tracks.visible_counts();
    Ok(SynthData {
        tracks,
        truth: GroundTruth {
            point_body,
            joint_positions,
            mechanism: s.mechanism.clone(),
            cam_from_world: cam,
            occluded_fraction,
            visible_frames,
            occluded_by_other_body,
            body_points: pts,
        },
    })
}

/// Axis-angle helper for random unit vectors.
pub(crate) fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let n = v.norm();
        if n > 0.2 && n <= 1.0 {
            return v / n;
        }
    }
}
