//! Degenerate but survivable situations, reported in the output instead of failing.

use serde::{Deserialize, Serialize};

/// A typed warning carried into the model output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[non_exhaustive]
pub enum Warning {
    /// Samples no recording can hold (a coordinate beyond `[pipeline.outliers]
    /// max_coordinate_m`, or a one-sample jump away from the track and straight back), made
    /// occluded before anything else.
    ImpossibleSamplesDropped {
        /// How many.
        count: usize,
        /// The points they belong to, ascending.
        points: Vec<usize>,
        /// The first of them as `[frame, point]` (at most 50).
        samples: Vec<[usize; 2]>,
    },
    /// A C3D file names more markers in `POINT:LABELS` than it stores (`POINT:USED`); the
    /// extra names were left out.
    C3dLabelsUnused {
        /// The points the file stores.
        points_used: usize,
        /// The names beyond them.
        labels: Vec<String>,
    },
    /// Points of a C3D file that its `POINT:ANGLES`, `FORCES`, `MOMENTS`, `POWERS`,
    /// `SCALARS` or `REACTIONS` parameters name: a modelling program's outputs stored as
    /// points, not markers; they were left out of the tracks.
    C3dOutputsSkipped {
        /// The groups that named them (`ANGLES`, ...).
        groups: Vec<String>,
        /// Their labels, in the file's order.
        labels: Vec<String>,
    },
    /// Points that a modelling program computed rather than markers, told by their names:
    /// Plug-in Gait's segment axes (a segment code's `O`, `A`, `L` and `P` points, such as
    /// `PELO` ... `PELP`) and centre of mass; they were left out of the tracks.
    ModelPointsSkipped {
        /// Their labels, in the file's order.
        labels: Vec<String>,
    },
    /// Points whose tracks repeat an earlier point's within a fraction of a millimetre (one
    /// marker stored twice under two names); they were left out of the tracks.
    PointsDuplicated {
        /// The points left out.
        points: Vec<usize>,
        /// The point each one repeats, in the same order.
        of: Vec<usize>,
        /// The bound on the median distance, metres.
        within_m: f64,
    },
    /// A point never visible in any frame; it is discarded.
    PointNeverVisible {
        /// The point.
        point: usize,
    },
    /// A point never seen together with any other point in two frames; it is discarded.
    PointUnpaired {
        /// The point.
        point: usize,
    },
    /// Pairs seen together in fewer than two frames; their dissimilarity was inferred through
    /// third points (see the README's occlusion policy).
    PairsInferred {
        /// Number of such pairs.
        count: usize,
    },
    /// A cluster with fewer than three points, too small for a pose; its points are discarded.
    ClusterDiscarded {
        /// The points of the cluster.
        points: Vec<usize>,
    },
    /// Points the clustering had discarded but whose tracks one body's poses explain; they
    /// were attached to it.
    PointsAttached {
        /// The points.
        points: Vec<usize>,
    },
    /// Points the segmentation had left unassigned that move together as one rigid body
    /// (their poses fit as one); each group became a body.
    UnassignedPointsGrouped {
        /// The groups of points.
        groups: Vec<Vec<usize>>,
    },
    /// A body seen too few points at a time for poses of its own in most frames (points on
    /// no body, typically one or two per frame, or a body registered in under half its
    /// frames) whose points turn together about one axis of a posed body or of the camera
    /// frame; it was posed through that hinge in the frames where it had no pose of its own
    /// and one of its points off the axis is visible (points on no body became a body).
    BodyPosedThroughHinge {
        /// The body's points.
        points: Vec<usize>,
        /// The points of the body it turns on when it was posed (`None`: the camera frame).
        parent: Option<Vec<usize>>,
        /// Frames posed through the hinge.
        frames: usize,
    },
    /// A body seen too few points at a time for poses of its own in most frames (a cluster
    /// of two points, typically two markers on a hand or foot) whose points stay at fixed
    /// distances from a point of a posed body or of the camera frame: it was posed through
    /// that ball joint, from the joint's centre and its points, in the frames where it had
    /// no pose of its own and two of its points are visible.
    BodyPosedThroughBall {
        /// The body's points.
        points: Vec<usize>,
        /// The points of the body it turns on when it was posed (`None`: the camera frame).
        parent: Option<Vec<usize>>,
        /// Frames posed through the ball joint.
        frames: usize,
    },
    /// Points of other bodies rigid with a group of points were given to it as well
    /// (`[pipeline.repairs.share_points]`): the group was a cluster too small for a pose, one
    /// or two points on no body, or points not rigid with most of their body, which became a
    /// body with them; or a body of the fewest points a pose needs. They are markers on a
    /// joint's axis, which now belong to both bodies (the model's `shared_points`).
    PointsShared {
        /// The points that belong to two bodies.
        points: Vec<usize>,
        /// The group's own points.
        body: Vec<usize>,
    },
    /// Points of a body posed through a hinge that do not turn with it: left out, each lowered
    /// the hinge's `chi^2` by far more than its own degrees of freedom allow. They were left on
    /// no body and the body posed again.
    PointsOffHinge {
        /// The points.
        points: Vec<usize>,
    },
    /// Points that fitted their body's motion in the model's whole-tree fit far worse than
    /// the noise and its other points allow, and no other body's either; they were left on
    /// no body and the bodies, joints and positions redone.
    PointsUnassigned {
        /// The points.
        points: Vec<usize>,
    },
    /// Points each of which alone made a joint multi-DoF: with it left out of its body, the
    /// pair test found a single-DoF joint where, over the same frames, it found more with
    /// it, and leaving out no other point of the joint's two bodies did the same. They were
    /// left on no body (another body's fitted motion may take them) and the bodies, joints
    /// and positions redone.
    PointsMakingJointsMultiDof {
        /// The points.
        points: Vec<usize>,
    },
    /// Points that a model's whole-tree fit placed on another body (its fitted motion
    /// explained their tracks better than their own body's), or on a body when they had none
    /// (it explained them clearly better than any other); they were moved there and the
    /// bodies, joints and positions redone.
    PointsReassigned {
        /// The points.
        points: Vec<usize>,
    },
    /// A body whose fit residuals were far above the noise (it mixed points of bodies that
    /// move apart) was split in two.
    BodySplit {
        /// The body's points before the split.
        points: Vec<usize>,
        /// Its median fit residual in units of `sigma`.
        residual_in_sigma: f64,
    },
    /// A body that could not be registered in enough frames; its points are discarded.
    BodyDropped {
        /// The body's points.
        points: Vec<usize>,
        /// Why.
        reason: String,
    },
    /// A body that has no pose in some frames.
    FramesUnregistered {
        /// Body id in the model numbering.
        body: usize,
        /// Frames without a pose.
        frames: usize,
    },
    /// Bodies found rigid relative to each other were merged into one.
    BodiesMerged {
        /// Points of the bodies that were merged, one list per original body.
        groups: Vec<Vec<usize>>,
    },
    /// No body is static relative to the camera; the tree is rooted at the least-moving one.
    NoStaticBody {
        /// The chosen root (model numbering).
        root: usize,
    },
    /// A body that shares too few frames with every other body for a pair test: it has no
    /// parent and no joint (the model is a forest, the others rooted at `root_body`).
    BodyDetached {
        /// The body (model numbering).
        body: usize,
    },
    /// The spanning tree had to use an edge that is not a single-DoF joint.
    MultiDofJoint {
        /// Parent body (model numbering).
        parent: usize,
        /// Child body (model numbering).
        child: usize,
        /// Estimated degrees of freedom of the pair.
        dof: usize,
    },
    /// Two bodies whose relative motion is two hinges through a link that no keypoint shows
    /// well enough to pose it: body `body` was put between them, turning on `parent` about
    /// the first hinge and carrying `child` about the second, with the keypoints `points`
    /// (`[pipeline.unseen_links]`). A link read from a universal joint between two of its
    /// children (`[pipeline.unseen_links] hubs`) turns or slides on `parent` and carries
    /// `child` and every other body the model hangs on it, each by a hinge; its `offset_m`
    /// is 0.
    UnseenLink {
        /// The seen body above the link (model numbering).
        parent: usize,
        /// The body put in for the link (model numbering).
        body: usize,
        /// The seen body below it (model numbering).
        child: usize,
        /// Shortest distance between the two hinge axes, metres.
        offset_m: f64,
        /// Keypoints whose tracks the link's fitted motion explains clearly best, given to
        /// it (none for a link buried between its neighbours).
        #[serde(default)]
        points: Vec<usize>,
    },
    /// The whole-tree fit could not follow a joint: the child's keypoints miss their
    /// positions predicted through the joint by far more than they miss the child's own pose.
    /// The joint's positions come from the two bodies' fitted poses instead.
    JointNotFollowed {
        /// Parent body (model numbering).
        parent: usize,
        /// Child body (model numbering).
        child: usize,
        /// The miss beyond the child's own pose, per point, in units of sigma^2.
        excess_in_sigma2: f64,
    },
    /// A joint the pair test called multi-DoF, or a single-DoF joint the whole-tree fit did
    /// not follow, moves as a joint of this type in the fit: fitted anew from the fitted
    /// poses, the fit followed it, and it replaced the pair test's joint (its ranks are still
    /// the pair test's).
    JointTypedByFit {
        /// Parent body (model numbering).
        parent: usize,
        /// Child body (model numbering).
        child: usize,
        /// `revolute` or `prismatic` (or `spherical`, for a universal joint the fit follows
        /// better as a ball).
        joint_type: crate::model::JointType,
        /// The child's miss beyond its own pose with this joint, per point, in sigma^2.
        excess_in_sigma2: f64,
    },
    /// The pair test between a joint's bodies found `tested` (rigid, or a slide that stood
    /// out only against the measured noise level): the child moves too little against the
    /// parent for the test to see its joint. A tree repair typed it from the bodies around it instead (a
    /// gripper's quiet finger, on the rail or pin its sibling moves along), and the model
    /// with it fitted the keypoints as well and was kept.
    JointTypedBySibling {
        /// Parent body (model numbering).
        parent: usize,
        /// Child body (model numbering).
        child: usize,
        /// The pair test's type.
        tested: crate::model::JointType,
        /// The type given.
        joint_type: crate::model::JointType,
    },
    /// The recorded motion cannot tell a joint's type from others; the type is the one the
    /// tests chose, and the alternatives fit the data as well. `basis` says why:
    /// - `small_motion`: its least-moving coordinate (for a ball joint, its rotations' least
    ///   principal direction that the type needs) spread over the frames by less than
    ///   `bound_in_std` of its per-frame standard deviations (`[pipeline.positions]
    ///   min_identifiable_spread_in_std`);
    /// - `within_model_error`: a hinge's child turned off the axis by at least `bound_in_std`
    ///   of the keypoint noise's standard deviations (`[pipeline.positions]
    ///   min_off_axis_spread_in_std`): motion a ball or universal joint has, which the type
    ///   decision took for the bodies' model error (skin under markers, joint play).
    JointNotIdentifiable {
        /// Parent body (model numbering).
        parent: usize,
        /// Child body (model numbering).
        child: usize,
        /// The type given.
        joint_type: crate::model::JointType,
        /// The types the motion cannot rule out.
        alternatives: Vec<crate::model::JointType>,
        /// The spread, RMS about the mean over the frames, in per-frame standard deviations.
        spread_in_std: f64,
        /// The bound the spread was held against.
        bound_in_std: f64,
        /// Why the types cannot be told apart (absent in files written before it existed:
        /// `small_motion`).
        #[serde(default)]
        basis: NotIdentifiableBasis,
    },
    /// The model had multi-DoF joints or joints its whole-tree fit did not follow, so every
    /// pair was tested again on the poses of its whole-tree fit and the model rebuilt on
    /// them; the rebuilt model, with fewer such joints, was kept. Pair tests, joints and
    /// positions are the rebuilt model's.
    PairsRetested {
        /// Multi-DoF joints plus joints not followed by the fit, in the first model.
        multi_dof_before: usize,
        /// The same count in the rebuilt one.
        multi_dof_after: usize,
    },
    /// The tracks had more points than `[pipeline.sampling] max_points`: the bodies, joints
    /// and pair tests were found on `sampled` of them, chosen to cover the scene, and every
    /// other point was tested against each body's poses and given to the body that explains
    /// it best; `unexplained` fitted no body's motion and were left on no body.
    TracksSampled {
        /// Points the discovery ran on.
        sampled: usize,
        /// Points given to a body afterwards.
        assigned: usize,
        /// Points no body's poses explain, ascending.
        unexplained: Vec<usize>,
        /// Discoveries run: more than one when points no body explained were added to the
        /// sample and the discovery run again.
        rounds: usize,
    },
    /// The noise level was estimated from the data.
    NoiseEstimated {
        /// The estimate, per-coordinate std-dev in metres.
        sigma_m: f64,
    },
    /// The noise estimate fell below the error of rounding the coordinates to the file's
    /// grid, and was raised to it: the data may be a model's noise-free output.
    NoiseAtPrecision {
        /// The level used, `precision_m / sqrt 12` (the std-dev of rounding), metres.
        sigma_m: f64,
        /// The grid's step (a C3D file's integer scale, a text file's last decimal), metres.
        precision_m: f64,
    },
}

