//! Exports of a discovered model: URDF and MJCF (MuJoCo) for robotics tools and DOT for graph
//! viewers.

use kinetree_core::model::{Joint, JointType, Model};
use kinetree_core::nalgebra::{Isometry3, Rotation3, UnitQuaternion, Vector3};
use kinetree_core::{Error, Result};
use std::fmt::Write as _;

/// Link name of body `id`.
pub fn link_name(id: usize) -> String {
    format!("body{id}")
}

/// Joint name of the joint from `parent` to `child`.
pub fn joint_name(parent: usize, child: usize) -> String {
    format!("body{parent}_to_body{child}")
}

/// Text safe inside an XML comment and on one line: XML forbids `--` inside a comment and a
/// `-` just before its closing `-->`, so a space goes after every `-` that another `-` or the
/// end follows; line breaks become spaces.
fn comment_text(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\n' | '\r' => out.push(' '),
            '-' if matches!(chars.peek(), Some('-') | None) => out.push_str("- "),
            c => out.push(c),
        }
    }
    out
}

/// Text safe inside a DOT double-quoted string.
fn dot_text(s: &str) -> String {
    s.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', " ")
}

fn v3(v: &Vector3<f64>) -> String {
    format!("{} {} {}", v.x, v.y, v.z)
}

/// Where a joint's frame sits: its origin in the parent *body* frame, and the child link's
/// offset (a child body point `x` is at `x + offset` in the child link frame).
struct JointFrame {
    origin: Vector3<f64>,
    rotation: Rotation3<f64>,
    offset: Vector3<f64>,
}

/// Joint `j`'s reference pose (the child's frame in the parent's at position zero), which the
/// `format` export needs.
fn reference_pose(j: &Joint, format: &str) -> Result<Isometry3<f64>> {
    let reference = j.reference_pose.ok_or_else(|| Error::InvalidParameter {
        name: format!("joints[{} -> {}].reference_pose", j.parent, j.child),
        message: format!(
            "missing; {format} needs the child's pose in its parent (schema v1 models written \
             before it was added cannot be exported)"
        ),
    })?;
    reference
        .to_isometry()
        .ok_or_else(|| Error::InvalidParameter {
            name: "reference_pose".into(),
            message: format!("{reference:?} is not a rigid transform"),
        })
}

fn joint_frame(j: &Joint) -> Result<JointFrame> {
    let reference = reference_pose(j, "URDF")?;
    let r = reference.rotation.to_rotation_matrix();
    let t = reference.translation.vector;
    // Revolute: the joint frame sits on the axis, so the rotation is about its origin;
    // spherical: at the centre.
    let origin = match (j.joint_type, j.point_in_parent) {
        (JointType::Revolute | JointType::Spherical | JointType::Universal, Some(p)) => {
            Vector3::from(p)
        }
        _ => t,
    };
    Ok(JointFrame {
        origin,
        rotation: r,
        offset: r.inverse() * (t - origin),
    })
}

/// Each joint's frame and each link's offset: a point `x` of body `b`'s frame is at
/// `x + offsets[b]` in the URDF link frame of `b` ([`to_urdf`]). The root's offset is zero.
///
/// # Errors
/// As [`to_urdf`].
pub fn link_offsets(model: &Model) -> Result<Vec<[f64; 3]>> {
    Ok(frames_and_offsets(model)?
        .1
        .iter()
        .map(|v| [v.x, v.y, v.z])
        .collect())
}

fn frames_and_offsets(model: &Model) -> Result<(Vec<JointFrame>, Vec<Vector3<f64>>)> {
    let nb = model.bodies.len();
    let mut offset = vec![Vector3::zeros(); nb];
    let mut frames = Vec::with_capacity(model.joints.len());
    let mut done = vec![false; nb];
    if model.root_body < nb {
        done[model.root_body] = true;
    }
    for j in &model.joints {
        if j.parent >= nb || j.child >= nb {
            return Err(Error::InvalidParameter {
                name: "joints".into(),
                message: format!("joint {} -> {} names a missing body", j.parent, j.child),
            });
        }
        frames.push(joint_frame(j)?);
    }
    // Link offsets are resolved from the root down, whatever the order of `joints`.
    let mut progress = true;
    while progress {
        progress = false;
        for (j, f) in model.joints.iter().zip(&frames) {
            if done[j.parent] && !done[j.child] {
                offset[j.child] = f.offset;
                done[j.child] = true;
                progress = true;
            }
        }
    }
    Ok((frames, offset))
}

