//! A keypoint that alone makes a joint multi-DoF left on no body, so that the model's fitted
//! motions may place it in the next pass. Asked only when no other points repair of the pass
//! proposed an edit.
//!
//! For every multi-DoF joint, a keypoint of its parent or child body (bodies of more than
//! three) qualifies when without it the body, posed by itself again, and the other pass the
//! pair test as a single-DoF joint, while with it, posed the same way over the same frames,
//! they do not; and when it is the only such keypoint of the two. The same frames, because
//! fewer frames pass the test more easily. A keypoint near a joint axis is rigid to both
//! bodies pairwise and can be clustered onto the wrong one; judging it against the body posed
//! without it does not find it, the pair test does (`docs/decisions.md`, `joint_spoilers`).

use super::move_points::points_settle;
use super::posed_as_one;
use crate::runner::{frame_and_moving, pose_spread};
use kinetree_core::{
    BodyTrack, Constraints, DofInput, Draft, Edit, Error, Proposal, Repair, RepairContext,
    RepairPhase, Result, Warning,
};
use serde::{Deserialize, Serialize};

/// Parameters of [`JointSpoilers`] (`[pipeline.repairs.joint_spoilers]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JointSpoilersParams {
    /// Whether the repair runs.
    pub enabled: bool,
}

impl Default for JointSpoilersParams {
    fn default() -> Self {
        Self { enabled: true }
    }
}

impl JointSpoilersParams {
    /// Checks the ranges (there are none).
    ///
    /// # Errors
    /// Never.
    pub fn validate(&self) -> Result<()> {
        Ok(())
    }
}

/// Takes off the keypoint that alone makes a joint multi-DoF.
#[derive(Debug, Clone)]
pub struct JointSpoilers {
    _params: JointSpoilersParams,
}

impl JointSpoilers {
    /// The repair.
    ///
    /// # Errors
    /// When the parameters are invalid.
    pub fn new(params: JointSpoilersParams) -> Result<Self> {
        params.validate()?;
        Ok(Self { _params: params })
    }
}

impl Repair for JointSpoilers {
    fn name(&self) -> &str {
        "joint_spoilers"
    }

    fn phase(&self) -> RepairPhase {
        RepairPhase::Points
    }

    fn propose(&self, ctx: &RepairContext<'_>, draft: &Draft) -> Result<Option<Proposal>> {
        if !draft.pending.is_empty() {
            return Ok(None);
        }
        let (Some(found), Some(poses)) = (draft.model.as_ref(), draft.poses.as_ref()) else {
            return Err(Error::Degenerate(
                "repair `joint_spoilers` needs a model and its poses".into(),
            ));
        };
        let n = poses.bodies.len();
        let spread: Vec<(f64, f64)> = poses.bodies.iter().map(pose_spread).collect();
        // `None` when the points cannot be posed.
        let posed_alone = |points: &[usize]| posed_as_one(ctx, points).ok().flatten();
        let mut out: Vec<usize> = Vec::new();
        let mut trial = poses.clone();
        for joint in found
            .model
            .joints
            .iter()
            .filter(|j| j.joint_type == kinetree_core::model::JointType::MultiDof)
        {
            let (p, c) = (joint.parent, joint.child);
            if p >= n || c >= n {
                continue;
            }
            let (frame, moving) = frame_and_moving(&spread, p, c);
            // Whether the pair test with `side` posed as `track` finds a single-DoF joint.
            let mut single_dof = |side: usize, track: BodyTrack| {
                trial.bodies[side] = track;
                let input = DofInput {
                    poses: &trial,
                    noise_sigma_m: ctx.noise_sigma_m,
                };
                let tested = ctx
                    .stages
                    .dof
                    .test_pair(&input, Some(frame), moving)
                    .ok()
                    .map(|pair| pair.joint.is_single_dof());
                trial.bodies[side] = poses.bodies[side].clone();
                tested
            };
            let mut single: Vec<usize> = Vec::new();
            for side in [c, p] {
                let points = &poses.bodies[side].points;
                if points.len() <= kinetree_core::MIN_BODY_POINTS {
                    continue;
                }
                // Posed by itself (its poses may have come through a hinge) with all its
                // points, the body must test multi-DoF on exactly the frames it keeps without
                // the point.
                let Some(all) = posed_alone(points) else {
                    continue;
                };
                for &i in points {
                    let rest: Vec<usize> = points.iter().copied().filter(|&q| q != i).collect();
                    let Some(without) = posed_alone(&rest) else {
                        continue;
                    };
                    let mut with = all.clone();
                    for t in 0..with.cam_from_body.len() {
                        if without.cam_from_body.get(t).is_none_or(Option::is_none) {
                            with.cam_from_body[t] = None;
                            with.quality[t] = None;
                        }
                    }
                    if single_dof(side, without) == Some(true)
                        && single_dof(side, with) == Some(false)
                    {
                        single.push(i);
                    }
                }
            }
            if let [i] = single[..]
                && !out.contains(&i)
            {
                out.push(i);
            }
        }
        out.sort_unstable();
        if out.is_empty() {
            return Ok(None);
        }
        let mut p = Proposal::new(
            Edit::Points(out.iter().map(|&i| (i, None)).collect()),
            format!(
                "{} keypoint(s) that alone make a joint multi-DoF left on none",
                out.len()
            ),
        );
        p.points.clone_from(&out);
        p.constraints = Constraints {
            kept_off: out.clone(),
            ..Constraints::default()
        };
        p.warnings
            .push(Warning::PointsMakingJointsMultiDof { points: out });
        Ok(Some(p))
    }

    fn stands(
        &self,
        ctx: &RepairContext<'_>,
        edit: &Edit,
        _before: &Draft,
        after: &Draft,
    ) -> Result<bool> {
        points_settle(
            self.name(),
            ctx,
            edit,
            after,
            kinetree_fit::MotionLimits::default(),
        )
    }
}
