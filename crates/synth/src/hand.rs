//! A human-like hand: a palm, four fingers of three phalanges and a thumb of three links,
//! links of 1.2-2.5 cm with keypoints on the surfaces a camera sees, universal joints
//! (flexion, then abduction) at the knuckles and the thumb's base, or small knuckle bodies
//! between an abduction and a flexion hinge, and hinges between phalanges.

use crate::mechanism::{BodySpec, BoxShape, JointSpec, JointType, Mechanism};
use crate::scenario::{Camera, Scenario, Trajectory};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Parameters of [`hand_scenario`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HandParams {
    /// Keypoints on each link's surface (the palm has twice as many).
    pub keypoints_per_link: usize,
    /// Least and most flexion range of each joint, degrees; abduction swings through a
    /// quarter of it.
    pub motion_deg: [f64; 2],
    /// Number of frames.
    pub n_frames: usize,
    /// Per-coordinate noise, metres.
    pub noise_sigma_m: f64,
    /// Random occlusion (see [`Scenario::dropout`]); links also hide each other.
    pub dropout: f64,
    /// Whether each finger's knuckle is a small body (7 x 4 x 2.5 mm) between an abduction
    /// hinge on the palm and a flexion hinge to the finger, as in robot hands, instead of one
    /// universal joint: 20 bodies instead of 16.
    pub knuckle_bodies: bool,
    /// Seed.
    pub seed: u64,
}

impl Default for HandParams {
    fn default() -> Self {
        Self {
            keypoints_per_link: 8,
            motion_deg: [30.0, 90.0],
            n_frames: 300,
            noise_sigma_m: 0.001,
            dropout: 0.2,
            knuckle_bodies: false,
            seed: 0,
        }
    }
}

impl HandParams {
    /// Checks the ranges: 3 to 1000 keypoints a link, a motion range within 1-170 deg (least
    /// first), 2 to 1 000 000 frames, noise from 0 to 1 m, a dropout in `[0, 0.99]`.
    ///
    /// # Errors
    /// [`kinetree_core::Error::InvalidParameter`] naming `data.<parameter>`.
    pub fn validate(&self) -> kinetree_core::Result<()> {
        use kinetree_core::limits::{check_count, check_within};
        check_count("data.keypoints_per_link", self.keypoints_per_link, 3, 1000)?;
        check_within("data.motion_deg", self.motion_deg[0], 1.0, 170.0)?;
        check_within(
            "data.motion_deg",
            self.motion_deg[1],
            self.motion_deg[0],
            170.0,
        )?;
        check_count("data.n_frames", self.n_frames, 2, 1_000_000)?;
        check_within("data.noise_sigma_m", self.noise_sigma_m, 0.0, 1.0)?;
        check_within("data.dropout", self.dropout, 0.0, 0.99)
    }
}

/// Lengths of a finger's three links, proximal first, metres, and the knuckle's x on the
/// palm's top edge (index to little finger), then the thumb's.
const FINGERS: [(f64, [f64; 3]); 4] = [
    (0.027, [0.025, 0.016, 0.012]),
    (0.009, [0.025, 0.018, 0.013]),
    (-0.009, [0.024, 0.017, 0.012]),
    (-0.027, [0.02, 0.014, 0.012]),
];
const THUMB: [f64; 3] = [0.025, 0.02, 0.015];

/// Half extents of a knuckle body, metres: the 7 x 4 x 2.5 mm of a robot hand's knuckle.
const KNUCKLE_HALF: [f64; 3] = [0.0035, 0.002, 0.00125];

/// A static palm (8 x 2 x 9 cm, in the x-z plane, fingers pointing up +z) with four fingers
/// and a thumb: 16 bodies, 15 joints. Each finger's knuckle is a universal joint, flexion
/// about the palm's x axis then abduction about the finger's y axis (normal to the palm), and
/// its two other joints are hinges about x; the thumb leaves the palm's side along +x with a
/// universal joint at its base (about z, then y) and two hinges about z. With
/// `knuckle_bodies`, each finger's universal joint becomes an abduction hinge (about y) to a
/// knuckle body and a flexion hinge (about x) from it, both through the same point: 20 bodies.
/// Links are 1.6 cm wide and 1.4 cm thick; a camera 60 cm in front of the palm.
///
/// Keypoints: `keypoints_per_link` on each link (twice as many on the palm), on the faces
/// that look toward the camera at the rest pose, area-weighted: a point tracker started on a
/// view of the hand follows points of the surface that view shows. They are drawn from their
/// own random stream.
///
/// Motion: every coordinate follows its own sine at 0.1-0.4 Hz with a random phase: a flexion
/// from straight through a range drawn from `motion_deg`, an abduction about zero through a
/// quarter of one.
pub fn hand_scenario(p: &HandParams) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut point_rng = ChaCha8Rng::seed_from_u64(p.seed ^ 0x6b65_7970_6f69_6e74);
    let camera = Camera::looking_at([0.1, -0.6, 0.15], [0.0, 0.0, 0.05], 60.0, 50.0);
    let mut link = |name: String, centre: [f64; 3], half: [f64; 3], points: usize| BodySpec {
        name,
        shape: BoxShape {
            centre,
            half_extents: half,
        },
        skip_corners: (0..8).collect(),
        extra_points: 0,
        interior_points: 0,
        marked_points: facing_points(&mut point_rng, centre, half, camera.eye, points),
    };
    let mut bodies = vec![link(
        "palm".into(),
        [0.0, 0.0, 0.0],
        [0.04, 0.01, 0.045],
        2 * p.keypoints_per_link,
    )];
    let mut joints = Vec::new();
    let mut trajectories = Vec::new();
    let [least, most] = p.motion_deg.map(f64::to_radians);
    let swing = |rng: &mut ChaCha8Rng, flexion: bool| {
        let range = rng.random_range(least..=most) * if flexion { 1.0 } else { 0.25 };
        Trajectory::Sine {
            offset: if flexion { range / 2.0 } else { 0.0 },
            amplitude: range / 2.0,
            frequency_hz: rng.random_range(0.1..0.4),
            phase_rad: rng.random_range(0.0..std::f64::consts::TAU),
        }
    };
    let (half_w, half_t) = (0.008, 0.007);
    // A finger or the thumb: links from `start` along the x or z axis (`along`), each turning
    // about `flexion`; the first on a universal joint whose second axis is y, or, with
    // `knuckle`, on a knuckle body between a hinge about y and one about `flexion`.
    let mut chain = |rng: &mut ChaCha8Rng,
                     bodies: &mut Vec<BodySpec>,
                     link: &mut dyn FnMut(String, [f64; 3], [f64; 3], usize) -> BodySpec,
                     name: &str,
                     start: [f64; 3],
                     along: usize,
                     lengths: &[f64],
                     flexion: [f64; 3],
                     knuckle: bool| {
        let mut at = start;
        let mut parent = 0;
        if knuckle {
            // The knuckle sits on the palm's edge, the finger starts beyond it.
            let mut centre = at;
            centre[along] += KNUCKLE_HALF[along];
            bodies.push(link(
                format!("{name}_knuckle"),
                centre,
                KNUCKLE_HALF,
                p.keypoints_per_link,
            ));
            let child = bodies.len() - 1;
            at[along] += KNUCKLE_HALF[along];
            joints.push(JointSpec {
                parent,
                child,
                joint_type: JointType::Revolute,
                axis: [0.0, 1.0, 0.0],
                anchor: at,
                second_axis: None,
            });
            trajectories.push(swing(rng, false));
            parent = child;
            at[along] += KNUCKLE_HALF[along];
        }
        for (k, len) in lengths.iter().enumerate() {
            let mut centre = at;
            centre[along] += 0.001 + len / 2.0;
            let mut half = [half_w, half_t, half_w];
            half[along] = len / 2.0;
            bodies.push(link(
                format!("{name}_{}", k + 1),
                centre,
                half,
                p.keypoints_per_link,
            ));
            let child = bodies.len() - 1;
            let universal = k == 0 && !knuckle;
            // A knuckle body's flexion turns about the point its abduction does.
            let mut anchor = at;
            if k == 0 && knuckle {
                anchor[along] -= KNUCKLE_HALF[along];
            }
            joints.push(JointSpec {
                parent,
                child,
                joint_type: if universal {
                    JointType::Universal
                } else {
                    JointType::Revolute
                },
                axis: flexion,
                anchor,
                second_axis: universal.then_some([0.0, 1.0, 0.0]),
            });
            trajectories.push(swing(rng, true));
            if universal {
                trajectories.push(swing(rng, false));
            }
            parent = child;
            at[along] += 0.001 + len;
        }
    };
    for (f, (x, lengths)) in FINGERS.iter().enumerate() {
        chain(
            &mut rng,
            &mut bodies,
            &mut link,
            &format!("finger{}", f + 1),
            [*x, 0.0, 0.045],
            2,
            lengths,
            [1.0, 0.0, 0.0],
            p.knuckle_bodies,
        );
    }
    chain(
        &mut rng,
        &mut bodies,
        &mut link,
        "thumb",
        [0.04, 0.0, -0.015],
        0,
        &THUMB,
        [0.0, 0.0, 1.0],
        false,
    );
    Scenario {
        mechanism: Mechanism { bodies, joints },
        trajectories,
        n_frames: p.n_frames,
        frame_rate_hz: 30.0,
        camera,
        noise_sigma_m: p.noise_sigma_m,
        dropout: p.dropout,
        seed: p.seed,
        self_occlusion: true,
        partly_seen: Vec::new(),
        soft_tissue_m: 0.0,
    }
}