/// URDF of the model: a link per body (named [`link_name`]) and a joint per tree edge (named
/// [`joint_name`]).
///
/// Frames: the root link is the root body's frame (origin at its keypoints' centroid). Each
/// joint frame is placed so that joint position 0 is the configuration at the joint's
/// `reference_frame`, the zero of the model's `positions`, and the positions keep their sign:
/// a revolute joint frame sits on the pivot line with the axis in it; a prismatic or
/// multi-DoF joint frame sits at the child's body origin. A child link frame is its joint
/// frame, so it is the child's body frame shifted by a fixed offset (written in a comment).
///
/// Types: `revolute` with `lower`/`upper` from the observed range, `continuous` when the
/// range exceeds one turn, `prismatic` with the range in metres, and `floating` for a
/// multi-DoF joint (the ranks are in the model JSON) or a detached body (hung from the
/// root). Effort and velocity limits are not observable from keypoints and are written as 0.
/// Keypoint labels go into comments.
///
/// # Errors
/// [`Error::InvalidModel`] for a model [`Model::validate`] refuses, and
/// [`Error::InvalidParameter`] when a joint has no reference pose (schema 1).
pub fn to_urdf(model: &Model) -> Result<String> {
    model.validate()?;
    let nb = model.bodies.len();
    let (frames, offset) = frames_and_offsets(model)?;
    let mut s = String::new();
    let _ = writeln!(s, r#"<?xml version="1.0"?>"#);
    let _ = writeln!(
        s,
        "<!-- Written by {} from a model of schema {}: {} bodies, {} frames. -->",
        comment_text(&model.generator),
        model.schema_version,
        nb,
        model.n_frames
    );
    let _ = writeln!(s, r#"<robot name="kinetree_model">"#);
    for b in &model.bodies {
        let labels: Vec<String> = b
            .points
            .iter()
            .map(|&p| {
                model
                    .point_labels
                    .as_ref()
                    .and_then(|l| l.get(p).cloned())
                    .unwrap_or_else(|| format!("point {p}"))
            })
            .collect();
        let _ = writeln!(
            s,
            "  <!-- body {}{}: {}; link frame = body frame + [{}] m -->",
            b.id,
            if b.is_static { " (static)" } else { "" },
            comment_text(&labels.join(", ")),
            v3(&offset[b.id])
        );
        let _ = writeln!(s, r#"  <link name="{}"/>"#, link_name(b.id));
    }
    for (j, f) in model.joints.iter().zip(&frames) {
        let xyz = f.origin + offset[j.parent];
        let (roll, pitch, yaw) = f.rotation.euler_angles();
        let axis_parent = j.axis_in_parent.map(Vector3::from);
        let axis = axis_parent.map(|a| f.rotation.inverse() * a.normalize());
        let span = j.range.map(|r| r[1] - r[0]);
        let kind = match j.joint_type {
            JointType::Revolute if span.is_some_and(|d| d > std::f64::consts::TAU) => "continuous",
            JointType::Revolute => "revolute",
            JointType::Prismatic => "prismatic",
            JointType::Spherical => {
                write_spherical(&mut s, j, &xyz, (roll, pitch, yaw));
                continue;
            }
            JointType::Universal => {
                write_universal(&mut s, j, &f.rotation, &xyz, (roll, pitch, yaw));
                continue;
            }
            JointType::Rigid | JointType::MultiDof => "floating",
        };
        let _ = writeln!(
            s,
            r#"  <joint name="{}" type="{kind}">"#,
            joint_name(j.parent, j.child)
        );
        let _ = writeln!(
            s,
            r#"    <origin xyz="{}" rpy="{roll} {pitch} {yaw}"/>"#,
            v3(&xyz)
        );
        let _ = writeln!(s, r#"    <parent link="{}"/>"#, link_name(j.parent));
        let _ = writeln!(s, r#"    <child link="{}"/>"#, link_name(j.child));
        if kind != "floating"
            && let Some(a) = axis
        {
            let _ = writeln!(s, r#"    <axis xyz="{}"/>"#, v3(&a));
        }
        if matches!(kind, "revolute" | "prismatic") {
            let [lo, hi] = j.range.unwrap_or([0.0, 0.0]);
            let _ = writeln!(
                s,
                r#"    <limit lower="{lo}" upper="{hi}" effort="0" velocity="0"/>"#
            );
        }
        if kind == "floating" {
            let _ = writeln!(
                s,
                "    <!-- {} DoF (ranks: translation {}, rotation {}) -->",
                j.dof, j.ranks.translation, j.ranks.rotation
            );
        }
        let _ = writeln!(s, "  </joint>");
    }
    // URDF is one tree: a detached body (no pair test with any other) hangs from the root by
    // a floating joint, which claims nothing about their relative motion.
    for b in &model.bodies {
        if b.id != model.root_body && b.parent.is_none() {
            let _ = writeln!(
                s,
                r#"  <joint name="{}" type="floating">"#,
                joint_name(model.root_body, b.id)
            );
            let _ = writeln!(s, "    <!-- detached body: no joint was observed -->");
            let _ = writeln!(s, r#"    <origin xyz="0 0 0" rpy="0 0 0"/>"#);
            let _ = writeln!(s, r#"    <parent link="{}"/>"#, link_name(model.root_body));
            let _ = writeln!(s, r#"    <child link="{}"/>"#, link_name(b.id));
            let _ = writeln!(s, "  </joint>");
        }
    }
    let _ = writeln!(s, "</robot>");
    Ok(s)
}

/// A universal joint as URDF, which has none: two `continuous` joints through the centre,
/// about the first axis and then the second, chained through a massless link named after the
/// joint; their angles are the model's coordinates.
fn write_universal(
    s: &mut String,
    j: &Joint,
    rotation: &Rotation3<f64>,
    xyz: &Vector3<f64>,
    rpy: (f64, f64, f64),
) {
    let name = joint_name(j.parent, j.child);
    let _ = writeln!(
        s,
        "  <!-- {name}: a universal joint, as two revolute joints through a massless link -->"
    );
    // Axes in the joint frame, which carries the child's reference orientation.
    let axes = [j.axis_in_parent, j.second_axis_in_parent]
        .map(|a| rotation.inverse() * a.map_or_else(Vector3::z, Vector3::from).normalize());
    let chain = [("1", axes[0]), ("2", axes[1])];
    write_revolute_chain(s, j, &name, &chain, xyz, rpy);
}

/// A spherical joint as URDF, which has no ball joint: three `continuous` joints about the
/// joint frame's x, y and z axes through the centre, chained through two massless links named
/// after the joint. Their angles are XYZ Euler angles, not the model's rotation vector.
fn write_spherical(s: &mut String, j: &Joint, xyz: &Vector3<f64>, rpy: (f64, f64, f64)) {
    let name = joint_name(j.parent, j.child);
    let _ = writeln!(
        s,
        "  <!-- {name}: a spherical joint about the centre, as three revolute joints through \
         massless links (their angles are XYZ Euler angles, not the model's rotation vector) -->"
    );
    let chain = [
        ("rx", Vector3::x()),
        ("ry", Vector3::y()),
        ("rz", Vector3::z()),
    ];
    write_revolute_chain(s, j, &name, &chain, xyz, rpy);
}

/// `continuous` joints `<name>_<suffix>` about each axis of `chain` (in the joint frame)
/// from `j`'s parent link to its child's, through a massless link between each two (named
/// after the next joint's suffix); the first joint sits at `xyz`, `rpy` in the parent link.
fn write_revolute_chain(
    s: &mut String,
    j: &Joint,
    name: &str,
    chain: &[(&str, Vector3<f64>)],
    xyz: &Vector3<f64>,
    rpy: (f64, f64, f64),
) {
    let mut links = vec![link_name(j.parent)];
    links.extend(
        chain[1..]
            .iter()
            .map(|(suffix, _)| format!("{name}_{suffix}_link")),
    );
    links.push(link_name(j.child));
    for link in &links[1..links.len() - 1] {
        let _ = writeln!(s, r#"  <link name="{link}"/>"#);
    }
    for (i, (suffix, axis)) in chain.iter().enumerate() {
        let _ = writeln!(s, r#"  <joint name="{name}_{suffix}" type="continuous">"#);
        if i == 0 {
            let (roll, pitch, yaw) = rpy;
            let _ = writeln!(
                s,
                r#"    <origin xyz="{}" rpy="{roll} {pitch} {yaw}"/>"#,
                v3(xyz)
            );
        } else {
            let _ = writeln!(s, r#"    <origin xyz="0 0 0" rpy="0 0 0"/>"#);
        }
        let _ = writeln!(s, r#"    <parent link="{}"/>"#, links[i]);
        let _ = writeln!(s, r#"    <child link="{}"/>"#, links[i + 1]);
        let _ = writeln!(s, r#"    <axis xyz="{}"/>"#, v3(axis));
        let _ = writeln!(s, "  </joint>");
    }
}

/// DOT (Graphviz) of the kinematic tree: the camera, a node per body (static ones marked), an
/// edge per joint labelled with its type, axis in the parent frame and observed range.
pub fn to_dot(model: &Model) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "digraph kinematic_tree {{");
    let _ = writeln!(s, "  rankdir=TB;");
    let _ = writeln!(s, "  node [shape=box, fontname=\"Helvetica\"];");
    let _ = writeln!(s, "  camera [shape=ellipse, label=\"camera\"];");
    for b in &model.bodies {
        let names: Vec<String> = b
            .points
            .iter()
            .filter_map(|&p| model.point_labels.as_ref()?.get(p).cloned())
            .collect();
        let detail = if names.is_empty() {
            format!("{} points", b.points.len())
        } else {
            dot_text(&names.join(", "))
        };
        let _ = writeln!(
            s,
            "  {} [label=\"body {}{}\\n{}\"];",
            link_name(b.id),
            b.id,
            if b.is_static { " (static)" } else { "" },
            detail
        );
    }
    if let Some(root) = model.bodies.get(model.root_body) {
        let style = if root.is_static {
            "static"
        } else {
            "moves (no static body)"
        };
        let _ = writeln!(
            s,
            "  camera -> {} [style=dashed, label=\"{style}\"];",
            link_name(root.id)
        );
    }
    for j in &model.joints {
        let mut label = dot_text(j.joint_type.as_str());
        if let Some(a) = j.axis_in_parent {
            let _ = write!(label, "\\naxis [{:.3}, {:.3}, {:.3}]", a[0], a[1], a[2]);
        }
        if let Some([lo, hi]) = j.range {
            let unit = if j.joint_type == JointType::Prismatic {
                "m"
            } else {
                "rad"
            };
            let _ = write!(label, "\\nrange [{lo:.3}, {hi:.3}] {unit}");
        }
        if j.joint_type == JointType::MultiDof {
            let _ = write!(label, "\\n{} DoF", j.dof);
        }
        let _ = writeln!(
            s,
            "  {} -> {} [label=\"{label}\"];",
            link_name(j.parent),
            link_name(j.child)
        );
    }
    let _ = writeln!(s, "}}");
    s
}

/// MJCF joint body name of the joint from `parent` to `child` ([`to_mjcf`]).
pub fn mjcf_joint_body_name(parent: usize, child: usize) -> String {
    format!("{}_joint", joint_name(parent, child))
}

/// `w x y z`, MJCF's quaternion order.
fn wxyz(q: &UnitQuaternion<f64>) -> String {
    format!("{} {} {} {}", q.w, q.i, q.j, q.k)
}

/// Nominal mass and inertia of every body, so MuJoCo loads the model: keypoints do not
/// observe them.
const NOMINAL_INERTIAL: &str =
    r#"<inertial pos="0 0 0" mass="0.001" diaginertia="1e-6 1e-6 1e-6"/>"#;

/// MJCF (MuJoCo) of the model. The world frame is the root body's frame when the root is
/// static; a root that is not static moves on a `freejoint` (its position and quaternion
/// `w x y z` in the world, which is then the camera frame), and so does a detached body.
///
/// Each joint is a massless-in-effect body named [`mjcf_joint_body_name`], placed in the
/// parent at the joint's pivot (revolute), centre (spherical) or origin (others) with the
/// parent's axes, that carries the joint; the child body, named [`link_name`], sits inside it
/// at the joint's reference pose. The joints' `qpos` are then the model's own coordinates: a
/// `hinge` about `axis_in_parent` by the position (radians), a `slide` along it (metres), a
/// `ball` by the quaternion of the rotation vector in `coordinates`; a multi-DoF joint is
/// three `slide`s along the parent's axes and a `ball` (MuJoCo allows a `free` joint on
/// top-level bodies only), and a rigid joint has none. The hinge and slide ranges are the
/// observed ones. Keypoints are `site`s of their bodies, named `point<index>` and their label.
///
/// # Errors
/// [`Error::InvalidModel`] for a model [`Model::validate`] refuses, and
/// [`Error::InvalidParameter`] when a joint has no reference pose (schema 1).
pub fn to_mjcf(model: &Model) -> Result<String> {
    model.validate()?;
    let nb = model.bodies.len();
    let mut children: Vec<Vec<&Joint>> = vec![Vec::new(); nb];
    for j in &model.joints {
        children[j.parent].push(j);
    }
    let mut s = String::new();
    let _ = writeln!(
        s,
        "<!-- Written by {} from a model of schema {}: {} bodies, {} frames. Masses and \
         inertias are nominal: keypoints do not observe them. -->",
        comment_text(&model.generator),
        model.schema_version,
        nb,
        model.n_frames
    );
    let _ = writeln!(s, r#"<mujoco model="kinetree_model">"#);
    let _ = writeln!(s, r#"  <compiler angle="radian"/>"#);
    let _ = writeln!(s, "  <worldbody>");
    let label = |p: usize| {
        model
            .point_labels
            .as_ref()
            .and_then(|l| l.get(p).cloned())
            .map_or_else(
                || format!("point{p}"),
                |l| format!("point{p}_{}", xml_attribute(&l)),
            )
    };
    // Bodies are written depth first; a body's open tag and its joints come from its joint.
    fn write_body(
        s: &mut String,
        model: &Model,
        children: &[Vec<&Joint>],
        b: usize,
        depth: usize,
        label: &dyn Fn(usize) -> String,
    ) -> Result<()> {
        let pad = "  ".repeat(depth);
        let _ = writeln!(s, "{pad}  {NOMINAL_INERTIAL}");
        let body = &model.bodies[b];
        for (p, shape) in body.points.iter().zip(&body.shape) {
            if let Some(x) = shape {
                let _ = writeln!(
                    s,
                    r#"{pad}  <site name="{}" pos="{} {} {}" size="0.005"/>"#,
                    label(*p),
                    x[0],
                    x[1],
                    x[2]
                );
            }
        }
        for j in &children[b] {
            write_joint(s, model, children, j, depth + 1, label)?;
        }
        Ok(())
    }
    fn write_joint(
        s: &mut String,
        model: &Model,
        children: &[Vec<&Joint>],
        j: &Joint,
        depth: usize,
        label: &dyn Fn(usize) -> String,
    ) -> Result<()> {
        let pad = "  ".repeat(depth);
        let reference = reference_pose(j, "MJCF")?;
        let at = match j.joint_type {
            JointType::Revolute | JointType::Spherical | JointType::Universal => {
                j.point_in_parent.map_or_else(Vector3::zeros, Vector3::from)
            }
            _ => Vector3::zeros(),
        };
        let _ = writeln!(
            s,
            r#"{pad}<body name="{}" pos="{}">"#,
            mjcf_joint_body_name(j.parent, j.child),
            v3(&at)
        );
        let _ = writeln!(s, "{pad}  {NOMINAL_INERTIAL}");
        let axis = j.axis_in_parent.map(Vector3::from);
        let range = j
            .range
            .map_or(String::new(), |[lo, hi]| format!(r#" range="{lo} {hi}""#));
        let name = joint_name(j.parent, j.child);
        match (j.joint_type, axis) {
            (JointType::Revolute, Some(a)) => {
                let _ = writeln!(
                    s,
                    r#"{pad}  <joint name="{name}" type="hinge" axis="{}"{range}/>"#,
                    v3(&a)
                );
            }
            (JointType::Prismatic, Some(a)) => {
                let _ = writeln!(
                    s,
                    r#"{pad}  <joint name="{name}" type="slide" axis="{}"{range}/>"#,
                    v3(&a)
                );
            }
            (JointType::Spherical, _) => {
                let _ = writeln!(s, r#"{pad}  <joint name="{name}" type="ball"/>"#);
            }
            // Two hinges in one body turn in order, the second about its axis as the first
            // has carried it: the model's two angles.
            (JointType::Universal, Some(a)) => {
                let second = j
                    .second_axis_in_parent
                    .map_or_else(Vector3::z, Vector3::from);
                for (i, axis) in [a, second].iter().enumerate() {
                    let _ = writeln!(
                        s,
                        r#"{pad}  <joint name="{name}_{}" type="hinge" axis="{}"/>"#,
                        i + 1,
                        v3(axis)
                    );
                }
            }
            (JointType::Rigid, _) => {
                let _ = writeln!(s, "{pad}  <!-- {name}: rigid, no joint -->");
            }
            _ => {
                let _ = writeln!(
                    s,
                    "{pad}  <!-- {name}: {} DoF of no known type, as three slides and a ball \
                     (ranks: translation {}, rotation {}) -->",
                    j.dof, j.ranks.translation, j.ranks.rotation
                );
                for (i, a) in ["1 0 0", "0 1 0", "0 0 1"].iter().enumerate() {
                    let _ = writeln!(
                        s,
                        r#"{pad}  <joint name="{name}_{}" type="slide" axis="{a}"/>"#,
                        ["x", "y", "z"][i]
                    );
                }
                let _ = writeln!(s, r#"{pad}  <joint name="{name}_ball" type="ball"/>"#);
            }
        }
        let inside = Vector3::from(reference.translation.vector) - at;
        let _ = writeln!(
            s,
            r#"{pad}  <body name="{}" pos="{}" quat="{}">"#,
            link_name(j.child),
            v3(&inside),
            wxyz(&reference.rotation)
        );
        write_body(s, model, children, j.child, depth + 1, label)?;
        let _ = writeln!(s, "{pad}  </body>");
        let _ = writeln!(s, "{pad}</body>");
        Ok(())
    }
    let free = |b: &kinetree_core::model::Body| {
        b.id != model.root_body && b.parent.is_none() || b.id == model.root_body && !b.is_static
    };
    for b in &model.bodies {
        if b.id != model.root_body && b.parent.is_some() {
            continue;
        }
        let _ = writeln!(s, r#"    <body name="{}">"#, link_name(b.id));
        if free(b) {
            let _ = writeln!(s, r#"      <freejoint name="{}_free"/>"#, link_name(b.id));
        }
        write_body(&mut s, model, &children, b.id, 2, &label)?;
        let _ = writeln!(s, "    </body>");
    }
    let _ = writeln!(s, "  </worldbody>");
    let _ = writeln!(s, "</mujoco>");
    Ok(s)
}

/// Text safe inside an XML attribute value.
fn xml_attribute(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace(['\n', '\r'], " ")
}