/// Why a `joint_not_identifiable` warning finds a joint's type undecided by the data.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NotIdentifiableBasis {
    /// The coordinates that tell the types apart moved too little.
    #[default]
    SmallMotion,
    /// The child moved in a way the type lacks, by more than the keypoint noise explains and
    /// within what the type decision allows a real joint (its model error).
    WithinModelError,
}

impl Warning {
    /// The keypoints a warning took off the bodies or left without one, which a reader with
    /// marker names wants named: never visible, unpaired, in a discarded cluster or dropped
    /// body, unassigned, or making a joint multi-DoF. Empty for other warnings.
    pub fn points_left_out(&self) -> &[usize] {
        match self {
            Warning::PointNeverVisible { point } | Warning::PointUnpaired { point } => {
                std::slice::from_ref(point)
            }
            Warning::ClusterDiscarded { points }
            | Warning::PointsDuplicated { points, .. }
            | Warning::PointsUnassigned { points }
            | Warning::PointsMakingJointsMultiDof { points }
            | Warning::BodyDropped { points, .. }
            | Warning::TracksSampled {
                unexplained: points,
                ..
            } => points,
            _ => &[],
        }
    }
}

impl Warning {
    /// The warning with every point index `i` it holds replaced by `f(i)`: for a warning
    /// made on a subset of the tracks' points, named back in the whole tracks' numbering.
    pub fn map_points(mut self, f: impl Fn(usize) -> usize) -> Self {
        let all = |v: &mut Vec<usize>| v.iter_mut().for_each(|i| *i = f(*i));
        match &mut self {
            Warning::ImpossibleSamplesDropped {
                points, samples, ..
            } => {
                all(points);
                samples.iter_mut().for_each(|s| s[1] = f(s[1]));
            }
            Warning::PointNeverVisible { point } | Warning::PointUnpaired { point } => {
                *point = f(*point);
            }
            Warning::PointsDuplicated { points, of, .. } => {
                all(points);
                all(of);
            }
            Warning::ClusterDiscarded { points }
            | Warning::PointsAttached { points }
            | Warning::PointsOffHinge { points }
            | Warning::PointsUnassigned { points }
            | Warning::PointsMakingJointsMultiDof { points }
            | Warning::PointsReassigned { points }
            | Warning::UnseenLink { points, .. }
            | Warning::BodySplit { points, .. }
            | Warning::BodyDropped { points, .. }
            | Warning::TracksSampled {
                unexplained: points,
                ..
            } => all(points),
            Warning::UnassignedPointsGrouped { groups } | Warning::BodiesMerged { groups } => {
                groups.iter_mut().for_each(all);
            }
            Warning::BodyPosedThroughHinge { points, parent, .. }
            | Warning::BodyPosedThroughBall { points, parent, .. } => {
                all(points);
                if let Some(p) = parent {
                    all(p);
                }
            }
            Warning::PointsShared { points, body } => {
                all(points);
                all(body);
            }
            _ => {}
        }
        self
    }
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Warning::ImpossibleSamplesDropped { count, points, .. } => write!(
                f,
                "{count} impossible sample(s) (huge coordinates, or one-frame jumps away and back) of point(s) {points:?} were dropped as occluded"
            ),
            Warning::C3dLabelsUnused {
                points_used,
                labels,
            } => write!(
                f,
                "the C3D file stores {points_used} points but names {} more ({}); the extra names were left out",
                labels.len(),
                labels.join(", ")
            ),
            Warning::C3dOutputsSkipped { groups, labels } => write!(
                f,
                "{} C3D point(s) named in POINT:{} are modelling outputs, not markers; left out: {}",
                labels.len(),
                groups.join("/"),
                labels.join(", ")
            ),
            Warning::ModelPointsSkipped { labels } => write!(
                f,
                "{} point(s) are Plug-in Gait segment axes or centre of mass, a model's outputs, not markers; left out: {}",
                labels.len(),
                labels.join(", ")
            ),
            Warning::PointsDuplicated {
                points,
                of,
                within_m,
            } => write!(
                f,
                "point(s) {points:?} repeat the tracks of point(s) {of:?} (median distance within {:.2} mm: one marker stored twice); left out",
                within_m * 1e3
            ),
            Warning::PointNeverVisible { point } => {
                write!(f, "point {point} is never visible; discarded")
            }
            Warning::PointUnpaired { point } => write!(
                f,
                "point {point} is never seen with another point in two frames; discarded"
            ),
            Warning::PairsInferred { count } => write!(
                f,
                "{count} point pairs were never seen together twice; their dissimilarity was inferred through third points"
            ),
            Warning::ClusterDiscarded { points } => {
                write!(
                    f,
                    "cluster of {} point(s) {points:?} is too small for a pose; discarded",
                    points.len()
                )
            }
            Warning::PointsAttached { points } => write!(
                f,
                "point(s) {points:?} discarded by the clustering were attached to the one body whose poses explain them"
            ),
            Warning::UnassignedPointsGrouped { groups } => write!(
                f,
                "point groups {groups:?} left unassigned by the clustering move as rigid bodies and became bodies"
            ),
            Warning::PointsShared { points, body } => write!(
                f,
                "point(s) {points:?}, rigid with their body and with the point(s) {body:?}, belong to both bodies"
            ),
            Warning::BodyPosedThroughHinge {
                points,
                parent,
                frames,
            } => match parent {
                Some(b) => write!(
                    f,
                    "the body of point(s) {points:?}, seen too few points at a time, turns about one axis of the body of points {b:?} and was posed through that hinge in {frames} frame(s)"
                ),
                None => write!(
                    f,
                    "the body of point(s) {points:?}, seen too few points at a time, turns about one axis fixed in the camera frame and was posed through that hinge in {frames} frame(s)"
                ),
            },
            Warning::BodyPosedThroughBall {
                points,
                parent,
                frames,
            } => match parent {
                Some(b) => write!(
                    f,
                    "the body of point(s) {points:?}, seen too few points at a time, turns about a point of the body of points {b:?} and was posed through that ball joint in {frames} frame(s)"
                ),
                None => write!(
                    f,
                    "the body of point(s) {points:?}, seen too few points at a time, turns about a point fixed in the camera frame and was posed through that ball joint in {frames} frame(s)"
                ),
            },
            Warning::PointsMakingJointsMultiDof { points } => write!(
                f,
                "without point(s) {points:?} (one per joint), a multi-DoF joint between their body and its neighbour tested single-DoF; they were left on no body"
            ),
            Warning::PointsOffHinge { points } => write!(
                f,
                "point(s) {points:?} did not turn with the hinge their body was posed through; they were left on no body"
            ),
            Warning::PointsUnassigned { points } => write!(
                f,
                "point(s) {points:?} fitted their body's motion far worse than the noise and its other points allow, and no other body's; they were left on no body"
            ),
            Warning::PointsReassigned { points } => write!(
                f,
                "point(s) {points:?} fitted another body's motion better than their own (or, unassigned, one body's clearly best) and were moved to it"
            ),
            Warning::BodySplit {
                points,
                residual_in_sigma,
            } => write!(
                f,
                "body with points {points:?} fitted with a median residual of {residual_in_sigma:.1} sigma and was split in two"
            ),
            Warning::BodyDropped { points, reason } => {
                write!(f, "body with points {points:?} dropped: {reason}")
            }
            Warning::FramesUnregistered { body, frames } => {
                write!(f, "body {body} has no pose in {frames} frame(s)")
            }
            Warning::BodiesMerged { groups } => {
                write!(
                    f,
                    "{} bodies moved rigidly together and were merged: {groups:?}",
                    groups.len()
                )
            }
            Warning::NoStaticBody { root } => write!(
                f,
                "no body is static relative to the camera; the tree is rooted at body {root}, a centre of the tree that turns least (or a body on a single-DoF joint with the camera)"
            ),
            Warning::BodyDetached { body } => write!(
                f,
                "body {body} has no pair test with any other body (too few shared frames); it has no parent and no joint"
            ),
            Warning::MultiDofJoint { parent, child, dof } => write!(
                f,
                "bodies {parent} -> {child} are linked in the tree but their relative motion has {dof} DoF, not one"
            ),
            Warning::UnseenLink {
                parent,
                body,
                child,
                offset_m,
                points,
            } => {
                write!(
                    f,
                    "bodies {parent} -> {child} turn on two hinges {:.1} mm apart; body {body}, a link too little seen to pose, was put between them",
                    offset_m * 1e3
                )?;
                if points.is_empty() {
                    Ok(())
                } else {
                    write!(f, " with the keypoints it explains, {points:?}")
                }
            }
            Warning::JointNotFollowed {
                parent,
                child,
                excess_in_sigma2,
            } => write!(
                f,
                "joint {parent} -> {child}: its child misses the whole-tree fit by {excess_in_sigma2:.1} sigma^2 per point beyond its own pose; its positions come from the two bodies' poses"
            ),
            Warning::JointTypedByFit {
                parent,
                child,
                joint_type,
                excess_in_sigma2,
            } => write!(
                f,
                "joint {parent} -> {child}: typed otherwise by its pair test, but the whole-tree fit follows it as {joint_type} (its child misses by {excess_in_sigma2:.1} sigma^2 per point beyond its own pose)"
            ),
            Warning::JointTypedBySibling {
                parent,
                child,
                tested,
                joint_type,
            } => write!(
                f,
                "joint {parent} -> {child}: its pair test found it {tested}, a motion too small to test; typed {joint_type} from its sibling's joint, whose axis it shares"
            ),
            Warning::JointNotIdentifiable {
                parent,
                child,
                joint_type,
                alternatives,
                spread_in_std,
                bound_in_std,
                basis,
            } => {
                let others: Vec<String> = alternatives.iter().map(|t| t.to_string()).collect();
                match basis {
                    NotIdentifiableBasis::SmallMotion => write!(
                        f,
                        "joint {parent} -> {child}: not identifiable; typed {joint_type}, but its motion spread only {spread_in_std:.2} std (below {bound_in_std}) where a {} joint differs, so the data fit that as well",
                        others.join(" or ")
                    ),
                    NotIdentifiableBasis::WithinModelError => write!(
                        f,
                        "joint {parent} -> {child}: not identifiable; typed {joint_type}, but its child turned off the axis by {spread_in_std:.2} std of noise (at least {bound_in_std}), as a {} joint would, and the type decision took that for model error",
                        others.join(" or ")
                    ),
                }
            }
            Warning::PairsRetested {
                multi_dof_before,
                multi_dof_after,
            } => write!(
                f,
                "pairs tested again on the whole-tree fit's poses: {multi_dof_before} multi-DoF or unfollowed joint(s) became {multi_dof_after}"
            ),
            Warning::TracksSampled {
                sampled,
                assigned,
                unexplained,
                rounds,
            } => {
                write!(
                    f,
                    "bodies and joints found on {sampled} sampled point(s) ({rounds} discovery run(s)); {assigned} other point(s) given to the body whose poses explain them"
                )?;
                if !unexplained.is_empty() {
                    write!(
                        f,
                        "; {} fitted no body and were left on none: {unexplained:?}",
                        unexplained.len()
                    )?;
                }
                Ok(())
            }
            Warning::NoiseEstimated { sigma_m } => write!(
                f,
                "noise level estimated from the data: sigma = {:.3} mm per coordinate",
                sigma_m * 1e3
            ),
            Warning::NoiseAtPrecision {
                sigma_m,
                precision_m,
            } => write!(
                f,
                "the noise estimate fell below the rounding of the file's coordinates to {:.4} mm; raised to its std-dev, {:.4} mm (noise-free model output?)",
                precision_m * 1e3,
                sigma_m * 1e3
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_point_a_warning_holds_is_renamed() {
        let twice = |i: usize| 2 * i + 1;
        let w = Warning::BodyPosedThroughHinge {
            points: vec![0, 2],
            parent: Some(vec![3]),
            frames: 7,
        }
        .map_points(twice);
        assert_eq!(
            w,
            Warning::BodyPosedThroughHinge {
                points: vec![1, 5],
                parent: Some(vec![7]),
                frames: 7,
            }
        );
        let w = Warning::ImpossibleSamplesDropped {
            count: 1,
            points: vec![4],
            samples: vec![[10, 4]],
        }
        .map_points(twice);
        assert_eq!(w.points_left_out(), &[] as &[usize]);
        assert!(
            matches!(w, Warning::ImpossibleSamplesDropped { points, samples, .. }
            if points == vec![9] && samples == vec![[10, 9]])
        );
        let w = Warning::PointsShared {
            points: vec![1],
            body: vec![2, 3],
        }
        .map_points(twice);
        assert_eq!(
            w,
            Warning::PointsShared {
                points: vec![3],
                body: vec![5, 7],
            }
        );
        let w = Warning::BodiesMerged {
            groups: vec![vec![0], vec![1, 2]],
        }
        .map_points(twice);
        assert_eq!(
            w,
            Warning::BodiesMerged {
                groups: vec![vec![1], vec![3, 5]],
            }
        );
        let w = Warning::UnseenLink {
            parent: 4,
            body: 6,
            child: 5,
            offset_m: 0.04,
            points: vec![2, 3],
        }
        .map_points(twice);
        assert!(matches!(w, Warning::UnseenLink { points, body: 6, .. } if points == vec![5, 7]));
        let w = Warning::PointNeverVisible { point: 3 }.map_points(twice);
        assert_eq!(w.points_left_out(), &[7]);
        let w = Warning::NoiseEstimated { sigma_m: 0.001 };
        assert_eq!(w.clone().map_points(twice), w);
    }
}