/// `n` points on the faces of the box (`centre`, half extents `half`) whose outward normals
/// point toward `eye`, each face drawn with probability in proportion to its area.
fn facing_points(
    rng: &mut ChaCha8Rng,
    centre: [f64; 3],
    half: [f64; 3],
    eye: [f64; 3],
    n: usize,
) -> Vec<[f64; 3]> {
    // Faces as (axis, sign, area).
    let faces: Vec<(usize, f64, f64)> = (0..3)
        .flat_map(|axis| [-1.0, 1.0].map(|sign| (axis, sign)))
        .filter(|&(axis, sign)| sign * (eye[axis] - centre[axis]) > half[axis])
        .map(|(axis, sign)| (axis, sign, half[(axis + 1) % 3] * half[(axis + 2) % 3]))
        .collect();
    let Some(&last) = faces.last() else {
        return Vec::new();
    };
    let total: f64 = faces.iter().map(|f| f.2).sum();
    (0..n)
        .map(|_| {
            let mut pick = rng.random_range(0.0..total);
            let &(axis, sign, _) = faces
                .iter()
                .find(|f| {
                    pick -= f.2;
                    pick < 0.0
                })
                .unwrap_or(&last);
            std::array::from_fn(|i| {
                centre[i]
                    + half[i]
                        * if i == axis {
                            sign
                        } else {
                            rng.random_range(-1.0..1.0)
                        }
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate;

    /// Checks that every keypoint lies on a face of its link's box that looks toward the
    /// camera.
    fn on_facing_faces(s: &Scenario, d: &crate::SynthData) {
        for (i, p) in d.truth.body_points.iter().enumerate() {
            let shape = &s.mechanism.bodies[d.truth.point_body[i]].shape;
            let on_face = (0..3).find(|&a| {
                let off = p[a] - shape.centre[a];
                (off.abs() - shape.half_extents[a]).abs() < 1e-12
                    && off * (s.camera.eye[a] - shape.centre[a]) > 0.0
            });
            assert!(
                on_face.is_some(),
                "keypoint {i} is not on a face toward the camera"
            );
            assert!(
                (0..3).all(|a| (p[a] - shape.centre[a]).abs() <= shape.half_extents[a] + 1e-12),
                "keypoint {i} is off its link"
            );
        }
    }

    #[test]
    fn a_hand_has_sixteen_links_on_universal_knuckles_and_hinges() {
        let s = hand_scenario(&HandParams::default());
        let m = &s.mechanism;
        assert_eq!((m.bodies.len(), m.joints.len()), (16, 15));
        let count = |t: JointType| m.joints.iter().filter(|j| j.joint_type == t).count();
        assert_eq!(
            (count(JointType::Universal), count(JointType::Revolute)),
            (5, 10)
        );
        assert_eq!(s.trajectories.len(), 20);
        let d = simulate(&s).expect("simulate");
        assert_eq!(d.tracks.n_points(), 16 * 8 + 8);
        on_facing_faces(&s, &d);
    }

    #[test]
    fn knuckle_bodies_split_each_finger_knuckle_into_two_hinges_through_one_point() {
        let p = HandParams {
            knuckle_bodies: true,
            ..HandParams::default()
        };
        let s = hand_scenario(&p);
        let m = &s.mechanism;
        assert_eq!((m.bodies.len(), m.joints.len()), (20, 19));
        let knuckles: Vec<usize> = (0..m.bodies.len())
            .filter(|&b| m.bodies[b].name.ends_with("_knuckle"))
            .collect();
        assert_eq!(knuckles.len(), 4);
        for &k in &knuckles {
            let into: Vec<&JointSpec> = m.joints.iter().filter(|j| j.child == k).collect();
            let out: Vec<&JointSpec> = m.joints.iter().filter(|j| j.parent == k).collect();
            assert_eq!((into.len(), out.len()), (1, 1));
            assert_eq!(into[0].parent, 0, "a knuckle hangs on the palm");
            assert_eq!(into[0].axis, [0.0, 1.0, 0.0], "abduction about y");
            assert_eq!(out[0].axis, [1.0, 0.0, 0.0], "flexion about x");
            assert_eq!(
                into[0].anchor, out[0].anchor,
                "both hinges through one point"
            );
            assert_eq!(m.bodies[k].shape.half_extents, KNUCKLE_HALF);
        }
        // Only the thumb keeps a universal joint; the coordinates match the trajectories.
        let universal = m
            .joints
            .iter()
            .filter(|j| j.joint_type == JointType::Universal);
        assert_eq!(universal.count(), 1);
        assert_eq!(s.trajectories.len(), 20);
        let d = simulate(&s).expect("simulate");
        assert_eq!(d.tracks.n_points(), 20 * 8 + 8);
        on_facing_faces(&s, &d);
    }
}
