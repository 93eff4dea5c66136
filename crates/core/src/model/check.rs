//! The rules a model must keep to be read: [`Model::validate`].

use super::{JointType, Model, SCHEMA_VERSION};
use crate::{Error, Result};

/// How far an axis' norm may be from one (the model writes unit axes to 17 digits; a reader
/// that rounds them to a few digits stays well inside).
const AXIS_NORM_TOLERANCE: f64 = 1e-3;

fn bad(field: impl Into<String>, message: impl Into<String>) -> Error {
    Error::InvalidModel {
        field: field.into(),
        message: message.into(),
    }
}

fn finite(field: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(k) => Err(bad(field, format!("has a non-finite entry {}", values[k]))),
        None => Ok(()),
    }
}

fn unit_axis(field: &str, axis: &[f64; 3]) -> Result<()> {
    finite(field, axis)?;
    let norm = axis.iter().map(|v| v * v).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > AXIS_NORM_TOLERANCE {
        return Err(bad(
            field,
            format!("must be a unit vector, has norm {norm}"),
        ));
    }
    Ok(())
}

fn per_frame(field: &str, values: &[Option<f64>], n_frames: usize, min: f64) -> Result<()> {
    frames_or_empty(field, values.len(), n_frames)?;
    for (t, v) in values.iter().enumerate() {
        if let Some(v) = v
            && !(v.is_finite() && *v >= min)
        {
            return Err(bad(
                format!("{field}[{t}]"),
                format!("must be finite and at least {min}, got {v}"),
            ));
        }
    }
    Ok(())
}

/// A per-frame array has `n_frames` entries or none.
fn frames_or_empty(field: &str, len: usize, n_frames: usize) -> Result<()> {
    if len != 0 && len != n_frames {
        return Err(bad(
            field,
            format!("has {len} entries; n_frames is {n_frames} (or leave it empty)"),
        ));
    }
    Ok(())
}

/// [`per_frame`] for arrays of `width` coordinates a frame; `width` below 2 takes none.
fn per_frame_vectors(
    field: &str,
    values: &[Option<Vec<f64>>],
    n_frames: usize,
    width: usize,
    min: f64,
) -> Result<()> {
    if values.is_empty() {
        return Ok(());
    }
    if width < 2 {
        return Err(bad(
            field,
            format!("is given on a joint of {width} coordinate(s); leave it empty"),
        ));
    }
    frames_or_empty(field, values.len(), n_frames)?;
    for (t, v) in values.iter().enumerate() {
        let Some(v) = v else { continue };
        if v.len() != width {
            return Err(bad(
                format!("{field}[{t}]"),
                format!("has {} entries; the joint has {width} coordinates", v.len()),
            ));
        }
        if let Some(x) = v.iter().find(|x| !(x.is_finite() && **x >= min)) {
            return Err(bad(
                format!("{field}[{t}]"),
                format!("must be finite and at least {min}, got {x}"),
            ));
        }
    }
    Ok(())
}

