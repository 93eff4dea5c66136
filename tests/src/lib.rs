//! Shared helpers for the kinetree test suite.

use kinetree_core::nalgebra::{Point3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// The first `n` mechanisms of the rate test's deterministic draw
/// (`kinetree_synth::strategies::any_mechanism()` under proptest's deterministic runner: the
/// same on every run and machine).
pub fn rate_draw(n: usize) -> Vec<kinetree_synth::MechanismSpec> {
    use proptest::strategy::{Strategy, ValueTree};
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let strategy = kinetree_synth::strategies::any_mechanism();
    (0..n)
        .map(|_| strategy.new_tree(&mut runner).expect("draw").current())
        .collect()
}

/// Seed of the property tests' draws when `PROPTEST_RNG_SEED` is not set, so that every run on
/// every machine draws the same cases; set the variable to explore others.
pub const PROPERTY_SEED: u64 = 1;

/// A property test's config: `cases` cases, drawn from `PROPTEST_RNG_SEED` when it is set,
/// else from [`PROPERTY_SEED`].
pub fn property_config(cases: u32) -> proptest::test_runner::Config {
    use proptest::test_runner::{Config, RngSeed};
    let mut config = Config {
        cases,
        ..Config::default()
    };
    if matches!(config.rng_seed, RngSeed::Random) {
        config.rng_seed = RngSeed::Fixed(PROPERTY_SEED);
    }
    config
}

/// Cases per property (and draws per rate test): `PROPTEST_CASES` when set, else 64.
pub fn cases() -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(64)
}

/// Eight keypoints of one rigid 20 x 15 x 10 cm body tumbling through 2 rad about a fixed
/// axis over `frames` frames, 1.5 m in front of the camera and drifting 10 cm, with Gaussian
/// noise of std-dev `sigma_m` per coordinate drawn from `seed`. `mistrack(frame, point)` is
/// added to a keypoint before the noise (a tracking error; zero for a clean track).
///
/// Returns the `(frames, 8, 3)` coordinates, row-major, and the body's true rotation at each
/// frame.
pub fn tumbling_body(
    frames: usize,
    sigma_m: f64,
    seed: u64,
    mistrack: impl Fn(usize, usize) -> Vector3<f64>,
) -> (Vec<f64>, Vec<UnitQuaternion<f64>>) {
    const BODY: [[f64; 3]; 8] = [
        [0.0, 0.0, 0.0],
        [0.2, 0.0, 0.0],
        [0.0, 0.15, 0.0],
        [0.0, 0.0, 0.1],
        [0.2, 0.15, 0.0],
        [0.2, 0.0, 0.1],
        [0.0, 0.15, 0.1],
        [0.1, 0.07, 0.05],
    ];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma_m).expect("finite, non-negative sigma");
    let mut xyz = Vec::with_capacity(frames * BODY.len() * 3);
    let mut rotations = Vec::with_capacity(frames);
    for t in 0..frames {
        let s = t as f64 / frames as f64;
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.3, 1.0, 0.2).normalize() * 2.0 * s);
        for (k, p) in BODY.iter().enumerate() {
            let q = r * Point3::from(*p) + Vector3::new(0.1 * s, 0.0, 1.5) + mistrack(t, k);
            xyz.extend(q.iter().map(|v| v + noise.sample(&mut rng)));
        }
        rotations.push(r);
    }
    (xyz, rotations)
}

/// The folders of the five real C3D recordings under `experiments/real/data`.
pub const RECORDINGS: [&str; 5] = [
    "c3dorg-fullbody-triads",
    "c3dorg-qualisys-walk",
    "ktk-wheelchair-racing",
    "ktk-wheelchair-sprint",
    "ktk-tennis-serve",
];

/// `experiments/real/data/<folder>` in the repository.
pub fn real_data(folder: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../experiments/real/data")
        .join(folder)
}

/// The `.c3d` file in [`real_data`]`(folder)`.
///
/// # Panics
/// When the folder cannot be read or holds no `.c3d` file (a broken checkout).
pub fn real_c3d(folder: &str) -> std::path::PathBuf {
    std::fs::read_dir(real_data(folder))
        .expect("a data folder of experiments/real")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|e| e == "c3d"))
        .expect("a .c3d file")
}

/// The mechanisms sweep's random all-revolute tree of `n_joints` joints drawn from `seed`
/// (`kinetree_synth::random_scenario`, defaults otherwise: 200 frames at 1 mm), simulated.
pub fn revolute_tree(n_joints: usize, seed: u64) -> kinetree_synth::SynthData {
    random_tree(n_joints, 0.0, seed)
}

/// The mechanisms sweep's random tree of `n_joints` joints, `prismatic_fraction` of them
/// prismatic, drawn from `seed` (as [`revolute_tree`]), simulated.
pub fn random_tree(
    n_joints: usize,
    prismatic_fraction: f64,
    seed: u64,
) -> kinetree_synth::SynthData {
    let scenario = kinetree_synth::random_scenario(&kinetree_synth::RandomParams {
        n_joints,
        prismatic_fraction,
        tree: true,
        seed,
        ..Default::default()
    });
    kinetree_synth::simulate(&scenario).expect("simulate")
}

/// The default pipeline's model of `tracks`.
pub fn discover_default(tracks: &kinetree_core::Tracks) -> kinetree_core::Model {
    discover_with(tracks, &kinetree_pipeline::PipelineConfig::default())
}

