//! Re-attaching discarded points to the one body whose poses explain their track.

use kinetree_core::nalgebra::{Point3, Vector3};
use kinetree_core::{BodyPoses, Segmentation, Tracks};

/// Fewest frames a point must share with a body to be scored against it.
pub const MIN_SHARED_FRAMES: usize = 3;

/// A point's track seen from a body's frame ([`point_fit`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointFit {
    /// `chi^2 / k`: about 1 for a point rigidly attached to the body.
    pub misfit: f64,
    /// Degrees of freedom `k = 3 (frames - 1)`.
    pub dof: f64,
    /// The point's place in the body frame: the weighted mean of its observations there.
    pub local: Point3<f64>,
}

/// How well body `body`'s poses explain `point` as a rigid part of it: `(chi^2 / k, k)`
/// ([`point_fit`]).
pub fn point_misfit(
    tracks: &Tracks,
    poses: &BodyPoses,
    body: usize,
    point: usize,
    sigma: f64,
) -> Option<(f64, f64)> {
    point_fit(tracks, poses, body, point, sigma).map(|f| (f.misfit, f.dof))
}

/// How well body `body`'s poses explain `point` as a rigid part of it, and where it sits.
///
/// The point's observations are mapped into the body frame, `z_t = cam_from_body(t)^-1 p(t)`,
/// and scattered about their weighted mean. The unit is the predicted variance
/// `sigma^2 (1 + trans^2 + (rot |z_t|)^2)`: the point's own noise, plus the pose's translation
/// and rotation noise at the point's lever arm. For a rigidly attached point `chi^2 / k` is
/// about 1, with `k = 3 (frames - 1)` degrees of freedom. Returns `None` with fewer than
/// [`MIN_SHARED_FRAMES`] shared frames.
pub fn point_fit(
    tracks: &Tracks,
    poses: &BodyPoses,
    body: usize,
    point: usize,
    sigma: f64,
) -> Option<PointFit> {
    let track = &poses.bodies[body];
    let mut z: Vec<(Point3<f64>, f64)> = Vec::new();
    for t in 0..poses.n_frames {
        let (Some(p), Some(pose), Some(q)) = (
            tracks.get(t, point),
            track.cam_from_body[t],
            track.quality[t],
        ) else {
            continue;
        };
        let zt = pose.inverse_transform_point(&p);
        let lever = q.rot_std_per_sigma * zt.coords.norm();
        z.push((
            zt,
            sigma * sigma * (1.0 + q.trans_std_per_sigma.powi(2) + lever * lever),
        ));
    }
    if z.len() < MIN_SHARED_FRAMES {
        return None;
    }
    let wsum: f64 = z.iter().map(|(_, v)| 1.0 / v).sum();
    let mean: Vector3<f64> = z.iter().map(|(p, v)| p.coords / *v).sum::<Vector3<f64>>() / wsum;
    let chi2: f64 = z
        .iter()
        .map(|(p, v)| (p.coords - mean).norm_squared() / v)
        .sum();
    let k = 3.0 * (z.len() - 1) as f64;
    Some(PointFit {
        misfit: chi2 / k,
        dof: k,
        local: Point3::from(mean),
    })
}

/// Upper bound on `chi^2_k / k` for a rigidly attached point: the Wilson-Hilferty quantile at
/// `z` standard deviations, times `slack` for the approximations in the predicted variance.
pub fn misfit_bound(k: f64, z: f64, slack: f64) -> f64 {
    slack * kinetree_core::stats::chi2_per_dof_quantile(k, z)
}

/// The attachment's default bound on a point's misfit: `(z, slack)` of [`misfit_bound`],
/// 4 standard deviations and slack 2.
pub const ATTACH_BOUND: (f64, f64) = (4.0, 2.0);

/// Whether body `body`'s poses explain `point` as a rigid part of it: [`point_misfit`] within
/// [`misfit_bound`] at `bound = (z, slack)` (the attachment's rule, [`ATTACH_BOUND`] by
/// default; also the pipeline's test of a point fitting no body before hinges are looked
/// for).
pub fn explains_point(
    tracks: &Tracks,
    poses: &BodyPoses,
    body: usize,
    point: usize,
    sigma: f64,
    (z, slack): (f64, f64),
) -> bool {
    point_misfit(tracks, poses, body, point, sigma)
        .is_some_and(|(m, k)| m <= misfit_bound(k, z, slack))
}