impl Model {
    /// Checks the rules every consumer of a model relies on, so that a hand-edited or damaged
    /// file is refused where it is read rather than giving a panic or a silently wrong export:
    /// a known schema version; bodies numbered by position with a parent tree rooted at
    /// `root_body` (bodies with a `body_detached` warning outside it) and one joint per body
    /// with a parent, matching it; body and point indices in
    /// range; unit, finite axes on single-DoF joints; per-frame arrays of `n_frames` entries;
    /// ordered ranges; valid reference poses and position limits.
    ///
    /// # Errors
    /// [`Error::InvalidModel`] naming the first field that breaks a rule, as its JSON path.
    pub fn validate(&self) -> Result<()> {
        if !(1..=SCHEMA_VERSION).contains(&self.schema_version) {
            return Err(bad(
                "schema_version",
                format!(
                    "is {}; this kinetree reads versions 1 to {SCHEMA_VERSION}",
                    self.schema_version
                ),
            ));
        }
        let (nf, np, nb) = (self.n_frames, self.n_points, self.bodies.len());
        if nf == 0 || np == 0 || nb == 0 {
            return Err(bad(
                "n_frames, n_points, bodies",
                format!("must all be non-empty, got {nf} frames, {np} points, {nb} bodies"),
            ));
        }
        if let Some(labels) = &self.point_labels
            && labels.len() != np
        {
            return Err(bad(
                "point_labels",
                format!("has {} labels for {np} points", labels.len()),
            ));
        }
        if let Some(name) = &self.body_poses_file
            && (name.is_empty()
                || name.contains(['/', '\\'])
                || name == ".."
                || !name.ends_with(".npy"))
        {
            return Err(bad(
                "body_poses_file",
                format!("must be the name of a .npy file beside the model, got `{name}`"),
            ));
        }
        let noise = &self.noise;
        if !(noise.sigma_m.is_finite() && noise.sigma_m > 0.0) {
            return Err(bad(
                "noise.sigma_m",
                format!("must be finite and positive, got {}", noise.sigma_m),
            ));
        }
        self.position_limits
            .validate("position_limits")
            .map_err(|e| match e {
                Error::InvalidParameter { name, message } => bad(name, message),
                other => other,
            })?;
        if self.point_body.len() != np {
            return Err(bad(
                "point_body",
                format!("has {} entries for {np} points", self.point_body.len()),
            ));
        }
        for (p, &b) in self.point_body.iter().enumerate() {
            if b < -1 || b >= nb as i64 {
                return Err(bad(
                    format!("point_body[{p}]"),
                    format!("is {b}; bodies are 0..{nb} (-1 for discarded)"),
                ));
            }
        }
        for (k, &[p, b]) in self.shared_points.iter().enumerate() {
            let field = format!("shared_points[{k}]");
            if k > 0 && self.shared_points[k - 1] >= [p, b] {
                return Err(bad(field, "must be ascending without repeats"));
            }
            if p >= np || b >= nb {
                return Err(bad(
                    field,
                    format!("is [{p}, {b}]; the model has {np} points and {nb} bodies"),
                ));
            }
            if self.point_body[p] < 0 || self.point_body[p] == b as i64 {
                return Err(bad(
                    field,
                    format!(
                        "shares point {p} with body {b}, but point_body puts it in {}",
                        self.point_body[p]
                    ),
                ));
            }
            if !self.bodies[b].points.contains(&p) {
                return Err(bad(field, format!("body {b} does not list point {p}")));
            }
        }
        if !self.point_confidence.is_empty() && self.point_confidence.len() != np {
            return Err(bad(
                "point_confidence",
                format!(
                    "has {} entries for {np} points",
                    self.point_confidence.len()
                ),
            ));
        }
        for (field, body) in [
            ("root_body", Some(self.root_body)),
            ("static_body", self.static_body),
        ] {
            if let Some(b) = body
                && b >= nb
            {
                return Err(bad(field, format!("is {b}; the model has {nb} bodies")));
            }
        }
        if let Some(root_joint) = self.root_joint
            && root_joint != super::RootJoint::of(self.static_body)
        {
            return Err(bad(
                "root_joint",
                format!(
                    "is {root_joint:?} but static_body is {:?}: the root is fixed exactly when \
                     a body is static",
                    self.static_body
                ),
            ));
        }
        self.validate_bodies()?;
        self.validate_joints()?;
        if let Some(chain) = &self.chain {
            let mut seen = vec![false; nb];
            for (k, &b) in chain.iter().enumerate() {
                if b >= nb || std::mem::replace(&mut seen[b], true) {
                    return Err(bad(
                        format!("chain[{k}]"),
                        format!("is {b}: not a body, or repeated"),
                    ));
                }
            }
        }
        for (k, pair) in self.pairs.iter().enumerate() {
            if pair.a.is_some_and(|a| a >= nb) || pair.b >= nb {
                return Err(bad(
                    format!("pairs[{k}]"),
                    format!("names body {:?} -> {}; the model has {nb}", pair.a, pair.b),
                ));
            }
        }
        if let Some(r) = self.reprediction_rms_in_sigma
            && !(r.is_finite() && r >= 0.0)
        {
            return Err(bad(
                "reprediction_rms_in_sigma",
                format!("must be finite and non-negative, got {r}"),
            ));
        }
        Ok(())
    }

