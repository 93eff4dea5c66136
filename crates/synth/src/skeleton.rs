//! A human-like skeleton: a static or floating pelvis with a spine and head, arms and legs, ball joints at
//! the spine, neck, shoulders, wrists, hips and ankles, hinges at the elbows and knees, and
//! markers on the segments' surfaces.

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, Scenario, Trajectory};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Parameters of [`skeleton_scenario`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SkeletonParams {
    /// Markers on each segment's surface.
    pub markers_per_segment: usize,
    /// Least and most range of motion of each joint, degrees: a hinge's full swing, a ball
    /// joint's swing about each of its axes.
    pub motion_deg: [f64; 2],
    /// Number of frames.
    pub n_frames: usize,
    /// Frame rate, hertz.
    pub frame_rate_hz: f64,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Random occlusion (see [`Scenario::dropout`]); segments do not hide each other, as in
    /// a many-camera motion-capture room.
    pub dropout: f64,
    /// Seed.
    pub seed: u64,
    /// Wrists and ankles as universal joints instead of ball joints: flexion about the
    /// medio-lateral axis (fixed in the forearm or shank), then deviation about the
    /// antero-posterior axis (fixed in the hand or foot).
    pub universal_wrists_and_ankles: bool,
    /// The pelvis floats: it moves freely (a `Free` joint from an unseen world body, body 0),
    /// so no body is static, as in a recording of a walking person.
    pub floating_pelvis: bool,
    /// A clinical marker set instead of `markers_per_segment` markers on every segment:
    /// four markers on the pelvis, torso and head, two on each limb segment, and two on each
    /// elbow's and knee's axis (the epicondyles, carried by the upper arm or thigh and rigid
    /// with the forearm or shank too) and on each wrist's and ankle's first axis (the
    /// styloids and malleoli, carried by the forearm or shank).
    pub clinical_markers: bool,
    /// A sparse marker set as Plug-in Gait places one (not with `clinical_markers`): four
    /// markers on the pelvis, torso and head, one on each upper arm, forearm, thigh and
    /// shank, two on each hand and foot, and one on each elbow's, knee's, wrist's and
    /// ankle's (first) axis, carried by the segment above. A limb segment then shows two
    /// markers at most, one of them rigid with the segment below as well, so some segments
    /// make no body and the tree joins their neighbours across them.
    pub plug_in_gait_markers: bool,
    /// Soft-tissue artefact, metres: each marker drifts from its place on its segment by a
    /// slow offset of at most this much per coordinate ([`Scenario::soft_tissue_m`]).
    pub soft_tissue_m: f64,
    /// Markers on a static object beside a floating subject (a box on the floor, as the
    /// blocks of a sprint start or a force plate's corners): the world (body 0) then carries
    /// them and is seen and static, while the pelvis still moves freely in it. 0 (default)
    /// leaves the world unseen; more needs `floating_pelvis`.
    pub scene_markers: usize,
}

impl Default for SkeletonParams {
    fn default() -> Self {
        Self {
            markers_per_segment: 6,
            motion_deg: [30.0, 90.0],
            n_frames: 300,
            frame_rate_hz: 30.0,
            noise_sigma_m: 0.001,
            dropout: 0.2,
            seed: 0,
            universal_wrists_and_ankles: false,
            floating_pelvis: false,
            clinical_markers: false,
            plug_in_gait_markers: false,
            soft_tissue_m: 0.0,
            scene_markers: 0,
        }
    }
}

impl SkeletonParams {
    /// Checks the ranges: 3 to 1000 markers a segment, a motion range within 1-170 deg
    /// (least first), 2 to 1 000 000 frames, a positive frame rate, noise from 0 to 1 m, a
    /// dropout in `[0, 1)`, a soft-tissue artefact from 0 to 0.1 m, at most 1000 scene
    /// markers and only with a floating pelvis.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count(
            "data.markers_per_segment",
            self.markers_per_segment,
            3,
            1000,
        )?;
        check_within("data.motion_deg", self.motion_deg[0], 1.0, 170.0)?;
        check_within(
            "data.motion_deg",
            self.motion_deg[1],
            self.motion_deg[0],
            170.0,
        )?;
        check_count("data.n_frames", self.n_frames, 2, 1_000_000)?;
        check_within("data.frame_rate_hz", self.frame_rate_hz, 1e-3, 1e6)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 0.99)?;
        check_within("data.soft_tissue_m", self.soft_tissue_m, 0.0, 0.1)?;
        check_count("data.scene_markers", self.scene_markers, 0, 1000)?;
        if self.plug_in_gait_markers && self.clinical_markers {
            return Err(kinetree_core::Error::InvalidParameter {
                name: "data.plug_in_gait_markers".into(),
                message: "is a marker set of its own: not with data.clinical_markers".into(),
            });
        }
        if self.scene_markers > 0 && !self.floating_pelvis {
            return Err(kinetree_core::Error::InvalidParameter {
                name: "data.scene_markers".into(),
                message: "needs data.floating_pelvis: the scene is the world the pelvis moves in"
                    .into(),
            });
        }
        Ok(())
    }
}

