//! The observer: joint positions of new frames from a discovered model, by a kinematic fit of
//! the whole tree to each frame's visible keypoints.

use crate::tree_cholesky::{TreeCholesky, TreePattern};
use kinetree_core::geom::{angle_about, kabsch_with_rank_check, wrap_pi};
use kinetree_core::model::{JointFit, JointType, PositionLimits};
use kinetree_core::nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Point3, Translation3, Unit, UnitQuaternion,
    Vector3, Vector6,
};
use kinetree_core::{Error, Model, PoseQuality, Result, Tracks, Warning};
use rayon::prelude::*;

#[derive(Debug, Clone)]
pub(crate) struct ObservedBody {
    /// `(point index, position in the body frame)` for every placed point.
    pub(crate) shape: Vec<(usize, Point3<f64>)>,
    /// Whether it is a link put in between two hinges (an `unseen_link` warning names it),
    /// whose frame is a choice its few keypoints need not fix.
    pub(crate) unseen_link: bool,
}

#[derive(Debug, Clone, Copy)]
pub(crate) enum Measure {
    /// Axis and a point on it, both in the parent's body frame.
    Revolute(Vector3<f64>, Point3<f64>),
    Prismatic(Vector3<f64>),
    /// A ball joint's centre in the parent's body frame: three parameters, the child's
    /// rotation about it.
    Spherical(Point3<f64>),
    /// A universal joint: its first axis (fixed in the parent), its second (fixed in the
    /// child, at joint position zero) and their intersection, all in the parent's body frame;
    /// two parameters, the angles about each.
    Universal(Vector3<f64>, Vector3<f64>, Point3<f64>),
    /// Neither, or no reference pose: no position.
    None,
}

impl Measure {
    /// Number of the fit's parameters the joint takes when it is followed.
    pub(crate) fn width(&self) -> usize {
        match self {
            Measure::Revolute(..) | Measure::Prismatic(..) => 1,
            Measure::Universal(..) => 2,
            Measure::Spherical(..) => 3,
            Measure::None => 0,
        }
    }
}

#[derive(Debug, Clone)]
pub(crate) struct ObservedJoint {
    pub(crate) parent: usize,
    pub(crate) child: usize,
    pub(crate) measure: Measure,
    pub(crate) reference: Isometry3<f64>,
}

/// One frame's kinematic fit (see [`Observer::fit`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFit {
    /// Joint positions, radians or metres, in the order of the model's joints; `None` where
    /// the frame does not determine the position (no visible point below the joint, or a
    /// standard deviation above the model's
    /// [`PositionLimits`](kinetree_core::model::PositionLimits)), and for spherical joints.
    pub positions: Vec<Option<f64>>,
    /// Standard deviation of each position from the fit, with the model's noise level.
    pub std: Vec<Option<f64>>,
    /// The rotation of each spherical joint (`None` for other joints, and where the frame
    /// does not determine it): the rotation vector, radians, of the child about the centre
    /// from its reference pose, in the parent's body frame.
    pub rotations: Vec<Option<[f64; 3]>>,
    /// Standard deviation of each spherical joint's rotation about the parent's three axes,
    /// radians.
    pub rotation_std: Vec<Option<[f64; 3]>>,
    /// The two angles of each universal joint, radians, from its reference pose (`None` for
    /// other joints, and where the frame does not determine them).
    pub angles: Vec<Option<[f64; 2]>>,
    /// Standard deviation of each universal joint's angles, radians.
    pub angle_std: Vec<Option<[f64; 2]>>,
    /// Every body's `camera_from_body` from the fitted configuration; `None` where its part of
    /// the tree is not determined.
    pub poses: Vec<Option<Isometry3<f64>>>,
    /// Visible placed points the fit used.
    pub n_points: usize,
    /// Sum of their squared residuals, m^2.
    pub sum_sq_m2: f64,
}

/// A parameter whose variance inflation (its variance over what it would be were it the
/// only free one) exceeds this is not determined by the frame.
const MAX_VARIANCE_INFLATION: f64 = 1e8;

/// Estimates joint positions of frames from a discovered [`Model`] by fitting the whole
/// kinematic tree to the frame's visible keypoints: the pose of the root (and of any body
/// below a joint that is not single-DoF) and every single-DoF joint's position, by damped
/// Gauss-Newton on the squared distances between the observed keypoints and their positions
/// predicted from the model's reference shapes, joints and reference poses.
///
/// Every visible point constrains every joint above it, so a body with one or two visible
/// points still gives its joint a position (a per-body pose needs three), and a small body's
/// few points are helped by its neighbours'. The fit starts from the root's Kabsch-Umeyama
/// pose and then, parents before children, each joint's closed-form best position given its
/// parent's starting pose (one or two visible points suffice); a previous frame's fit, when
/// given, fills the gaps and is a second start; a joint whose child shows no point scans its
/// angle in twelve steps over the points below it.
///
/// Complexity per iteration: one pass over the visible points plus, per body, a product of
/// its 6 x 6 information matrix with the motions of the parameters above it. Two to four
/// iterations from the start.
#[derive(Debug, Clone)]
pub struct Observer {
    n_points: usize,
    pub(crate) sigma: f64,
    /// When a position is reported unknown (the model's).
    pub(crate) limits: PositionLimits,
    pub(crate) bodies: Vec<ObservedBody>,
    pub(crate) joints: Vec<ObservedJoint>,
    /// Joints treated as free (see [`Observer::free_joint`]).
    pub(crate) freed: Vec<bool>,
    /// The joint whose child each body is.
    parent_joint: Vec<Option<usize>>,
    /// Bodies, parents before children.
    topo: Vec<usize>,
    /// The single-DoF joint whose child each body is; `None` for a freely posed body.
    link: Vec<Option<usize>>,
    /// First of the six pose parameters of each freely posed body.
    pub(crate) free_col: Vec<Option<usize>>,
    /// The parameter of each single-DoF joint.
    pub(crate) joint_col: Vec<Option<usize>>,
    /// Parameters that move each body: its free ancestor's six, then the joints down to it.
    pub(crate) cols: Vec<Vec<usize>>,
    /// The parameters' paths (each one's is the start of its body's `cols`), for the
    /// factorisation of the normal matrix without fill-in ([`TreeCholesky`]).
    pub(crate) pattern: TreePattern,
    pub(crate) n_params: usize,
}