    fn validate_bodies(&self) -> Result<()> {
        let (nf, np, nb) = (self.n_frames, self.n_points, self.bodies.len());
        for (i, body) in self.bodies.iter().enumerate() {
            let field = |name: &str| format!("bodies[{i}].{name}");
            if body.id != i {
                return Err(bad(
                    field("id"),
                    format!("is {}; bodies are numbered by position", body.id),
                ));
            }
            for (k, &p) in body.points.iter().enumerate() {
                if p >= np {
                    return Err(bad(
                        format!("bodies[{i}].points[{k}]"),
                        format!("is {p}; the model has {np} points"),
                    ));
                }
                if k > 0 && body.points[k - 1] >= p {
                    return Err(bad(field("points"), "must be ascending without repeats"));
                }
                if self.point_body[p] != i as i64 && !self.shared_points.contains(&[p, i]) {
                    return Err(bad(
                        format!("bodies[{i}].points[{k}]"),
                        format!(
                            "is point {p}, which point_body puts in body {}",
                            self.point_body[p]
                        ),
                    ));
                }
            }
            if !body.shape.is_empty() && body.shape.len() != body.points.len() {
                return Err(bad(
                    field("shape"),
                    format!(
                        "has {} entries for {} points",
                        body.shape.len(),
                        body.points.len()
                    ),
                ));
            }
            for (k, s) in body.shape.iter().enumerate() {
                if let Some(s) = s {
                    finite(&format!("bodies[{i}].shape[{k}]"), s)?;
                }
            }
            if body.frames_registered > nf {
                return Err(bad(
                    field("frames_registered"),
                    format!("is {}; the model has {nf} frames", body.frames_registered),
                ));
            }
            match body.parent {
                None if i != self.root_body && !self.is_detached(i) => {
                    return Err(bad(
                        field("parent"),
                        format!(
                            "is null, but only the root (body {}) and bodies with a \
                             `body_detached` warning have none",
                            self.root_body
                        ),
                    ));
                }
                Some(p) if i == self.root_body || p >= nb || p == i => {
                    return Err(bad(
                        field("parent"),
                        format!("is {p}: the root has none, others name another of {nb} bodies"),
                    ));
                }
                _ => {}
            }
        }
        // Following parents ends within `nb` steps at a body without one (no cycle).
        for i in 0..nb {
            let mut b = i;
            for _ in 0..nb {
                match self.bodies[b].parent {
                    Some(p) => b = p,
                    None => break,
                }
            }
            if self.bodies[b].parent.is_some() {
                return Err(bad(
                    format!("bodies[{i}].parent"),
                    "leads round a cycle instead of to the root",
                ));
            }
        }
        Ok(())
    }

    /// Whether body `b` is reported detached (no parent, no joint) by a warning.
    fn is_detached(&self, b: usize) -> bool {
        self.warnings
            .iter()
            .any(|w| matches!(w, crate::Warning::BodyDetached { body } if *body == b))
    }