/// The model of `tracks` by the pipeline of `config`.
pub fn discover_with(
    tracks: &kinetree_core::Tracks,
    config: &kinetree_pipeline::PipelineConfig,
) -> kinetree_core::Model {
    kinetree_pipeline::Pipeline::from_config(config)
        .expect("pipeline")
        .run(tracks)
        .expect("discover")
        .model
}

/// Whether `model` carries a warning `matches` accepts.
pub fn warned(
    model: &kinetree_core::Model,
    matches: impl Fn(&kinetree_core::Warning) -> bool,
) -> bool {
    model.warnings.iter().any(matches)
}

/// Whether `joint` of `model` is typed as a ball may be: spherical or universal, or revolute
/// with a `joint_not_identifiable` warning that names the spherical type.
pub fn typed_as_ball(model: &kinetree_core::Model, joint: &kinetree_core::model::Joint) -> bool {
    use kinetree_core::model::JointType;
    matches!(
        joint.joint_type,
        JointType::Spherical | JointType::Universal
    ) || (joint.joint_type == JointType::Revolute
        && warned(model, |w| {
            matches!(w, kinetree_core::Warning::JointNotIdentifiable { child, alternatives, .. }
                    if *child == joint.child && alternatives.contains(&JointType::Spherical))
        }))
}

/// Hand-built mechanisms: box bodies, joints, sine trajectories, a fixed scene.
pub mod build {
    /// A box body of `points` interior keypoints.
    pub fn body(centre: [f64; 3], half: [f64; 3], points: usize) -> kinetree_synth::BodySpec {
        kinetree_synth::BodySpec {
            name: String::new(),
            shape: kinetree_synth::BoxShape {
                centre,
                half_extents: half,
            },
            skip_corners: (0..8).collect(),
            extra_points: 0,
            interior_points: points,
            marked_points: Vec::new(),
        }
    }

    /// A revolute (or prismatic) joint from `parent` to `child`.
    pub fn joint(
        parent: usize,
        child: usize,
        revolute: bool,
        axis: [f64; 3],
        anchor: [f64; 3],
    ) -> kinetree_synth::JointSpec {
        kinetree_synth::JointSpec {
            parent,
            child,
            joint_type: if revolute {
                kinetree_synth::JointType::Revolute
            } else {
                kinetree_synth::JointType::Prismatic
            },
            axis,
            anchor,
            second_axis: None,
        }
    }

    /// A sine trajectory about zero.
    pub fn sine(amplitude: f64, frequency_hz: f64, phase_rad: f64) -> kinetree_synth::Trajectory {
        kinetree_synth::Trajectory::Sine {
            offset: 0.0,
            amplitude,
            frequency_hz,
            phase_rad,
        }
    }

    /// 200 frames at 30 Hz, a fixed camera, 10 % dropout, seed 3.
    pub fn scenario(
        mechanism: kinetree_synth::Mechanism,
        trajectories: Vec<kinetree_synth::Trajectory>,
        noise: f64,
    ) -> kinetree_synth::Scenario {
        kinetree_synth::Scenario {
            mechanism,
            trajectories,
            n_frames: 200,
            frame_rate_hz: 30.0,
            camera: kinetree_synth::Camera::looking_at(
                [1.6, -1.8, 1.4],
                [0.0, 0.0, 0.2],
                90.0,
                80.0,
            ),
            noise_sigma_m: noise,
            dropout: 0.1,
            seed: 3,
            self_occlusion: false,
            partly_seen: Vec::new(),
            soft_tissue_m: 0.0,
        }
    }

    /// A static 8-point base slab under the origin.
    pub fn base() -> kinetree_synth::BodySpec {
        body([0.0, 0.0, -0.05], [0.25, 0.25, 0.05], 8)
    }

    /// Two links turning through one anchor about axes `tilt_deg` apart, 1 mm of noise: the
    /// second on the base beside the first (`serial` false), or on the first.
    pub fn two_links_on_one_anchor(
        tilt_deg: f64,
        serial: bool,
        seed: u64,
    ) -> kinetree_synth::SynthData {
        let t = tilt_deg.to_radians();
        let mechanism = kinetree_synth::Mechanism {
            bodies: vec![
                base(),
                body([0.15, 0.0, 0.12], [0.12, 0.03, 0.03], 8),
                body([-0.12, 0.06, 0.16], [0.1, 0.03, 0.03], 8),
            ],
            joints: vec![
                joint(0, 1, true, [0.0, 0.0, 1.0], [0.0, 0.0, 0.1]),
                joint(
                    usize::from(serial),
                    2,
                    true,
                    [t.sin(), 0.0, t.cos()],
                    [0.0, 0.0, 0.1],
                ),
            ],
        };
        let mut s = scenario(
            mechanism,
            vec![sine(0.8, 0.2, 0.0), sine(0.9, 0.33, 1.0)],
            0.001,
        );
        s.seed = seed;
        kinetree_synth::simulate(&s).expect("simulate")
    }
}

/// Whether a tree's `edges` join `from` to `to` directly or through nodes that `has_body`
/// says have no body (a segment a model lacks, which its joints may skip).
pub fn joined_across_missing<T: Copy + PartialEq>(
    edges: &[(T, T)],
    has_body: impl Fn(T) -> bool,
    from: T,
    to: T,
) -> bool {
    let mut seen = vec![from];
    let mut stack = vec![from];
    while let Some(u) = stack.pop() {
        for &(x, y) in edges {
            let next = if x == u {
                y
            } else if y == u {
                x
            } else {
                continue;
            };
            if next == to {
                return true;
            }
            if !seen.contains(&next) && !has_body(next) {
                seen.push(next);
                stack.push(next);
            }
        }
    }
    false
}