fn vector(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

/// The parameters of one frame's fit.
#[derive(Debug, Clone)]
pub(crate) struct State {
    /// Pose of every freely posed body (`None`: not yet known).
    free: Vec<Option<Isometry3<f64>>>,
    /// Position of every single-DoF joint (`None`: not yet known).
    pub(crate) q: Vec<Option<f64>>,
    /// Rotation of every spherical joint about its centre from its reference pose, in the
    /// parent's frame (`None`: not yet known).
    pub(crate) turn: Vec<Option<UnitQuaternion<f64>>>,
    /// The second angle of every universal joint (its first is in `q`).
    pub(crate) q2: Vec<Option<f64>>,
}

impl Observer {
    /// Builds the observer from a model. Its freed joints (`JointFit::Freed`; in files of
    /// schema 1, the joints its `joint_not_followed` warnings name) are freed (see
    /// [`Observer::free_joint`]), as they were when it was discovered.
    ///
    /// # Errors
    /// [`Error::Config`] when the model has no reference shapes (written by an older version),
    /// a joint names a body that does not exist, a body has two parents, or the joints form a
    /// cycle.
    pub fn new(model: &Model) -> Result<Self> {
        let bodies = model
            .bodies
            .iter()
            .map(|b| {
                if b.shape.len() != b.points.len() {
                    return Err(Error::Config(format!(
                        "body {} has {} shape entries for {} points; rediscover with this version",
                        b.id,
                        b.shape.len(),
                        b.points.len()
                    )));
                }
                let shape = b
                    .points
                    .iter()
                    .zip(&b.shape)
                    .filter(|&(&i, _)| i < model.n_points)
                    .filter_map(|(&i, s)| s.map(|s| (i, Point3::from(vector(s)))))
                    .collect();
                Ok(ObservedBody {
                    shape,
                    unseen_link: model.is_unseen_link(b.id),
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let nb = bodies.len();
        let joints = model
            .joints
            .iter()
            .map(|j| {
                if j.parent >= nb || j.child >= nb {
                    return Err(Error::Config(format!(
                        "joint {} -> {} names a missing body",
                        j.parent, j.child
                    )));
                }
                if j.parent == j.child {
                    return Err(Error::Config(format!(
                        "joint {} -> {} joins a body to itself",
                        j.parent, j.child
                    )));
                }
                let rigid = |r: kinetree_core::model::RigidTransform| {
                    r.to_isometry().ok_or_else(|| {
                        Error::Config(format!(
                            "joint {} -> {}: reference_pose {:?} is not a rigid transform",
                            j.parent, j.child, r
                        ))
                    })
                };
                let (measure, reference) = match (j.reference_pose, j.axis_in_parent) {
                    (Some(r), Some(axis)) if vector(axis).norm() > 0.0 => {
                        let reference = rigid(r)?;
                        let axis = vector(axis).normalize();
                        let pivot = Point3::from(vector(j.point_in_parent.unwrap_or([0.0; 3])));
                        let measure = match (j.joint_type, j.second_axis_in_parent) {
                            (JointType::Revolute, _) => Measure::Revolute(axis, pivot),
                            (JointType::Prismatic, _) => Measure::Prismatic(axis),
                            (JointType::Universal, Some(second))
                                if vector(second).norm() > 0.0 && j.point_in_parent.is_some() =>
                            {
                                Measure::Universal(axis, vector(second).normalize(), pivot)
                            }
                            _ => Measure::None,
                        };
                        (measure, reference)
                    }
                    (Some(r), _) if j.joint_type == JointType::Spherical => {
                        let reference = rigid(r)?;
                        let measure = j.point_in_parent.map_or(Measure::None, |c| {
                            Measure::Spherical(Point3::from(vector(c)))
                        });
                        (measure, reference)
                    }
                    _ => (Measure::None, Isometry3::identity()),
                };
                Ok(ObservedJoint {
                    parent: j.parent,
                    child: j.child,
                    measure,
                    reference,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut parent_joint: Vec<Option<usize>> = vec![None; nb];
        for (k, j) in joints.iter().enumerate() {
            if parent_joint[j.child].replace(k).is_some() {
                return Err(Error::Config(format!(
                    "body {} is the child of two joints",
                    j.child
                )));
            }
        }
        // Parents before children: breadth first from the bodies no joint leads to.
        let mut topo: Vec<usize> = (0..nb).filter(|&b| parent_joint[b].is_none()).collect();
        let mut i = 0;
        while i < topo.len() {
            let u = topo[i];
            topo.extend(joints.iter().filter(|j| j.parent == u).map(|j| j.child));
            i += 1;
        }
        if topo.len() != nb {
            return Err(Error::Config("the model's joints form a cycle".into()));
        }
        model.position_limits.validate("position_limits")?;
        let mut observer = Self {
            n_points: model.n_points,
            sigma: model.noise.sigma_m,
            limits: model.position_limits,
            bodies,
            freed: vec![false; joints.len()],
            joints,
            parent_joint,
            topo,
            link: Vec::new(),
            free_col: Vec::new(),
            joint_col: Vec::new(),
            cols: Vec::new(),
            pattern: TreePattern::default(),
            n_params: 0,
        };
        // Joints freed when the model was discovered stay free, so new frames are fitted as
        // the discovery's were. Files of schema 1 name them by their warnings only.
        for j in &model.joints {
            if j.fit == JointFit::Freed
                && let Some(&Some(k)) = observer.parent_joint.get(j.child)
                && observer.joints[k].parent == j.parent
            {
                observer.freed[k] = true;
            }
        }
        if model.schema_version < 2 {
            for w in &model.warnings {
                if let Warning::JointNotFollowed { parent, child, .. } = w
                    && let Some(&Some(k)) = observer.parent_joint.get(*child)
                    && observer.joints[k].parent == *parent
                {
                    observer.freed[k] = true;
                }
            }
        }
        observer.lay_out();
        Ok(observer)
    }

    /// Treats joint `k` as free in the fit: its child is posed freely, as below a joint that is
    /// not single-DoF, and the joint's position comes from the two bodies' fitted poses.
    /// [`crate::fit_model_positions`] does this for joints the model cannot follow.
    pub fn free_joint(&mut self, k: usize) {
        if let Some(f) = self.freed.get_mut(k) {
            *f = true;
            self.lay_out();
        }
    }

    /// Frees the joint from body `parent` to body `child` (model ids), if the model has it
    /// (see [`Observer::free_joint`]).
    pub fn free_joint_between(&mut self, parent: usize, child: usize) {
        if let Some(&Some(k)) = self.parent_joint.get(child)
            && self.joints[k].parent == parent
        {
            self.free_joint(k);
        }
    }

    /// Assigns the fit's parameters: six per freely posed body, one per single-DoF joint,
    /// three per spherical joint (chained on the tree pattern like a free pose's six).
    fn lay_out(&mut self) {
        let nb = self.bodies.len();
        self.link = self
            .parent_joint
            .iter()
            .map(|pj| {
                pj.filter(|&k| !self.freed[k] && !matches!(self.joints[k].measure, Measure::None))
            })
            .collect();
        self.n_params = 0;
        self.free_col = vec![None; nb];
        self.joint_col = vec![None; self.joints.len()];
        self.cols = vec![Vec::new(); nb];
        for &b in &self.topo {
            match self.link[b] {
                None => {
                    self.free_col[b] = Some(self.n_params);
                    self.cols[b] = (self.n_params..self.n_params + 6).collect();
                    self.n_params += 6;
                }
                Some(k) => {
                    let width = self.joints[k].measure.width();
                    self.joint_col[k] = Some(self.n_params);
                    let mut c = self.cols[self.joints[k].parent].clone();
                    c.extend(self.n_params..self.n_params + width);
                    self.cols[b] = c;
                    self.n_params += width;
                }
            }
        }
        let mut parent = vec![None; self.n_params];
        for path in &self.cols {
            for pair in path.windows(2) {
                parent[pair[1]] = Some(pair[0]);
            }
        }
        // Columns are laid out parents first, so the pattern always exists.
        self.pattern = TreePattern::new(&parent).unwrap_or_default();
    }

    /// Number of joints (the length of [`Observer::observe`]'s result).
    pub fn n_joints(&self) -> usize {
        self.joints.len()
    }

    /// Whether joint `k` is revolute (its positions are angles).
    pub fn is_revolute(&self, k: usize) -> bool {
        matches!(
            self.joints.get(k).map(|j| j.measure),
            Some(Measure::Revolute(..))
        )
    }

    /// Whether joint `k` is universal (its angles are in [`FrameFit::angles`]).
    pub fn is_universal(&self, k: usize) -> bool {
        matches!(
            self.joints.get(k).map(|j| j.measure),
            Some(Measure::Universal(..))
        )
    }

    /// Whether joint `k` is spherical (its rotations are in [`FrameFit::rotations`]).
    pub fn is_spherical(&self, k: usize) -> bool {
        matches!(
            self.joints.get(k).map(|j| j.measure),
            Some(Measure::Spherical(..))
        )
    }

    /// Every body's `camera_from_body` in one frame from its own visible points alone
    /// (Kabsch-Umeyama), `None` with fewer than three visible placed points or collinear ones.
    pub fn body_poses(&self, frame: &[Option<Point3<f64>>]) -> Vec<Option<Isometry3<f64>>> {
        self.visible(frame).iter().map(own_pose).collect()
    }

    /// Per body, `(shape point, observation)` for its placed points visible (and finite) in
    /// `frame`.
    fn visible(&self, frame: &[Option<Point3<f64>>]) -> Visible {
        // One buffer for all bodies: a vector per body cost 15 % of a frame's fit in
        // allocation (measured on the observer benchmark).
        let mut pairs = Vec::with_capacity(self.bodies.iter().map(|b| b.shape.len()).sum());
        let mut end = Vec::with_capacity(self.bodies.len());
        for b in &self.bodies {
            pairs.extend(
                b.shape
                    .iter()
                    .filter_map(|&(i, s)| frame.get(i).copied().flatten().map(|p| (s, p)))
                    .filter(|(_, p)| p.coords.iter().all(|x| x.is_finite())),
            );
            end.push(pairs.len());
        }
        let mut visible = Visible {
            pairs,
            end,
            moments: Vec::new(),
        };
        visible.moments = (0..self.bodies.len())
            .map(|b| Moments::of(&visible[b]))
            .collect();
        visible
    }

    /// Joint positions in one frame (radians wrapped to `(-pi, pi]`, or metres), `None` where
    /// the frame does not determine them: [`Observer::fit`] without a previous frame.
    ///
    /// # Errors
    /// [`Error::Shape`] when the frame does not have the model's number of points.
    pub fn observe(&self, frame: &[Option<Point3<f64>>]) -> Result<Vec<Option<f64>>> {
        let mut q = self.fit(frame, None)?.positions;
        for (k, v) in q.iter_mut().enumerate() {
            if self.is_revolute(k) {
                *v = v.map(wrap_pi);
            }
        }
        Ok(q)
    }

    /// Fits the model to every frame of `tracks` in turn, each fit starting from the last
    /// known values of the frames before it, so revolute positions come out unwrapped.
    ///
    /// # Errors
    /// [`Error::Shape`] when the tracks do not have the model's number of points.
    pub fn fit_sequence(&self, tracks: &Tracks) -> Result<Vec<FrameFit>> {
        self.fit_sequence_with(tracks, |_, _| {})
    }

    /// [`Error::Shape`] unless a frame of `found` points has the model's points.
    fn check_points(&self, found: usize) -> Result<()> {
        if found == self.n_points {
            return Ok(());
        }
        Err(Error::Shape {
            expected: format!("{} points per frame", self.n_points),
            found: format!("{found} points"),
        })
    }

    /// [`Observer::fit_sequence`] over the given frames only, in their order, each fit
    /// starting from the frames fitted before it: one fit per listed frame.
    ///
    /// # Errors
    /// As [`Observer::fit_sequence`]; [`Error::Shape`] also for a frame beyond the tracks.
    pub fn fit_frames(&self, tracks: &Tracks, frames: &[usize]) -> Result<Vec<FrameFit>> {
        if let Some(&t) = frames.iter().find(|&&t| t >= tracks.n_frames()) {
            return Err(Error::Shape {
                expected: format!("frames below {}", tracks.n_frames()),
                found: format!("frame {t}"),
            });
        }
        self.fit_listed_frames(tracks, frames.iter().copied(), |_, _| {})
    }

    /// [`Observer::fit_sequence`], handing each frame's converged descent and visible points
    /// to `each` as well.
    pub(crate) fn fit_sequence_with(
        &self,
        tracks: &Tracks,
        each: impl FnMut(Descent, Visible),
    ) -> Result<Vec<FrameFit>> {
        self.fit_listed_frames(tracks, 0..tracks.n_frames(), each)
    }

    /// The fits of `frames` (each below the tracks' frame count), in turn, each starting from
    /// the last known values of the frames fitted before it.
    fn fit_listed_frames(
        &self,
        tracks: &Tracks,
        frames: impl ExactSizeIterator<Item = usize>,
        mut each: impl FnMut(Descent, Visible),
    ) -> Result<Vec<FrameFit>> {
        self.check_points(tracks.n_points())?;
        let mut warm: Option<FrameFit> = None;
        let mut out = Vec::with_capacity(frames.len());
        for t in frames {
            let frame = tracks.frame_points(t);
            let (descent, visible) = self.fit_descent(&frame, warm.as_ref());
            let fit = self.finish(&descent, &visible, warm.as_ref())?;
            each(descent, visible);
            remember(&mut warm, &fit);
            out.push(fit);
        }
        Ok(out)
    }

    /// [`Observer::fit_sequence`] again, given `known`: this observer's own fit of the same
    /// tracks. The fits are the same, frame for frame and bit for bit: each frame starts from
    /// the last known values of the frames before it, which `known` holds, so chunks of
    /// frames run in parallel. Without a fit per frame in `known`, the frames are fitted in
    /// turn.
    ///
    /// # Errors
    /// As [`Observer::fit_sequence`].
    pub fn refit_sequence(&self, tracks: &Tracks, known: &[FrameFit]) -> Result<Vec<FrameFit>> {
        if known.len() != tracks.n_frames() {
            return self.fit_sequence(tracks);
        }
        self.replay_with(tracks, known, |descent, visible, warm| {
            self.finish(&descent, &visible, warm)
        })
    }

    /// The descents and visible points [`Observer::fit_sequence_with`] hands on, given
    /// `known` as [`Observer::refit_sequence`] takes it, the same bit for bit, each frame's
    /// handed to `each` as it is formed (so that a caller need not keep every frame's visible
    /// points).
    ///
    /// # Errors
    /// As [`Observer::fit_sequence`].
    pub(crate) fn replay_sequence_with<R: Send>(
        &self,
        tracks: &Tracks,
        known: &[FrameFit],
        each: impl Fn(Descent, Visible) -> R + Sync,
    ) -> Result<Vec<R>> {
        if known.len() != tracks.n_frames() {
            let mut out = Vec::with_capacity(tracks.n_frames());
            self.fit_sequence_with(tracks, |d, v| out.push(each(d, v)))?;
            return Ok(out);
        }
        self.replay_with(tracks, known, |descent, visible, _| {
            Ok(each(descent, visible))
        })
    }

    /// Every frame's descent started at `known`'s own fit of that frame, all frames in
    /// parallel: the converged state of each frame again, within the descent's tolerance (not
    /// bit for bit, as [`Observer::replay_sequence_with`] gives it), for a few steps a frame
    /// where a fit from the frames before takes two full descents; each frame's handed to
    /// `each`. Without a fit per frame in `known`, as [`Observer::replay_sequence_with`].
    ///
    /// # Errors
    /// As [`Observer::fit_sequence`].
    pub(crate) fn settle_sequence_with<R: Send>(
        &self,
        tracks: &Tracks,
        known: &[FrameFit],
        each: impl Fn(Descent, Visible) -> R + Sync,
    ) -> Result<Vec<R>> {
        if known.len() != tracks.n_frames() {
            return self.replay_sequence_with(tracks, known, each);
        }
        self.settle_frames_with(tracks, known, 0..known.len(), each)
    }

    /// [`Observer::settle_sequence_with`] for the frames in `range` alone (`known` holding a
    /// fit per frame of `tracks`), in parallel.
    ///
    /// # Errors
    /// As [`Observer::fit_sequence`]; [`Error::Shape`] also for a range beyond `known`.
    pub(crate) fn settle_frames_with<R: Send>(
        &self,
        tracks: &Tracks,
        known: &[FrameFit],
        range: std::ops::Range<usize>,
        each: impl Fn(Descent, Visible) -> R + Sync,
    ) -> Result<Vec<R>> {
        self.check_points(tracks.n_points())?;
        let Some(fits) = known
            .get(range.clone())
            .filter(|_| range.end <= tracks.n_frames())
        else {
            return Err(Error::Shape {
                expected: format!("frames below {}", tracks.n_frames().min(known.len())),
                found: format!("frames {range:?}"),
            });
        };
        Ok(fits
            .par_iter()
            .zip(range)
            .map(|(fit, t)| {
                let (descent, visible) = self.settle_frame(tracks, fit, t);
                each(descent, visible)
            })
            .collect())
    }

    /// Sum over `frames` of the fit's squared residual, m^2, each frame's descent started at
    /// `known`'s fit of that frame (a fit of the same tracks by an observer of the same
    /// bodies, whatever its joints), frames in parallel: a few steps a frame where
    /// [`Observer::fit_frames`] descends from the listed frame before.
    ///
    /// # Errors
    /// [`Error::Shape`] when the tracks do not have the model's points, or a frame has no fit
    /// in `known`.
    pub fn settled_miss(
        &self,
        tracks: &Tracks,
        known: &[FrameFit],
        frames: &[usize],
    ) -> Result<f64> {
        self.check_points(tracks.n_points())?;
        if let Some(&t) = frames
            .iter()
            .find(|&&t| t >= tracks.n_frames().min(known.len()))
        {
            return Err(Error::Shape {
                expected: format!("frames below {}", tracks.n_frames().min(known.len())),
                found: format!("frame {t}"),
            });
        }
        let costs: Vec<f64> = frames
            .par_iter()
            .map(|&t| self.settle_frame(tracks, &known[t], t).0.cost)
            .collect();
        Ok(costs.iter().sum())
    }

    /// Frame `t`'s descent started at `known`, a fit of that frame, with its visible points.
    fn settle_frame(&self, tracks: &Tracks, known: &FrameFit, t: usize) -> (Descent, Visible) {
        let visible = self.visible_at(tracks, t);
        let descent = self.descend(self.initial_state(&visible, Some(known), true), &visible);
        (descent, visible)
    }

    /// [`Observer::visible`] of frame `t` of `tracks` (which has the model's points).
    pub(crate) fn visible_at(&self, tracks: &Tracks, t: usize) -> Visible {
        let frame = tracks.frame_points(t);
        self.visible(&frame)
    }

    /// The number of placed points: the most a frame can show.
    pub(crate) fn placed_points(&self) -> usize {
        self.bodies.iter().map(|b| b.shape.len()).sum()
    }

    /// Every frame's descent from the last known values of the frames before it (folded from
    /// `known`, one fit per frame), in chunks of [`REPLAY_CHUNK`] frames in parallel, each
    /// handed to `each` with those values.
    fn replay_with<R: Send>(
        &self,
        tracks: &Tracks,
        known: &[FrameFit],
        each: impl Fn(Descent, Visible, Option<&FrameFit>) -> Result<R> + Sync,
    ) -> Result<Vec<R>> {
        self.check_points(tracks.n_points())?;
        let t_len = tracks.n_frames().min(known.len());
        let mut starts = Vec::with_capacity(t_len.div_ceil(REPLAY_CHUNK));
        let mut warm: Option<FrameFit> = None;
        for (t, fit) in known.iter().enumerate().take(t_len) {
            if t % REPLAY_CHUNK == 0 {
                starts.push((t, warm.clone()));
            }
            remember(&mut warm, fit);
        }
        let chunks: Vec<Result<Vec<R>>> = starts
            .into_par_iter()
            .map(|(start, mut warm)| {
                let end = (start + REPLAY_CHUNK).min(t_len);
                let mut out = Vec::with_capacity(end - start);
                for (t, fit) in known.iter().enumerate().take(end).skip(start) {
                    let frame = tracks.frame_points(t);
                    let (descent, visible) = self.fit_descent(&frame, warm.as_ref());
                    out.push(each(descent, visible, warm.as_ref())?);
                    remember(&mut warm, fit);
                }
                Ok(out)
            })
            .collect();
        let mut out = Vec::with_capacity(t_len);
        for chunk in chunks {
            out.extend(chunk?);
        }
        Ok(out)
    }

    /// Fits the model to one frame: the pose of every freely posed body (the root, and any
    /// body below a joint that is not single-DoF) and every single-DoF joint's position.
    /// `previous` (a fit of an earlier frame) seeds what the frame's own points cannot, and
    /// keeps revolute positions within half a turn of it.
    ///
    /// # Errors
    /// [`Error::Shape`] when the frame does not have the model's number of points.
    pub fn fit(
        &self,
        frame: &[Option<Point3<f64>>],
        previous: Option<&FrameFit>,
    ) -> Result<FrameFit> {
        self.check_points(frame.len())?;
        if let Some(p) = previous
            && (p.positions.len() != self.joints.len() || p.poses.len() != self.bodies.len())
        {
            return Err(Error::Shape {
                expected: format!(
                    "a previous fit of {} joints and {} bodies",
                    self.joints.len(),
                    self.bodies.len()
                ),
                found: format!("{} joints and {} bodies", p.positions.len(), p.poses.len()),
            });
        }
        let (best, visible) = self.fit_descent(frame, previous);
        self.finish(&best, &visible, previous)
    }

    /// The converged descent of [`Observer::fit`] (inputs checked by the caller) and the
    /// frame's visible points.
    fn fit_descent(
        &self,
        frame: &[Option<Point3<f64>>],
        previous: Option<&FrameFit>,
    ) -> (Descent, Visible) {
        let visible = self.visible(frame);
        // From the previous frame's values, and from the frame's own poses where they differ
        // (a pose from three noisy points can start a joint far off, and a descent from there
        // may settle a whole turn away on another joint); the lower final cost wins. A descent
        // from the previous frame that already explains the keypoints within noise is taken
        // as it is: the second descent would cost as much again.
        if previous.is_none() {
            let best = self.descend(self.initial_state(&visible, previous, false), &visible);
            return (best, visible);
        }
        let from_previous = self.descend(self.initial_state(&visible, previous, true), &visible);
        if self.within_noise(&from_previous, &visible) {
            return (from_previous, visible);
        }
        let own = self.descend(self.initial_state(&visible, previous, false), &visible);
        let best = if from_previous.cost < own.cost {
            from_previous
        } else {
            own
        };
        (best, visible)
    }

    /// Whether descent `d`'s squared residual, in noise variances, is within the chi-square
    /// of its degrees of freedom (three a keypoint of a posed body, less the fit's
    /// parameters) plus [`WITHIN_NOISE_IN_STD`] of its standard deviations.
    fn within_noise(&self, d: &Descent, visible: &Visible) -> bool {
        let dof = (3 * posed_points(d, visible)) as f64 - self.n_params as f64;
        let var = self.sigma * self.sigma;
        dof > 0.0 && var > 0.0 && d.cost / var <= dof + WITHIN_NOISE_IN_STD * (2.0 * dof).sqrt()
    }

    /// The report of a converged state, revolute positions brought within half a turn of
    /// `previous`.
    fn finish(
        &self,
        descent: &Descent,
        visible: &Visible,
        previous: Option<&FrameFit>,
    ) -> Result<FrameFit> {
        let mut fit = self.report(descent, visible);
        // Revolute positions within half a turn of the previous frame's.
        if let Some(p) = previous {
            for (k, q) in fit.positions.iter_mut().enumerate() {
                if let (Some(v), Some(before), true) =
                    (q.as_mut(), p.positions[k], self.is_revolute(k))
                {
                    *v = before + wrap_pi(*v - before);
                }
            }
            for (now, before) in fit.angles.iter_mut().zip(&p.angles) {
                if let (Some(v), Some(b)) = (now.as_mut(), before) {
                    for i in 0..2 {
                        v[i] = b[i] + wrap_pi(v[i] - b[i]);
                    }
                }
            }
        }
        Ok(fit)
    }

    /// Damped Gauss-Newton (Levenberg-Marquardt) from `state`.
    pub(crate) fn descend(&self, mut state: State, visible: &Visible) -> Descent {
        let mut poses = self.forward(&state);
        let mut cost = Self::cost(&poses, visible);
        let mut lambda = 1e-6;
        let mut last = None;
        // Buffers reused across iterations: allocation was a tenth of a frame's fit.
        let mut trial = state.clone();
        let mut trial_poses = poses.clone();
        let mut scratch = Scratch::default();
        let mut previous_step: Option<f64> = None;
        for _ in 0..MAX_ITERATIONS {
            let Some(lin) = self.linearise(&poses, visible, &mut scratch) else {
                break;
            };
            let mut moved = false;
            while lambda < 1e10 {
                let Some(step) = lin.solve(lambda, &self.pattern) else {
                    lambda *= 10.0;
                    continue;
                };
                self.apply(&state, &step, &lin.origin, &mut trial);
                self.forward_into(&trial, &mut trial_poses);
                let c = Self::cost(&trial_poses, visible);
                if c <= cost {
                    // Converged once a step moves nothing by more than STEP_TOLERANCE, the
                    // next step predicted from the last two (their ratio is the rate of
                    // convergence) is under PREDICTED_STEP_TOLERANCE, or the step lowers the
                    // cost by under a millionth.
                    let size = self.step_size(&step);
                    let predicted = previous_step.map_or(f64::INFINITY, |p| size * size / p);
                    moved = size >= STEP_TOLERANCE
                        && predicted >= PREDICTED_STEP_TOLERANCE
                        && c < cost * (1.0 - 1e-6);
                    previous_step = Some(size);
                    std::mem::swap(&mut state, &mut trial);
                    std::mem::swap(&mut poses, &mut trial_poses);
                    cost = c;
                    lambda = (lambda * 0.1).max(1e-9);
                    break;
                }
                lambda *= 10.0;
            }
            // The last linearisation, a converged step away, serves the variances.
            last = Some(lin);
            if !moved {
                break;
            }
        }
        Descent {
            state,
            poses,
            lin: last,
            cost,
        }
    }

    /// `parent_from_child` of joint `k` in the state `s` (`None` while its value is unknown).
    fn local(&self, k: usize, s: &State) -> Option<Isometry3<f64>> {
        let j = &self.joints[k];
        match j.measure {
            Measure::Spherical(centre) => {
                let turn = s.turn[k]?;
                Some(
                    Translation3::from(centre.coords)
                        * turn
                        * Translation3::from(-centre.coords)
                        * j.reference,
                )
            }
            Measure::Universal(..) => Some(Self::universal_transform(j, s.q[k]?, s.q2[k]?)),
            _ => s.q[k].map(|q| Self::joint_transform(j, q)),
        }
    }

    /// `parent_from_child` of universal joint `j` at angles `(q1, q2)`: the child turned
    /// from its reference pose about the second axis by `q2`, then about the first by `q1`,
    /// both through the centre. Other joints: the reference pose.
    pub(crate) fn universal_transform(j: &ObservedJoint, q1: f64, q2: f64) -> Isometry3<f64> {
        let Measure::Universal(first, second, centre) = j.measure else {
            return j.reference;
        };
        Translation3::from(centre.coords)
            * UnitQuaternion::from_axis_angle(&Unit::new_unchecked(first), q1)
            * UnitQuaternion::from_axis_angle(&Unit::new_unchecked(second), q2)
            * Translation3::from(-centre.coords)
            * j.reference
    }

    /// The angles of universal joint `j` from the relative pose `x` (`parent_from_child`):
    /// the first from where the rotation takes the second axis about the first, the second
    /// from what is left, the rotation about the second axis.
    fn measure_angles(j: &ObservedJoint, x: &Isometry3<f64>) -> Option<[f64; 2]> {
        let Measure::Universal(first, second, _) = j.measure else {
            return None;
        };
        let turn = x.rotation * j.reference.rotation.inverse();
        Some(universal_angles(&turn, &first, &second))
    }

    /// `parent_from_child` of a single-DoF joint `j` at position `q` (the reference pose for
    /// other joints).
    pub(crate) fn joint_transform(j: &ObservedJoint, q: f64) -> Isometry3<f64> {
        match j.measure {
            Measure::Revolute(axis, pivot) => {
                let turn = Translation3::from(pivot.coords)
                    * UnitQuaternion::from_axis_angle(&Unit::new_unchecked(axis), q)
                    * Translation3::from(-pivot.coords);
                // The reference pose carries the child to q = 0; the rotation about the pivot
                // line then moves it to q.
                turn * j.reference
            }
            Measure::Prismatic(axis) => Translation3::from(axis * q) * j.reference,
            Measure::Spherical(_) | Measure::Universal(..) | Measure::None => j.reference,
        }
    }

    /// The rotation vector of spherical joint `j` from the relative pose `x`
    /// (`parent_from_child`): the child's rotation from its reference pose, in the parent's
    /// frame.
    fn measure_rotation(j: &ObservedJoint, x: &Isometry3<f64>) -> Option<[f64; 3]> {
        let Measure::Spherical(_) = j.measure else {
            return None;
        };
        let v = (x.rotation * j.reference.rotation.inverse()).scaled_axis();
        Some([v.x, v.y, v.z])
    }

    /// The measured position of joint `j` from the relative pose `x` (`parent_from_child`).
    fn measure(j: &ObservedJoint, x: &Isometry3<f64>) -> Option<f64> {
        match j.measure {
            Measure::Revolute(axis, _) => Some(angle_about(
                &(x.rotation * j.reference.rotation.inverse()),
                &axis,
            )),
            Measure::Prismatic(axis) => {
                Some(axis.dot(&(x.translation.vector - j.reference.translation.vector)))
            }
            Measure::Spherical(_) | Measure::Universal(..) | Measure::None => None,
        }
    }

    /// Body poses from the parameters (`None` below an unknown parameter).
    fn forward(&self, s: &State) -> Vec<Option<Isometry3<f64>>> {
        let mut poses = Vec::new();
        self.forward_into(s, &mut poses);
        poses
    }

    /// [`Observer::forward`] into `poses`, reusing its allocation.
    fn forward_into(&self, s: &State, poses: &mut Vec<Option<Isometry3<f64>>>) {
        poses.clear();
        poses.resize(self.bodies.len(), None);
        for &b in &self.topo {
            poses[b] = match self.link[b] {
                None => s.free[b],
                Some(k) => match (poses[self.joints[k].parent], self.local(k, s)) {
                    (Some(p), Some(x)) => Some(p * x),
                    _ => None,
                },
            };
        }
    }

    /// Starting values. Freely posed bodies: their own Kabsch-Umeyama pose, else `previous`'s
    /// (the other way round with `prefer_previous`), else through a body below them. Joints,
    /// parents before children: the position that best carries the child's visible points
    /// onto the model given the parent's starting pose (closed form, see [`best_position`]),
    /// else `previous`'s, else a scan over the points below the joint. With
    /// `prefer_previous`, `previous`'s positions come first.
    fn initial_state(
        &self,
        visible: &Visible,
        previous: Option<&FrameFit>,
        prefer_previous: bool,
    ) -> State {
        let nb = self.bodies.len();
        let mut s = State {
            free: vec![None; nb],
            q: vec![None; self.joints.len()],
            turn: vec![None; self.joints.len()],
            q2: vec![None; self.joints.len()],
        };
        // Per-body poses only where a freely posed body needs one: they are the costliest
        // part of the start (one 3 x 3 SVD each).
        let mut own: Vec<Option<Option<Isometry3<f64>>>> = vec![None; nb];
        let mut own_pose_of = |b: usize| *own[b].get_or_insert_with(|| own_pose(&visible[b]));
        for &b in &self.topo {
            if self.link[b].is_some() {
                continue;
            }
            let before = previous.and_then(|p| p.poses[b]);
            s.free[b] = if prefer_previous {
                before.or_else(|| own_pose_of(b))
            } else {
                own_pose_of(b).or(before)
            };
        }
        // A freely posed body with too few points of its own: from a body below it that has a
        // pose, through the joints' starting positions (previous or zero).
        for &b in &self.topo {
            if self.link[b].is_some() || s.free[b].is_some() {
                continue;
            }
            let below = self.topo.iter().copied().find(|&d| {
                self.cols[d].first() == self.free_col[b].as_ref() && own_pose_of(d).is_some()
            });
            if let Some(d) = below {
                let mut trial = s.clone();
                trial.free[b] = Some(Isometry3::identity());
                for (k, q) in trial.q.iter_mut().enumerate() {
                    *q = Some(previous.and_then(|p| p.positions[k]).unwrap_or(0.0));
                }
                for (k, t) in trial.turn.iter_mut().enumerate() {
                    *t = Some(previous_turn(previous, k).unwrap_or_default());
                }
                for (k, (q1, q2)) in trial.q.iter_mut().zip(&mut trial.q2).enumerate() {
                    if self.is_universal(k) {
                        let [a, b] = previous.and_then(|p| p.angles[k]).unwrap_or([0.0; 2]);
                        (*q1, *q2) = (Some(a), Some(b));
                    }
                }
                if let (Some(db), Some(od)) = (self.forward(&trial)[d], own_pose_of(d)) {
                    s.free[b] = Some(od * db.inverse());
                }
            }
        }
        // Joints, parents before children, each from its parent's starting pose.
        let mut poses: Vec<Option<Isometry3<f64>>> = vec![None; nb];
        for &b in &self.topo {
            let Some(k) = self.link[b] else {
                poses[b] = s.free[b];
                continue;
            };
            let j = &self.joints[k];
            // Each joint's closed-form start from its child's points is formed only when it is
            // used: a start that prefers the previous frame's values takes them where known.
            if let Measure::Spherical(centre) = j.measure {
                let before = previous_turn(previous, k);
                let closed = || {
                    poses[j.parent]
                        .and_then(|parent| best_turn(j, &centre, &parent, &visible[b], self.sigma))
                };
                s.turn[k] = if prefer_previous {
                    before.or_else(closed)
                } else {
                    closed().or(before)
                };
                if s.turn[k].is_none() && poses[j.parent].is_some() {
                    s.turn[k] = Some(UnitQuaternion::identity());
                }
            } else if let Measure::Universal(first, second, centre) = j.measure {
                let before = previous.and_then(|p| p.angles[k]);
                let closed = || {
                    poses[j.parent]
                        .and_then(|parent| best_turn(j, &centre, &parent, &visible[b], self.sigma))
                        .map(|turn| universal_angles(&turn, &first, &second))
                };
                let angles = match before {
                    Some(p) if prefer_previous => Some(p),
                    _ => match (closed(), before) {
                        (Some(v), Some(p)) => {
                            Some([p[0] + wrap_pi(v[0] - p[0]), p[1] + wrap_pi(v[1] - p[1])])
                        }
                        (v, p) => v.or(p),
                    },
                };
                if let Some([a, b]) = angles {
                    (s.q[k], s.q2[k]) = (Some(a), Some(b));
                } else if poses[j.parent].is_some() {
                    (s.q[k], s.q2[k]) = (Some(0.0), Some(0.0));
                }
            } else {
                let before = previous.and_then(|p| p.positions[k]);
                let closed = || {
                    poses[j.parent]
                        .and_then(|parent| best_position(j, &parent, &visible[b], self.sigma))
                };
                s.q[k] = match before {
                    Some(p) if prefer_previous => Some(p),
                    _ => match (closed(), before) {
                        (Some(v), Some(p)) if matches!(j.measure, Measure::Revolute(..)) => {
                            Some(p + wrap_pi(v - p))
                        }
                        (Some(v), _) => Some(v),
                        (None, p) => p,
                    },
                };
                if s.q[k].is_none() && poses[j.parent].is_some() {
                    s.q[k] = Some(self.scan(&s, k, visible));
                }
            }
            poses[b] = match (poses[j.parent], self.local(k, &s)) {
                (Some(p), Some(x)) => Some(p * x),
                _ => None,
            };
        }
        // Joints below a body with no pose: zero (their part of the tree is undetermined).
        for &b in &self.topo {
            if let Some(k) = self.link[b] {
                match self.joints[k].measure {
                    Measure::Spherical(_) => {
                        s.turn[k].get_or_insert_with(UnitQuaternion::identity);
                    }
                    Measure::Universal(..) => {
                        s.q[k].get_or_insert(0.0);
                        s.q2[k].get_or_insert(0.0);
                    }
                    _ => {
                        s.q[k].get_or_insert(0.0);
                    }
                }
            }
        }
        s
    }

    /// The position of joint `k` that best fits the visible points below it (every other
    /// joint at its value in `s`, unknown ones at zero): a scan of twelve angles for a
    /// revolute joint, zero for a prismatic one (its residuals are linear in the position).
    fn scan(&self, s: &State, k: usize, visible: &Visible) -> f64 {
        let Measure::Revolute(..) = self.joints[k].measure else {
            return 0.0;
        };
        let col = self.joint_col[k];
        let below: Vec<usize> = self
            .topo
            .iter()
            .copied()
            .filter(|&d| col.is_some_and(|c| self.cols[d].contains(&c)))
            .collect();
        let mut trial = s.clone();
        for q in &mut trial.q {
            q.get_or_insert(0.0);
        }
        for t in &mut trial.turn {
            t.get_or_insert_with(UnitQuaternion::identity);
        }
        for q in &mut trial.q2 {
            q.get_or_insert(0.0);
        }
        let mut best = (f64::INFINITY, 0.0);
        for i in 0..12 {
            let c = f64::from(i) * PI_6 - PI_6 * 5.0;
            trial.q[k] = Some(c);
            let poses = self.forward(&trial);
            let e: f64 = below
                .iter()
                .filter_map(|&d| poses[d].map(|p| miss(&p, &visible[d])))
                .sum();
            if e < best.0 {
                best = (e, c);
            }
        }
        best.1
    }

    /// Sum of squared residuals over the points whose body has a pose (`poses` from
    /// [`Observer::forward`]).
    fn cost(poses: &[Option<Isometry3<f64>>], visible: &Visible) -> f64 {
        poses
            .iter()
            .zip(visible.iter())
            .filter_map(|(p, v)| p.map(|p| miss(&p, v)))
            .sum()
    }

    /// Normal equations of the fit at the body poses `poses`, with coordinates taken about
    /// the centroid of the visible points (better conditioned than about the camera).
    pub(crate) fn linearise(
        &self,
        poses: &[Option<Isometry3<f64>>],
        visible: &Visible,
        scratch: &mut Scratch,
    ) -> Option<Linear> {
        let (mut total, mut count) = (Vector3::zeros(), 0usize);
        for (_, v) in poses
            .iter()
            .zip(visible.iter())
            .filter(|(p, _)| p.is_some())
        {
            total += v.iter().map(|(_, o)| o.coords).sum::<Vector3<f64>>();
            count += v.len();
        }
        if count == 0 {
            return None;
        }
        let origin = total / count as f64;
        // The motion (v, w) of every parameter: a point p moves by v + w x (p - origin).
        let Scratch {
            twist,
            info,
            grad,
            points,
        } = scratch;
        twist.clear();
        twist.resize(self.n_params, Vector6::zeros());
        for &b in &self.topo {
            match self.link[b] {
                None => {
                    if let Some(c) = self.free_col[b] {
                        for i in 0..3 {
                            twist[c + i][i] = 1.0;
                            twist[c + 3 + i][3 + i] = 1.0;
                        }
                    }
                }
                Some(k) => {
                    let j = &self.joints[k];
                    let (Some(c), Some(parent)) = (self.joint_col[k], poses[j.parent]) else {
                        continue;
                    };
                    let turning = |w: Vector3<f64>, pivot: &Point3<f64>| {
                        let at = (parent * pivot).coords - origin;
                        let v = at.cross(&w);
                        Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z)
                    };
                    match j.measure {
                        Measure::Revolute(axis, pivot) => {
                            twist[c] = turning(parent.rotation * axis, &pivot);
                        }
                        Measure::Prismatic(axis) => {
                            let v = parent.rotation * axis;
                            twist[c] = Vector6::new(v.x, v.y, v.z, 0.0, 0.0, 0.0);
                        }
                        // A turn about each of the parent's axes through the centre.
                        Measure::Spherical(centre) => {
                            for (i, t) in twist[c..c + 3].iter_mut().enumerate() {
                                *t = turning(parent.rotation * Vector3::ith(i, 1.0), &centre);
                            }
                        }
                        // A turn about the first axis, fixed in the parent, and one about
                        // the second where the first angle has carried it (the child's own).
                        Measure::Universal(first, second, centre) => {
                            twist[c] = turning(parent.rotation * first, &centre);
                            let in_child = j.reference.rotation.inverse() * second;
                            let now = poses[j.child]
                                .map_or(parent.rotation * second, |p| p.rotation * in_child);
                            twist[c + 1] = turning(now, &centre);
                        }
                        Measure::None => twist[c] = Vector6::zeros(),
                    }
                }
            }
        }
        // Each body's 6 x 6 information [[n I, -[S]x], [[S]x, sum(|p|^2 I - p p^T)]] and
        // gradient (sum r, sum p x r), p about the origin, r = observed - predicted; then
        // summed over every body a parameter moves (its subtree in the fit).
        let nb = self.bodies.len();
        info.clear();
        info.resize(nb, Matrix6::zeros());
        grad.clear();
        grad.resize(nb, Vector6::zeros());
        points.clear();
        points.resize(nb, 0);
        for (b, pose) in poses.iter().enumerate() {
            let Some(pose) = pose else { continue };
            let m = &visible.moments[b];
            (info[b], grad[b]) = m.information(pose, &origin);
            points[b] = m.n;
        }
        for &b in self.topo.iter().rev() {
            if let Some(k) = self.link[b] {
                let a = self.joints[k].parent;
                let (h, g, n) = (info[b], grad[b], points[b]);
                info[a] += h;
                grad[a] += g;
                points[a] += n;
            }
        }
        // A parameter of body b moves b's subtree; the normal matrix entry with a parameter
        // above it (or its own) is its twist against the subtree's information times the
        // other's twist. Parameters on different branches share no point.
        let n = self.n_params;
        let mut normal = DMatrix::<f64>::zeros(n, n);
        let mut rhs = DVector::<f64>::zeros(n);
        let mut seen = vec![false; n];
        for &b in &self.topo {
            if points[b] == 0 {
                continue;
            }
            let own: &[usize] = match self.link[b] {
                None => &self.cols[b][..],
                Some(k) => &self.cols[b][self.cols[b].len() - self.joints[k].measure.width()..],
            };
            for &c in own {
                let moved = info[b] * twist[c];
                seen[c] = true;
                rhs[c] = twist[c].dot(&grad[b]);
                for &other in &self.cols[b] {
                    let v = moved.dot(&twist[other]);
                    normal[(c, other)] = v;
                    normal[(other, c)] = v;
                }
            }
        }
        Some(Linear {
            normal,
            rhs,
            seen,
            origin,
        })
    }

    /// The model's noise level in units of 1 mm (of the tracks' length unit). The fit's length
    /// tolerances ([`STEP_TOLERANCE`], `PositionLimits::max_std_m`) were set for 1 mm of noise and scale
    /// with it, so a model in millimetres (noise 1, not 0.001) fits to the same relative
    /// precision and decides the same: with fixed tolerances in metres, the invariance tests
    /// found a mechanism whose tree changed when its tracks were given in millimetres.
    fn length_unit(&self) -> f64 {
        let u = self.sigma / 1e-3;
        if u.is_finite() && u > 0.0 { u } else { 1.0 }
    }

    /// The largest component of a descent step, lengths in [`Observer::length_unit`]s and
    /// angles in radians.
    fn step_size(&self, step: &DVector<f64>) -> f64 {
        let unit = self.length_unit();
        let mut size: f64 = 0.0;
        for c in self.free_col.iter().flatten() {
            for i in 0..3 {
                size = size
                    .max(step[c + i].abs() / unit)
                    .max(step[c + 3 + i].abs());
            }
        }
        for (k, c) in self.joint_col.iter().enumerate() {
            let Some(c) = *c else { continue };
            let measure = self.joints[k].measure;
            for i in 0..measure.width() {
                let v = step[c + i].abs();
                size = size.max(match measure {
                    Measure::Revolute(..) | Measure::Spherical(..) | Measure::Universal(..) => v,
                    _ => v / unit,
                });
            }
        }
        size
    }

    /// `s` moved by `step` (free poses turned about `origin`), into `out`.
    fn apply(&self, s: &State, step: &DVector<f64>, origin: &Vector3<f64>, out: &mut State) {
        out.free.clone_from(&s.free);
        out.q.clone_from(&s.q);
        out.turn.clone_from(&s.turn);
        out.q2.clone_from(&s.q2);
        for (b, free) in out.free.iter_mut().enumerate() {
            let (Some(c), Some(pose)) = (self.free_col[b], free.as_mut()) else {
                continue;
            };
            let dt = Vector3::new(step[c], step[c + 1], step[c + 2]);
            let dw = Vector3::new(step[c + 3], step[c + 4], step[c + 5]);
            let delta = Translation3::from(origin + dt)
                * UnitQuaternion::from_scaled_axis(dw)
                * Translation3::from(-origin);
            *pose = delta * *pose;
        }
        for (k, q) in out.q.iter_mut().enumerate() {
            if let (Some(c), Some(v)) = (self.joint_col[k], q.as_mut()) {
                *v += step[c];
            }
        }
        for (k, q) in out.q2.iter_mut().enumerate() {
            if let (Some(c), Some(v)) = (self.joint_col[k], q.as_mut()) {
                *v += step[c + 1];
            }
        }
        // A spherical joint's step turns the child about the parent's axes (see `linearise`).
        for (k, t) in out.turn.iter_mut().enumerate() {
            if let (Some(c), Some(turn)) = (self.joint_col[k], t.as_mut()) {
                let w = Vector3::new(step[c], step[c + 1], step[c + 2]);
                *turn = UnitQuaternion::from_scaled_axis(w) * *turn;
            }
        }
    }

    /// The fit's outputs, with every position's standard deviation from the normal matrix.
    fn report(&self, d: &Descent, visible: &Visible) -> FrameFit {
        let variance = d.lin.as_ref().map(|l| l.marginal_variances(&self.pattern));
        let determined = |c: usize| {
            variance
                .as_ref()
                .and_then(|v| v[c])
                .is_some_and(|(_, inflation)| inflation <= MAX_VARIANCE_INFLATION)
        };
        let mut std = vec![None; self.joints.len()];
        let mut positions = vec![None; self.joints.len()];
        let mut rotations = vec![None; self.joints.len()];
        let mut rotation_std = vec![None; self.joints.len()];
        let mut angles = vec![None; self.joints.len()];
        let mut angle_std = vec![None; self.joints.len()];
        for (k, j) in self.joints.iter().enumerate() {
            let Some(c) = self.joint_col[k] else { continue };
            if let Measure::Universal(..) = j.measure {
                let Some(var) = variance.as_ref() else {
                    continue;
                };
                let (Some((v1, _)), Some((v2, _))) = (var[c], var[c + 1]) else {
                    continue;
                };
                let sd = [self.sigma * v1.sqrt(), self.sigma * v2.sqrt()];
                angle_std[k] = Some(sd);
                if (c..c + 2).all(determined) && sd.iter().all(|&v| v <= self.limits.max_std_rad) {
                    angles[k] = d.state.q[k].zip(d.state.q2[k]).map(|(a, b)| [a, b]);
                }
                continue;
            }
            if let Measure::Spherical(_) = j.measure {
                let Some(var) = variance.as_ref() else {
                    continue;
                };
                let sd: Option<Vec<f64>> = (c..c + 3)
                    .map(|i| var[i].map(|(v, _)| self.sigma * v.sqrt()))
                    .collect();
                let Some(sd) = sd else { continue };
                let sd = [sd[0], sd[1], sd[2]];
                rotation_std[k] = Some(sd);
                if (c..c + 3).all(determined) && sd.iter().all(|&v| v <= self.limits.max_std_rad) {
                    rotations[k] = d.state.turn[k].map(|t| {
                        let v = t.scaled_axis();
                        [v.x, v.y, v.z]
                    });
                }
                continue;
            }
            let Some((var, _)) = variance.as_ref().and_then(|v| v[c]) else {
                continue;
            };
            let sd = self.sigma * var.sqrt();
            std[k] = Some(sd);
            let limit = match j.measure {
                Measure::Revolute(..) => self.limits.max_std_rad,
                _ => self.limits.max_std_m * self.length_unit(),
            };
            if determined(c) && sd <= limit {
                positions[k] = d.state.q[k];
            }
        }
        let poses: Vec<Option<Isometry3<f64>>> = d
            .poses
            .iter()
            .enumerate()
            .map(|(b, p)| p.filter(|_| self.cols[b].iter().all(|&c| determined(c))))
            .collect();
        // Joints outside the fit (freed, see `free_joint`): from the two fitted poses.
        for (k, j) in self.joints.iter().enumerate() {
            if self.joint_col[k].is_none()
                && let (Some(a), Some(b)) = (poses[j.parent], poses[j.child])
            {
                positions[k] = Self::measure(j, &(a.inverse() * b));
                rotations[k] = Self::measure_rotation(j, &(a.inverse() * b));
                angles[k] = Self::measure_angles(j, &(a.inverse() * b));
            }
        }
        let n_points = posed_points(d, visible);
        FrameFit {
            positions,
            std,
            rotations,
            rotation_std,
            angles,
            angle_std,
            poses,
            n_points,
            sum_sq_m2: d.cost,
        }
    }

    /// Per body, the precision of its pose in a converged frame fit (`None` where the body has
    /// no pose or the frame's normal equations are singular), in the per-body pose
    /// estimator's terms ([`PoseQuality`]): the covariance of the body's pose error from the
    /// inverse normal matrix of every parameter that moves it, per unit noise variance; its
    /// own visible points and their RMS residual.
    ///
    /// A body posed through its joint needs no three visible points of its own, and its pose
    /// is as precise as its parent's, its position and their points make it: a body hidden
    /// by its neighbours in most frames gets poses, with their precision, where the
    /// per-body estimator has none.
    pub(crate) fn pose_qualities(
        &self,
        descent: &Descent,
        visible: &Visible,
        scratch: &mut Scratch,
    ) -> Vec<Option<PoseQuality>> {
        let nb = self.bodies.len();
        let Some(lin) = self.linearise(&descent.poses, visible, scratch) else {
            return vec![None; nb];
        };
        // Parameters no point depends on are pinned (a unit diagonal); a body's covariance
        // needs the inverse only between parameters on one path.
        let Some(factor) = lin.damped_factor(0.0, &self.pattern) else {
            return vec![None; nb];
        };
        let inverse = factor.inverse();
        (0..nb)
            .map(|b| {
                let pose = descent.poses[b]?;
                let cols = &self.cols[b];
                if cols.iter().any(|&c| !lin.seen[c]) {
                    return None;
                }
                // The body's motion (v, w) about the origin is the sum of its parameters'.
                let mut cov = Matrix6::<f64>::zeros();
                for &c in cols {
                    for &d in cols {
                        let n_cd = inverse.entry(c, d).unwrap_or(0.0);
                        cov += scratch.twist[c] * scratch.twist[d].transpose() * n_cd;
                    }
                }
                let r = pose.rotation.to_rotation_matrix();
                let w = cov.fixed_view::<3, 3>(3, 3).into_owned();
                let lever = (pose.translation.vector - lin.origin).cross_matrix();
                // The origin moves by v + w x (t - origin) = v - [t - origin]x w.
                let mut jacobian = kinetree_core::nalgebra::Matrix3x6::<f64>::zeros();
                jacobian
                    .fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&Matrix3::identity());
                jacobian.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-lever));
                let origin = jacobian * cov * jacobian.transpose();
                let rot_cov = r.transpose() * w * r;
                let origin_cov = r.transpose() * origin * r;
                let own = &visible[b];
                let rms = if own.is_empty() {
                    0.0
                } else {
                    (miss(&pose, own) / own.len() as f64).sqrt()
                };
                Some(PoseQuality::from_covariances(
                    own.len(),
                    rms,
                    rot_cov,
                    origin_cov,
                ))
            })
            .collect()
    }

    /// How far the fit misses each joint's child, beyond what the child's own pose misses:
    /// over the frames where the child has three or more visible points, the sum of its
    /// points' squared residuals in `fits` minus that of its own Kabsch-Umeyama pose, per
    /// point, in units of the model's noise variance. A joint the model describes well gives
    /// about 6 / (points of the child) plus its axis and pivot errors times the motion (under
    /// 1 on random mechanisms); a joint whose child does not move as the model says, tens to
    /// thousands. `None` for joints outside the fit or with no such frame.
    ///
    /// # Errors
    /// [`Error::Shape`] when the tracks or fits do not match the model.
    pub fn joint_excess(&self, tracks: &Tracks, fits: &[FrameFit]) -> Result<Vec<Option<f64>>> {
        if tracks.n_points() != self.n_points || fits.len() != tracks.n_frames() {
            return Err(Error::Shape {
                expected: format!("{} points and one fit per frame", self.n_points),
                found: format!(
                    "{} points, {} frames and {} fits",
                    tracks.n_points(),
                    tracks.n_frames(),
                    fits.len()
                ),
            });
        }
        let mut excess = vec![(0.0, 0usize); self.joints.len()];
        for (t, fit) in fits.iter().enumerate() {
            let frame = tracks.frame_points(t);
            let visible = self.visible(&frame);
            for (k, j) in self.joints.iter().enumerate() {
                if self.joint_col[k].is_none() {
                    continue;
                }
                let v = &visible[j.child];
                let (Some(pose), Some(own)) =
                    (fit.poses.get(j.child).copied().flatten(), own_pose(v))
                else {
                    continue;
                };
                excess[k].0 += miss(&pose, v) - miss(&own, v);
                excess[k].1 += v.len();
            }
        }
        let var = self.sigma * self.sigma;
        Ok(excess
            .into_iter()
            .map(|(e, n)| (n > 0 && var > 0.0).then(|| e / (n as f64 * var)))
            .collect())
    }

    /// RMS distance, in units of `sigma`, between every observed keypoint and its position
    /// predicted by the model fitted to its frame ([`Observer::fit_sequence`]): about 1.2-1.6
    /// when the model is right, more with axis or pivot errors, far more with a wrong joint.
    /// `None` with no usable frame.
    ///
    /// # Errors
    /// [`Error::Shape`] when the tracks do not have the model's points.
    pub fn reprediction_rms_in_sigma(&self, tracks: &Tracks, sigma: f64) -> Result<Option<f64>> {
        if tracks.n_points() != self.n_points {
            return Err(Error::Shape {
                expected: format!("{} points", self.n_points),
                found: format!("{} points", tracks.n_points()),
            });
        }
        Ok(rms_in_sigma(&self.fit_sequence(tracks)?, sigma))
    }
}

/// The visible keypoints of the bodies descent `d` poses: the ones its residual sums.
fn posed_points(d: &Descent, visible: &Visible) -> usize {
    d.poses
        .iter()
        .zip(visible.iter())
        .filter(|(p, _)| p.is_some())
        .map(|(_, v)| v.len())
        .sum()
}

/// A frame's fit started from the previous frame's values is kept without a second start
/// from the frame's own poses when its squared residual, in noise variances, is within its
/// degrees of freedom plus this many standard deviations of their chi-square
/// (`docs/decisions.md`, `kinetree_fit::WITHIN_NOISE_IN_STD`).
const WITHIN_NOISE_IN_STD: f64 = 3.0;
/// Gauss-Newton iterations per start, at most (two to four are typical).
const MAX_ITERATIONS: usize = 30;
/// A step whose largest component (metres at 1 mm of noise, see [`Observer::length_unit`], or
/// radians) is below this ends the descent: near the solution each step is at most about 1 %
/// of the one before, so the state is then within about a micron or microradian of the
/// minimum, far below any noise (`docs/decisions.md`, `kinetree_fit::STEP_TOLERANCE`).
const STEP_TOLERANCE: f64 = 1e-4;
/// The descent also ends when the next step, predicted as `s_k^2 / s_(k-1)` from the last two
/// step sizes, is below this (as [`STEP_TOLERANCE`]): the actual next step is smaller than
/// the prediction (`docs/decisions.md`, `kinetree_fit::PREDICTED_STEP_TOLERANCE`).
const PREDICTED_STEP_TOLERANCE: f64 = 1e-5;

/// The position of single-DoF joint `j` that best carries its child's visible points onto
/// their observations, the parent posed at `parent` (`camera_from_parent`): least squares in
/// closed form. Revolute: with `a` the model's points and `b` the observations, both in the
/// parent's frame relative to the pivot, `atan2(sum u . (a x b), sum a_perp . b_perp)`;
/// prismatic: the mean of `u . (b - a)`. `None` without visible points, or when the points
/// lie within three noise std-devs of a revolute axis (the angle is then undetermined).
///
/// It replaces per-body Kabsch-Umeyama poses as the start of a joint: it needs no three
/// non-collinear points, uses the parent's pose (itself fitted on more points for most
/// joints), and costs no SVD.
pub(crate) fn best_position(
    j: &ObservedJoint,
    parent: &Isometry3<f64>,
    visible: &[(Point3<f64>, Point3<f64>)],
    sigma: f64,
) -> Option<f64> {
    if visible.is_empty() {
        return None;
    }
    match j.measure {
        Measure::Revolute(axis, pivot) => {
            let (mut sin, mut cos, mut lever) = (0.0, 0.0, 0.0);
            for (sp, o) in visible {
                let a = (j.reference * sp) - pivot;
                let b = parent.inverse_transform_point(o) - pivot;
                let a_perp = a - axis * axis.dot(&a);
                let b_perp = b - axis * axis.dot(&b);
                sin += axis.dot(&a_perp.cross(&b_perp));
                cos += a_perp.dot(&b_perp);
                lever += a_perp.norm() * b_perp.norm();
            }
            (lever > 9.0 * sigma * sigma).then(|| sin.atan2(cos))
        }
        Measure::Prismatic(axis) => {
            let sum: f64 = visible
                .iter()
                .map(|(sp, o)| axis.dot(&(parent.inverse_transform_point(o) - j.reference * sp)))
                .sum();
            Some(sum / visible.len() as f64)
        }
        Measure::Spherical(_) | Measure::Universal(..) | Measure::None => None,
    }
}

/// The two angles `(q1, q2)` of the rotation `turn = R(first, q1) R(second, q2)` (axes in one
/// frame): `q1` turns `second` about `first` to where `turn` takes it, and `q2` is what is
/// left, the twist about `second`. A rotation outside that family gives the nearest pair.
pub(crate) fn universal_angles(
    turn: &UnitQuaternion<f64>,
    first: &Vector3<f64>,
    second: &Vector3<f64>,
) -> [f64; 2] {
    let across = |v: Vector3<f64>| v - first * first.dot(&v);
    let (from, to) = (across(*second), across(turn * second));
    let q1 = first.dot(&from.cross(&to)).atan2(from.dot(&to));
    let rest = UnitQuaternion::from_axis_angle(&Unit::new_unchecked(*first), -q1) * turn;
    [q1, angle_about(&rest, second)]
}

/// A spherical joint's rotation from `previous`, when it has one.
fn previous_turn(previous: Option<&FrameFit>, k: usize) -> Option<UnitQuaternion<f64>> {
    let v = previous?.rotations.get(k).copied().flatten()?;
    Some(UnitQuaternion::from_scaled_axis(vector(v)))
}

/// The rotation about `centre` (parent's frame) that best carries spherical joint `j`'s
/// visible child points onto their observations, given the parent's pose: the orthogonal
/// Procrustes rotation of the points about the centre (two points not in line with it
/// suffice). `None` when the points do not fix it.
fn best_turn(
    j: &ObservedJoint,
    centre: &Point3<f64>,
    parent: &Isometry3<f64>,
    visible: &[(Point3<f64>, Point3<f64>)],
    sigma: f64,
) -> Option<UnitQuaternion<f64>> {
    let mut h = Matrix3::zeros();
    for (sp, o) in visible {
        let a = (j.reference * sp) - centre;
        let b = parent.inverse_transform_point(o) - centre;
        h += b * a.transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // Two independent directions are needed (the third follows); below the noise they are
    // not.
    let mut values = svd.singular_values;
    values.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if values[1] <= 9.0 * sigma * sigma {
        return None;
    }
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = kinetree_core::nalgebra::Rotation3::from_matrix_unchecked(u * d * v_t);
    Some(UnitQuaternion::from_rotation_matrix(&r))
}

/// A body's pose from its own visible points alone (Kabsch-Umeyama), `None` with fewer than
/// three or collinear ones.
fn own_pose(visible: &[(Point3<f64>, Point3<f64>)]) -> Option<Isometry3<f64>> {
    let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = visible.iter().copied().unzip();
    kabsch_with_rank_check(&src, &dst, 1e-6)
}

/// Sum of squared distances between `pose` applied to the shape points and the observations.
fn miss(pose: &Isometry3<f64>, visible: &[(Point3<f64>, Point3<f64>)]) -> f64 {
    // One rotation matrix per body: cheaper per point than rotating by the quaternion.
    let rotation = pose.rotation.to_rotation_matrix();
    let t = pose.translation.vector;
    visible
        .iter()
        .map(|(s, o)| (rotation * s.coords + t - o.coords).norm_squared())
        .sum()
}

const PI_6: f64 = std::f64::consts::PI / 6.0;

/// One frame's visible placed points, `(shape point, observation)`, body by body
/// (`visible[b]` is body `b`'s).
#[derive(Debug, Clone)]
pub(crate) struct Visible {
    pairs: Vec<(Point3<f64>, Point3<f64>)>,
    /// End of each body's run in `pairs`.
    end: Vec<usize>,
    /// Per body, the moments of its pairs.
    moments: Vec<Moments>,
}

/// Sums over one body's visible pairs `(s, o)` (shape point, observation), from which the
/// linearisation's per-body information and gradient follow at any pose in a few 3 x 3
/// products instead of a pass over the points (which was a fifth of a frame's fit).
#[derive(Debug, Clone, Copy)]
struct Moments {
    n: usize,
    /// `sum s`.
    shape: Vector3<f64>,
    /// `sum o`.
    observed: Vector3<f64>,
    /// `sum s s^T`.
    shape_outer: Matrix3<f64>,
    /// `sum s o^T`.
    cross: Matrix3<f64>,
}

impl Moments {
    fn of(pairs: &[(Point3<f64>, Point3<f64>)]) -> Self {
        let mut m = Self {
            n: pairs.len(),
            shape: Vector3::zeros(),
            observed: Vector3::zeros(),
            shape_outer: Matrix3::zeros(),
            cross: Matrix3::zeros(),
        };
        for (s, o) in pairs {
            m.shape += s.coords;
            m.observed += o.coords;
            m.shape_outer += s.coords * s.coords.transpose();
            m.cross += s.coords * o.coords.transpose();
        }
        m
    }

    /// The body's 6 x 6 information `[[n I, -[S]x], [[S]x, sum(|p|^2 I - p p^T)]]` and
    /// gradient `(sum r, sum p x r)` at `pose`, with `p = pose * s - origin` and
    /// `r = o - origin - p`: the normal-equation blocks of a motion `(v, w)` that moves `p` by
    /// `v + w x p`.
    fn information(
        &self,
        pose: &Isometry3<f64>,
        origin: &Vector3<f64>,
    ) -> (Matrix6<f64>, Vector6<f64>) {
        // sum p = R sum s + n shift, sum p p^T expands likewise; sum r = sum o - n origin -
        // sum p; sum p x r = sum p x (o - origin), whose R s x o part is the antisymmetric
        // part of R sum s o^T.
        let nf = self.n as f64;
        let rotation = pose.rotation.to_rotation_matrix();
        let shift = pose.translation.vector - origin;
        let turned = rotation * self.shape;
        let sum = turned + shift * nf;
        let outer = rotation * self.shape_outer * rotation.transpose()
            + turned * shift.transpose()
            + shift * turned.transpose()
            + shift * shift.transpose() * nf;
        let inertia = Matrix3::identity() * outer.trace() - outer;
        let force = self.observed - origin * nf - sum;
        let a = rotation * self.cross;
        let torque = Vector3::new(
            a[(1, 2)] - a[(2, 1)],
            a[(2, 0)] - a[(0, 2)],
            a[(0, 1)] - a[(1, 0)],
        ) - turned.cross(origin)
            + shift.cross(&(self.observed - origin * nf));
        let cross = sum.cross_matrix();
        let mut h = Matrix6::zeros();
        h.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(Matrix3::identity() * nf));
        h.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-cross));
        h.fixed_view_mut::<3, 3>(3, 0).copy_from(&cross);
        h.fixed_view_mut::<3, 3>(3, 3).copy_from(&inertia);
        let g = Vector6::new(force.x, force.y, force.z, torque.x, torque.y, torque.z);
        (h, g)
    }
}

impl Visible {
    /// Every body's pairs, in body order.
    fn iter(&self) -> impl Iterator<Item = &[(Point3<f64>, Point3<f64>)]> {
        (0..self.end.len()).map(|b| &self[b])
    }
}

impl std::ops::Index<usize> for Visible {
    type Output = [(Point3<f64>, Point3<f64>)];

    fn index(&self, b: usize) -> &Self::Output {
        let start = if b == 0 { 0 } else { self.end[b - 1] };
        &self.pairs[start..self.end[b]]
    }
}

/// Per-iteration buffers of [`Observer::linearise`].
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    /// The motion of every parameter.
    pub(crate) twist: Vec<Vector6<f64>>,
    /// Per body, its information and gradient, then summed over its subtree.
    pub(crate) info: Vec<Matrix6<f64>>,
    pub(crate) grad: Vec<Vector6<f64>>,
    /// Per body, its visible points, then summed over its subtree.
    points: Vec<usize>,
}

/// The end of one descent ([`Observer::descend`]).
#[derive(Debug, Clone)]
pub(crate) struct Descent {
    pub(crate) state: State,
    /// Body poses of `state` ([`Observer::forward`]).
    pub(crate) poses: Vec<Option<Isometry3<f64>>>,
    /// The last linearisation, a converged step from `state`; `None` when no point is used.
    lin: Option<Linear>,
    /// Sum of squared residuals of `state` ([`Observer::cost`]).
    pub(crate) cost: f64,
}

/// Normal equations `N x = g` of one linearisation.
#[derive(Debug, Clone)]
pub(crate) struct Linear {
    pub(crate) normal: DMatrix<f64>,
    pub(crate) rhs: DVector<f64>,
    /// Parameters some visible point depends on.
    pub(crate) seen: Vec<bool>,
    pub(crate) origin: Vector3<f64>,
}

impl Linear {
    /// The damped step `(N + lambda diag N) x = g`; parameters no point depends on stay.
    /// `pattern` is the observer's [`Observer::pattern`].
    fn solve(&self, lambda: f64, pattern: &TreePattern) -> Option<DVector<f64>> {
        let step = self.damped_factor(lambda, pattern)?.solve(&self.rhs);
        step.iter().all(|x| x.is_finite()).then_some(step)
    }

    /// The factor of `N + lambda diag N`, with parameters no point depends on pinned (a unit
    /// diagonal); `None` when it is not positive definite.
    pub(crate) fn damped_factor<'a>(
        &self,
        lambda: f64,
        pattern: &'a TreePattern,
    ) -> Option<TreeCholesky<'a>> {
        let diagonal: Vec<f64> = (0..self.normal.nrows())
            .map(|i| {
                let d = self.normal[(i, i)];
                if self.seen[i] && d > 0.0 {
                    d * (1.0 + lambda)
                } else {
                    1.0
                }
            })
            .collect();
        TreeCholesky::with_diagonal(&self.normal, &diagonal, pattern)
    }

    /// Per parameter, its variance in units of the noise variance and its variance
    /// inflation (the variance times the parameter's own information); `None` for parameters
    /// no point depends on. A ridge of `1e-12` of each diagonal entry keeps exact dependencies
    /// factorable; such parameters come out with a huge inflation.
    fn marginal_variances(&self, pattern: &TreePattern) -> Vec<Option<(f64, f64)>> {
        let n = self.normal.nrows();
        let Some(factor) = self.damped_factor(1e-12, pattern) else {
            return vec![None; n];
        };
        let inverse = factor.inverse();
        (0..n)
            .map(|i| {
                let d = self.normal[(i, i)];
                (self.seen[i] && d > 0.0).then(|| {
                    let var = inverse.diagonal(i);
                    (var, var * d)
                })
            })
            .collect()
    }
}