    fn validate_joints(&self) -> Result<()> {
        let (nf, nb) = (self.n_frames, self.bodies.len());
        let with_parent = self.bodies.iter().filter(|b| b.parent.is_some()).count();
        if self.joints.len() != with_parent {
            return Err(bad(
                "joints",
                format!(
                    "has {} joints; the bodies name {with_parent} parents",
                    self.joints.len()
                ),
            ));
        }
        let mut seen = vec![false; nb];
        for (k, j) in self.joints.iter().enumerate() {
            let field = |name: &str| format!("joints[{k}].{name}");
            if j.child >= nb || j.parent >= nb {
                return Err(bad(
                    field("child"),
                    format!(
                        "joint {} -> {} names a body beyond the model's {nb}",
                        j.parent, j.child
                    ),
                ));
            }
            if self.bodies[j.child].parent != Some(j.parent) {
                return Err(bad(
                    field("parent"),
                    format!(
                        "is {}, but bodies[{}].parent is {:?}",
                        j.parent, j.child, self.bodies[j.child].parent
                    ),
                ));
            }
            if std::mem::replace(&mut seen[j.child], true) {
                return Err(bad(
                    field("child"),
                    format!("body {} has a second joint", j.child),
                ));
            }
            for (name, axis) in [
                ("axis", &j.axis),
                ("axis_in_parent", &j.axis_in_parent),
                ("second_axis", &j.second_axis),
                ("second_axis_in_parent", &j.second_axis_in_parent),
            ] {
                if let Some(a) = axis {
                    unit_axis(&field(name), a)?;
                }
            }
            if j.joint_type.is_single_dof() && j.axis_in_parent.is_none() {
                return Err(bad(
                    field("axis_in_parent"),
                    format!("is null on a {} joint", j.joint_type),
                ));
            }
            if j.joint_type == JointType::Revolute && j.point_in_parent.is_none() {
                return Err(bad(field("point_in_parent"), "is null on a revolute joint"));
            }
            for (name, point) in [("point", &j.point), ("point_in_parent", &j.point_in_parent)] {
                if let Some(p) = point {
                    finite(&field(name), p)?;
                }
            }
            if j.reference_frame >= nf {
                return Err(bad(
                    field("reference_frame"),
                    format!("is {}; the model has {nf} frames", j.reference_frame),
                ));
            }
            if let Some(pose) = &j.reference_pose
                && pose.to_isometry().is_none()
            {
                return Err(bad(
                    field("reference_pose"),
                    "is not a rigid transform (zero or non-finite quaternion, or non-finite translation)",
                ));
            }
            for (name, value) in [
                ("axis_std_deg", j.axis_std_deg),
                ("pivot_std_m", j.pivot_std_m),
                ("centre_std_m", j.centre_std_m),
                ("second_axis_std_deg", j.second_axis_std_deg),
            ] {
                if let Some(v) = value
                    && !(v.is_finite() && v >= 0.0)
                {
                    return Err(bad(
                        field(name),
                        format!("must be finite and at least 0, got {v}"),
                    ));
                }
            }
            per_frame(&field("positions"), &j.positions, nf, f64::NEG_INFINITY)?;
            per_frame(&field("position_std"), &j.position_std, nf, 0.0)?;
            per_frame(
                &field("smoothed_positions"),
                &j.smoothed_positions,
                nf,
                f64::NEG_INFINITY,
            )?;
            per_frame(&field("smoothed_std"), &j.smoothed_std, nf, 0.0)?;
            let width = j.joint_type.n_coordinates();
            for (name, values, min) in [
                ("coordinates", &j.coordinates, f64::NEG_INFINITY),
                ("coordinate_std", &j.coordinate_std, 0.0),
                (
                    "smoothed_coordinates",
                    &j.smoothed_coordinates,
                    f64::NEG_INFINITY,
                ),
                ("smoothed_coordinate_std", &j.smoothed_coordinate_std, 0.0),
            ] {
                per_frame_vectors(&field(name), values, nf, width, min)?;
            }
            if matches!(j.joint_type, JointType::Spherical | JointType::Universal)
                && j.point_in_parent.is_none()
            {
                return Err(bad(
                    field("point_in_parent"),
                    format!("is null on a {} joint", j.joint_type),
                ));
            }
            if j.joint_type == JointType::Universal {
                for (name, axis) in [
                    ("axis_in_parent", j.axis_in_parent),
                    ("second_axis_in_parent", j.second_axis_in_parent),
                ] {
                    if axis.is_none() {
                        return Err(bad(field(name), "is null on a universal joint"));
                    }
                }
            }
            if let Some([lo, hi]) = j.range
                && !(lo.is_finite() && hi.is_finite() && lo <= hi)
            {
                return Err(bad(
                    field("range"),
                    format!("must be finite with lower <= upper, got [{lo}, {hi}]"),
                ));
            }
            if j.fit_ratio.is_nan() {
                return Err(bad(field("fit_ratio"), "is NaN"));
            }
        }
        Ok(())
    }
}