/// One segment: its name, the joint that carries it (parent segment, type, centre or a point
/// on the hinge axis, hinge axis), and its box, all in metres, standing upright (z up, the
/// person facing -y, left at +x).
struct Segment {
    name: &'static str,
    parent: usize,
    joint: JointType,
    centre: [f64; 3],
    axis: [f64; 3],
    box_centre: [f64; 3],
    half: [f64; 3],
}

const fn segment(
    name: &'static str,
    parent: usize,
    joint: JointType,
    centre: [f64; 3],
    box_centre: [f64; 3],
    half: [f64; 3],
) -> Segment {
    Segment {
        name,
        parent,
        joint,
        centre,
        axis: [1.0, 0.0, 0.0],
        box_centre,
        half,
    }
}

const BALL: JointType = JointType::Spherical;
const HINGE: JointType = JointType::Revolute;

/// The segments after the pelvis (body 0), parents first. Elbows and knees are hinges about
/// the medio-lateral axis.
const SEGMENTS: [Segment; 14] = [
    segment(
        "torso",
        0,
        BALL,
        [0.0, 0.0, 1.1],
        [0.0, 0.0, 1.33],
        [0.15, 0.1, 0.2],
    ),
    segment(
        "head",
        1,
        BALL,
        [0.0, 0.0, 1.58],
        [0.0, 0.0, 1.71],
        [0.08, 0.09, 0.11],
    ),
    segment(
        "upper_arm_l",
        1,
        BALL,
        [0.2, 0.0, 1.48],
        [0.2, 0.0, 1.33],
        [0.04, 0.04, 0.13],
    ),
    segment(
        "forearm_l",
        3,
        HINGE,
        [0.2, 0.0, 1.18],
        [0.2, 0.0, 1.05],
        [0.035, 0.035, 0.11],
    ),
    segment(
        "hand_l",
        4,
        BALL,
        [0.2, 0.0, 0.92],
        [0.2, 0.0, 0.85],
        [0.04, 0.02, 0.05],
    ),
    segment(
        "upper_arm_r",
        1,
        BALL,
        [-0.2, 0.0, 1.48],
        [-0.2, 0.0, 1.33],
        [0.04, 0.04, 0.13],
    ),
    segment(
        "forearm_r",
        6,
        HINGE,
        [-0.2, 0.0, 1.18],
        [-0.2, 0.0, 1.05],
        [0.035, 0.035, 0.11],
    ),
    segment(
        "hand_r",
        7,
        BALL,
        [-0.2, 0.0, 0.92],
        [-0.2, 0.0, 0.85],
        [0.04, 0.02, 0.05],
    ),
    segment(
        "thigh_l",
        0,
        BALL,
        [0.1, 0.0, 0.92],
        [0.1, 0.0, 0.71],
        [0.06, 0.06, 0.18],
    ),
    segment(
        "shank_l",
        9,
        HINGE,
        [0.1, 0.0, 0.5],
        [0.1, 0.0, 0.3],
        [0.045, 0.045, 0.18],
    ),
    segment(
        "foot_l",
        10,
        BALL,
        [0.1, 0.0, 0.08],
        [0.1, -0.05, 0.035],
        [0.045, 0.1, 0.03],
    ),
    segment(
        "thigh_r",
        0,
        BALL,
        [-0.1, 0.0, 0.92],
        [-0.1, 0.0, 0.71],
        [0.06, 0.06, 0.18],
    ),
    segment(
        "shank_r",
        12,
        HINGE,
        [-0.1, 0.0, 0.5],
        [-0.1, 0.0, 0.3],
        [0.045, 0.045, 0.18],
    ),
    segment(
        "foot_r",
        13,
        BALL,
        [-0.1, 0.0, 0.08],
        [-0.1, -0.05, 0.035],
        [0.045, 0.1, 0.03],
    ),
];