/// RMS residual of a sequence of fits over all their points, in units of `sigma`.
pub(crate) fn rms_in_sigma(fits: &[FrameFit], sigma: f64) -> Option<f64> {
    let count: usize = fits.iter().map(|f| f.n_points).sum();
    let sum: f64 = fits.iter().map(|f| f.sum_sq_m2).sum();
    (count > 0 && sigma > 0.0).then(|| (sum / count as f64).sqrt() / sigma)
}

/// Frames per parallel chunk of [`Observer::replay_sequence_with`]: enough to outweigh the
/// copy of the last known values each chunk starts from.
const REPLAY_CHUNK: usize = 256;

/// Folds a frame's fit into the last known values of the frames before it: every entry the
/// fit has replaces the one before (the first fit is taken whole).
fn remember(warm: &mut Option<FrameFit>, fit: &FrameFit) {
    let Some(w) = warm else {
        *warm = Some(fit.clone());
        return;
    };
    fn keep<T: Copy>(into: &mut [Option<T>], from: &[Option<T>]) {
        for (a, b) in into.iter_mut().zip(from) {
            if b.is_some() {
                *a = *b;
            }
        }
    }
    keep(&mut w.positions, &fit.positions);
    keep(&mut w.rotations, &fit.rotations);
    keep(&mut w.angles, &fit.angles);
    keep(&mut w.poses, &fit.poses);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hand-written diagonal of the inverse agrees with nalgebra's whole inverse.
    #[test]
    fn marginal_variances_are_the_inverse_diagonal() {
        let n = 7;
        // A symmetric positive definite matrix with a wide range of scales.
        let a = DMatrix::<f64>::from_fn(n, n, |i, k| ((i * 7 + k * 3) % 11) as f64 - 5.0);
        let mut normal = &a * a.transpose() + DMatrix::<f64>::identity(n, n);
        normal[(2, 2)] *= 1e6;
        let lin = Linear {
            normal: normal.clone(),
            rhs: DVector::zeros(n),
            seen: vec![true; n],
            origin: Vector3::zeros(),
        };
        let inverse = normal.clone().cholesky().expect("spd").inverse();
        // A chain's pattern is the whole lower triangle: a dense matrix fits it.
        let chain: Vec<Option<usize>> = (0..n).map(|i| i.checked_sub(1)).collect();
        let pattern = TreePattern::new(&chain).expect("parents first");
        for (i, v) in lin.marginal_variances(&pattern).iter().enumerate() {
            let (var, inflation) = v.expect("seen");
            assert!((var / inverse[(i, i)] - 1.0).abs() < 1e-9, "{i}: {var}");
            assert!((inflation - inverse[(i, i)] * normal[(i, i)]).abs() < 1e-6 * inflation);
        }
    }

    /// The per-body information and gradient from the moments equal their per-point sums.
    #[test]
    fn moments_give_the_per_point_information() {
        let pairs: Vec<(Point3<f64>, Point3<f64>)> = (0..6)
            .map(|i| {
                let x = f64::from(i);
                (
                    Point3::new(0.1 * x.sin(), 0.07 * x.cos(), 0.02 * x),
                    Point3::new(0.3 + 0.01 * x, -0.2 + 0.05 * x.cos(), 2.0 + 0.03 * x.sin()),
                )
            })
            .collect();
        let pose = Isometry3::from_parts(
            Translation3::new(0.25, -0.1, 1.9),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.7, -0.2, 1.1)),
        );
        let origin = Vector3::new(0.1, 0.2, 1.5);
        let (h, g) = Moments::of(&pairs).information(&pose, &origin);
        let mut h_direct = Matrix6::zeros();
        let mut g_direct = Vector6::zeros();
        for (s, o) in &pairs {
            let p = (pose * s).coords - origin;
            let r = o.coords - origin - p;
            // The motion (v, w) moves p by v + w x p = [I, -[p]x] (v, w).
            let mut j = kinetree_core::nalgebra::Matrix3x6::zeros();
            j.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&Matrix3::identity());
            j.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&(-p.cross_matrix()));
            h_direct += j.transpose() * j;
            g_direct += j.transpose() * r;
        }
        assert!((h - h_direct).amax() < 1e-12, "{h} against {h_direct}");
        assert!((g - g_direct).amax() < 1e-12, "{g} against {g_direct}");
    }

    /// The closed-form start recovers a revolute and a prismatic position exactly from noise-
    /// free points, and gives up on points on the axis.
    #[test]
    fn best_position_is_exact_without_noise() {
        let axis = Vector3::new(1.0, 2.0, 2.0).normalize();
        let pivot = Point3::new(0.1, -0.2, 0.3);
        let reference = Isometry3::from_parts(
            Translation3::new(0.3, 0.1, -0.1),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.2, -0.4, 0.1)),
        );
        let parent = Isometry3::from_parts(
            Translation3::new(0.0, 0.5, 2.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(-1.0, 0.3, 0.5)),
        );
        let shape = [
            Point3::new(0.05, 0.0, 0.0),
            Point3::new(0.0, 0.07, 0.01),
            Point3::new(-0.02, 0.01, 0.09),
        ];
        for (measure, q) in [
            (Measure::Revolute(axis, pivot), 2.9),
            (Measure::Revolute(axis, pivot), -1.3),
            (Measure::Prismatic(axis), 0.04),
        ] {
            let j = ObservedJoint {
                parent: 0,
                child: 1,
                measure,
                reference,
            };
            let child = parent * Observer::joint_transform(&j, q);
            // One point is enough.
            for n in [1, 3] {
                let visible: Vec<_> = shape[..n].iter().map(|s| (*s, child * s)).collect();
                let found = best_position(&j, &parent, &visible, 1e-4).expect("determined");
                assert!((found - q).abs() < 1e-9, "{measure:?}: {found} against {q}");
            }
        }
        // A point on the axis says nothing about the angle.
        let j = ObservedJoint {
            parent: 0,
            child: 1,
            measure: Measure::Revolute(axis, pivot),
            reference: Isometry3::identity(),
        };
        let on_axis = pivot + axis * 0.2;
        let visible = [(on_axis, parent * on_axis)];
        assert_eq!(best_position(&j, &parent, &visible, 1e-4), None);
        assert_eq!(best_position(&j, &parent, &[], 1e-4), None);
    }
}