/// Which bodies [`attach_unassigned`] lets take a point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttachRule {
    /// The `(z, slack)` of [`explains_point`]'s misfit bound.
    pub bound: (f64, f64),
    /// Fewest points of its own (shared points not counted) a body needs to take one.
    pub min_own: usize,
}

/// Gives every unassigned point (seen in at least [`MIN_SHARED_FRAMES`] frames with some body)
/// to the body whose poses explain it, when exactly one body does ([`explains_point`] at
/// `rule.bound`). Assigned points are never moved. A point near a
/// joint axis can fit two bodies, and such points stay unassigned. Points in `keep_off` are
/// never attached (the pipeline's model found them fitting no body's motion), and no body
/// is given points that would make it one of the point sets in `undone` (ascending; the
/// pipeline's splits undid them). Only a body with at least `rule.min_own` points of its own
/// (shared points not counted) takes a point. Returns the new segmentation and the points
/// attached.
///
/// Why `undone`: a 4-point slider in a mechanism of 20-25 bodies, broken into two pairs by
/// the pairwise measure (`tests/tests/segmentation.rs`), had one pair fit a small
/// neighbour's poorly determined poses within the bound; the split took it off again (29
/// sigma), this attachment put it back, eight times over, and the two pairs never became
/// one body. Only the very body a split undid is refused: barring every point the split left
/// out from the body it left also refused right attachments (a point seen in 6 of 20
/// frames, left out by a split that had kept a wrong one), one run lost on the occlusion
/// sweep.
///
/// Why `rule.min_own`: a body of two markers and a point it shares is posed through a
/// joint, and its poses are loose enough away from that joint to explain a far marker on
/// skin data (a thigh of two markers took the upper arm's marker). Bodies of three or more
/// points of their own are unaffected.
///
/// Pairwise tests discard a point whose own noise happened to be high over its few visible
/// frames, because every pair it belongs to shares that noise. This test looks at the point
/// alone, against poses fitted on many points.
///
/// Complexity: O(N B T).
pub fn attach_unassigned(
    tracks: &Tracks,
    poses: &BodyPoses,
    seg: &Segmentation,
    sigma: f64,
    keep_off: &[usize],
    undone: &[Vec<usize>],
    rule: AttachRule,
) -> (Segmentation, Vec<usize>) {
    let AttachRule { bound, min_own } = rule;
    let nb = poses.bodies.len();
    let mut labels: Vec<Option<usize>> = seg.labels().to_vec();
    let mut own = vec![0usize; nb];
    for b in labels.iter().flatten() {
        if *b < nb {
            own[*b] += 1;
        }
    }
    let mut attached = Vec::new();
    for (i, label) in labels.iter_mut().enumerate() {
        if label.is_some() || keep_off.contains(&i) {
            continue;
        }
        let fitting: Vec<usize> = (0..nb)
            .filter(|&b| own[b] >= min_own && explains_point(tracks, poses, b, i, sigma, bound))
            .collect();
        if let [b] = fitting[..] {
            *label = Some(b);
            attached.push(i);
        }
    }
    // A body the attachment would make one a split undid gets none of its new points.
    let remade: Vec<Option<usize>> = attached
        .iter()
        .map(|&i| labels[i])
        .filter(|&b| {
            let members: Vec<usize> = (0..labels.len()).filter(|&p| labels[p] == b).collect();
            undone.contains(&members)
        })
        .collect();
    for &i in &attached {
        if remade.contains(&labels[i]) {
            labels[i] = None;
        }
    }
    attached.retain(|&i| labels[i].is_some());
    if attached.is_empty() {
        return (seg.clone(), attached);
    }
    // Every body keeps at least the three points it had, so no minimum size applies here.
    let mut out = Segmentation::from_raw(&labels, 1).with_shared_of(seg, &labels);
    out.discarded_groups = seg.discarded_groups_without(&attached);
    (out, attached)
}