/// A skeleton of 15 segments (the pelvis static or floating, 10 ball joints and 4 hinges, or 6 ball
/// joints, 4 universal joints and 4 hinges) with
/// `markers_per_segment` markers at random places on each segment's box surface, seen by a
/// camera 4 m in front.
///
/// Motion: every coordinate follows its own sine with a frequency of 0.1-0.4 Hz and a random
/// phase. A hinge swings through a range drawn from `motion_deg` (flexion from near straight);
/// a ball joint's rotation vector, and each of a universal joint's angles, has each component
/// swing through such a range about zero. A floating pelvis turns about the vertical through
/// such a range and tilts through a third of one, and it moves 0.2-1 m forward and sideways
/// and 2-10 cm up and down; the world it moves in (body 0) has no markers, or
/// `scene_markers` on a 30 x 20 x 10 cm box on the floor 0.8 m ahead and to the left.
pub fn skeleton_scenario(p: &SkeletonParams) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let markers = |centre: [f64; 3], half: [f64; 3]| BodySpec {
        name: String::new(),
        shape: BoxShape {
            centre,
            half_extents: half,
        },
        skip_corners: (0..8).collect(),
        extra_points: if p.clinical_markers {
            2
        } else if p.plug_in_gait_markers {
            1
        } else {
            p.markers_per_segment
        },
        interior_points: 0,
        marked_points: Vec::new(),
    };
    let pelvis_centre = [0.0, 0.0, 1.0];
    // The trunk's segments carry four markers in a clinical set.
    let trunk = |b: BodySpec| BodySpec {
        extra_points: if p.clinical_markers || p.plug_in_gait_markers {
            4
        } else {
            b.extra_points
        },
        ..b
    };
    let mut bodies = vec![trunk(BodySpec {
        name: "pelvis".into(),
        ..markers(pelvis_centre, [0.15, 0.1, 0.08])
    })];
    let mut joints = Vec::new();
    let mut trajectories = Vec::new();
    let [least, most] = p.motion_deg.map(f64::to_radians);
    // The first segment's body id: 1, or 2 below a floating pelvis.
    let first = usize::from(p.floating_pelvis) + 1;
    if p.floating_pelvis {
        bodies.insert(
            0,
            if p.scene_markers > 0 {
                BodySpec {
                    name: "scene".into(),
                    extra_points: p.scene_markers,
                    ..markers([0.8, -0.8, 0.05], [0.15, 0.1, 0.05])
                }
            } else {
                BodySpec {
                    name: "world".into(),
                    extra_points: 0,
                    ..markers([0.0; 3], [0.01; 3])
                }
            },
        );
        joints.push(JointSpec {
            parent: 0,
            child: 1,
            joint_type: JointType::Free,
            axis: [0.0, 0.0, 1.0],
            anchor: pelvis_centre,
            second_axis: None,
        });
        // Translation x, y, z, then the rotation vector's x, y, z.
        let ranges = [
            rng.random_range(0.2..=1.0),
            rng.random_range(0.2..=1.0),
            rng.random_range(0.02..=0.1),
            rng.random_range(least..=most) / 3.0,
            rng.random_range(least..=most) / 3.0,
            rng.random_range(least..=most),
        ];
        for range in ranges {
            trajectories.push(Trajectory::Sine {
                offset: 0.0,
                amplitude: range / 2.0,
                frequency_hz: rng.random_range(0.1..0.4),
                phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
            });
        }
    }
    for (k, s) in SEGMENTS.iter().enumerate() {
        let distal = s.name.starts_with("hand") || s.name.starts_with("foot");
        let mut body = BodySpec {
            name: s.name.into(),
            ..markers(s.box_centre, s.half)
        };
        if p.plug_in_gait_markers && distal {
            body.extra_points = 2;
        }
        bodies.push(if s.name == "torso" || s.name == "head" {
            trunk(body)
        } else {
            body
        });
        // Markers on the joint's (first) axis, on the skin, carried by the parent segment:
        // both sides in a clinical set, one in Plug-in Gait's.
        let reach = s.half[0] + 0.01;
        let on_axis = |sign: f64| std::array::from_fn(|a| s.centre[a] + sign * reach * s.axis[a]);
        let on_axes = &mut bodies[s.parent + first - 1].marked_points;
        if p.clinical_markers && (s.joint == HINGE || distal) {
            on_axes.extend([on_axis(-1.0), on_axis(1.0)]);
        }
        if p.plug_in_gait_markers && (s.joint == HINGE || distal) {
            on_axes.push(on_axis(1.0));
        }
        let joint_type = if distal && p.universal_wrists_and_ankles {
            JointType::Universal
        } else {
            s.joint
        };
        joints.push(JointSpec {
            parent: s.parent + first - 1,
            child: k + first,
            joint_type,
            axis: s.axis,
            anchor: s.centre,
            second_axis: (joint_type == JointType::Universal).then_some([0.0, 1.0, 0.0]),
        });
        for _ in 0..joint_type.n_coordinates() {
            let range = rng.random_range(least..=most);
            let offset = if s.joint == HINGE {
                // Flexion: from near straight to bent (elbows forward, knees backward).
                let sign = if s.name.starts_with("shank") {
                    1.0
                } else {
                    -1.0
                };
                sign * (0.1 + range / 2.0)
            } else {
                0.0
            };
            trajectories.push(Trajectory::Sine {
                offset,
                amplitude: range / 2.0,
                frequency_hz: rng.random_range(0.1..0.4),
                phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
            });
        }
    }
    Scenario {
        mechanism: Mechanism { bodies, joints },
        trajectories,
        n_frames: p.n_frames,
        frame_rate_hz: p.frame_rate_hz,
        camera: Camera::looking_at([0.5, -4.0, 1.2], [0.0, 0.0, 0.9], 90.0, 80.0),
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
        self_occlusion: false,
        partly_seen: Vec::new(),
        soft_tissue_m: p.soft_tissue_m,
    }
}
