//! Kinematic structure: the DoF graph over bodies and the camera, the paper's chain
//! extraction, a spanning tree rooted at the static body, joints and their positions.

use kinetree_core::geom::{angle_about, relative_poses, unwrap_angles};
use kinetree_core::nalgebra::{
    Isometry3, Point3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3, Vector4,
};
use kinetree_core::{BodyPoses, JointKind, PairDof, RankTest, TreeCosts};
use petgraph::graph::{NodeIndex, UnGraph};

/// A node of the DoF graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameNode {
    /// The camera frame (the paper's F0).
    Camera,
    /// A body, by segmentation id.
    Body(usize),
}

/// The DoF graph: node 0 is the camera, node `k + 1` body `k`; each tested pair is an edge
/// whose weight indexes into `pairs`.
pub fn dof_graph(n_bodies: usize, pairs: &[PairDof]) -> UnGraph<FrameNode, usize> {
    let mut g = UnGraph::with_capacity(n_bodies + 1, pairs.len());
    g.add_node(FrameNode::Camera);
    for b in 0..n_bodies {
        g.add_node(FrameNode::Body(b));
    }
    for (i, p) in pairs.iter().enumerate() {
        let a = p.a.map_or(0, |a| a + 1);
        g.add_edge(NodeIndex::new(a), NodeIndex::new(p.b + 1), i);
    }
    g
}

/// The test of the pair `(a, b)` among `pairs`, in either direction between two bodies.
pub fn find_pair(pairs: &[PairDof], a: Option<usize>, b: usize) -> Option<&PairDof> {
    pairs
        .iter()
        .find(|p| (p.a == a && p.b == b) || (a.is_some() && p.a == Some(b) && Some(p.b) == a))
}

/// Bodies with no motion relative to the camera.
pub fn static_bodies(n_bodies: usize, pairs: &[PairDof]) -> Vec<usize> {
    (0..n_bodies)
        .filter(|&b| find_pair(pairs, None, b).is_some_and(|p| p.dof == 0))
        .collect()
}

/// The paper's chain extraction (Sec. III-B): start from a body with `f_0l = 0` (or, without
/// one, from the camera), then repeatedly step to the one unused body with a single DoF to
/// the current one. Returns the chain of bodies when it covers them all and every step was
/// unambiguous, `None` otherwise (a tree, or a structure this rule cannot order).
pub fn paper_chain(n_bodies: usize, pairs: &[PairDof]) -> Option<Vec<usize>> {
    let statics = static_bodies(n_bodies, pairs);
    let mut chain = Vec::new();
    let mut current: Option<usize> = None;
    if let [s] = statics[..] {
        chain.push(s);
        current = Some(s);
    } else if statics.len() > 1 {
        return None;
    }
    while chain.len() < n_bodies {
        let next: Vec<usize> = (0..n_bodies)
            .filter(|b| !chain.contains(b))
            .filter(|&b| find_pair(pairs, current, b).is_some_and(|p| p.dof == 1))
            .collect();
        let [b] = next[..] else { return None };
        chain.push(b);
        current = Some(b);
    }
    Some(chain)
}

/// The kinematic tree over bodies.
#[derive(Debug, Clone, PartialEq)]
pub struct Tree {
    /// The root body.
    pub root: usize,
    /// Whether the root is static relative to the camera.
    pub root_is_static: bool,
    /// Parent of every body (`None` for the root and for bodies no test links to the rest).
    pub parent: Vec<Option<usize>>,
    /// Bodies in breadth-first order from the root (children by ascending id), then any
    /// unlinked bodies.
    pub order: Vec<usize>,
}

/// Edge cost for the spanning tree: single-DoF joints first, the clearest fits over the most
/// of their frames first (the fit ratio plus the share of frames the test missed, see
/// [`missed_share`], halved: 1-2); then multi-DoF pairs by their number of DoF and, among
/// those with as many, the one whose motion beyond its largest translation and rotation is
/// smallest (the nearest to a joint). Without that last term, equal costs left the choice to
/// the order of the edges, which follows the numbering of the points. A spherical joint (a
/// centre fixed in both bodies) costs 4-5, by its fit and missed share as a single-DoF
/// joint: below the multi-DoF edges of two DoF a ball between two siblings turning about
/// one anchor took a hidden link from its parent. A universal joint (two intersecting axes)
/// costs [`TreeCosts::universal_cost`] more than its fit and missed share, 2.5-3.5 by
/// default.
fn edge_cost(p: &PairDof, missed: f64, costs: &TreeCosts) -> f64 {
    let fit = (p.fit_ratio.min(0.999) + missed) / 2.0;
    if p.joint.is_single_dof() {
        1.0 + fit
    } else if let JointKind::Universal { .. } = p.joint {
        costs.universal_cost + fit
    } else if let JointKind::Spherical { .. } = p.joint {
        4.0 + fit
    } else {
        let extra: f64 = [&p.translation.whitened, &p.rotation.whitened]
            .iter()
            .flat_map(|w| w.iter().skip(1))
            .filter(|v| v.is_finite())
            .sum();
        1.0 + p.dof.max(1) as f64 + extra / (1.0 + extra)
    }
}

/// The share of the frames where both bodies could be posed that the pair's test did not
/// see (`seen`: frames posed of the less often posed body), 0-1, added to the edge's cost.
///
/// A test over few frames passes more easily: its bound is wider while a true joint's residual
/// per degree of freedom is the same, so its fit ratio is smaller. On the mechanisms sweep's
/// trees two siblings turning about one anchor, over the 23 frames both were posed, passed
/// for a hinge with fit ratio 0.13, while one sibling's true joint with the base, over the
/// 110 frames it was posed, had 0.26 (residuals 0.71 and 0.70 per degree of freedom); the
/// tree took the siblings' edge and the fit followed it.
fn missed_share(p: &PairDof, seen: usize) -> f64 {
    if seen == 0 {
        return 0.0;
    }
    1.0 - (p.translation.n_columns as f64 / seen as f64).min(1.0)
}

/// Spanning tree over bodies rooted at the static body (the one posed in the most frames if
/// several, then the lowest-numbered), a subject moving freely past it hung by the subject's
/// own root (`hang_subjects_by_their_root`);
/// without a static body, at a body on a single-DoF joint with the camera (an arm's first link
/// on an unseen base), else at a centre of the largest tree (fewest edges to its farthest
/// body), the one that turns least among several.
/// Prefers single-DoF edges with the best fit, then near pairs, as `costs` weighs them
/// (minimum spanning tree on `edge_cost`-style costs, computed by petgraph's Kruskal).
pub fn spanning_tree(n_bodies: usize, pairs: &[PairDof], costs: &TreeCosts) -> Option<Tree> {
    spanning_tree_without(n_bodies, pairs, &[], costs)
}

/// [`spanning_tree`] with the edges between the body pairs in `excluded` (either order) left
/// out of the graph.
pub fn spanning_tree_without(
    n_bodies: usize,
    pairs: &[PairDof],
    excluded: &[(usize, usize)],
    tree_costs: &TreeCosts,
) -> Option<Tree> {
    if n_bodies == 0 {
        return None;
    }
    let statics = static_bodies(n_bodies, pairs);
    // Among several static bodies the one posed in the most frames (then the lowest id): a
    // body posed in two frames tests static by chance, and the ids follow the point order.
    let posed = posed_frames(n_bodies, pairs);
    let most_posed = statics
        .iter()
        .copied()
        .max_by_key(|&s| (posed[s], std::cmp::Reverse(s)));
    let costs = edge_costs(n_bodies, pairs, tree_costs);
    let mut g: UnGraph<usize, f64> = UnGraph::with_capacity(n_bodies, pairs.len());
    for b in 0..n_bodies {
        g.add_node(b);
    }
    for (p, cost) in pairs.iter().zip(&costs) {
        if let (Some(a), Some(cost)) = (p.a, cost) {
            if excluded
                .iter()
                .any(|&(x, y)| (x, y) == (a, p.b) || (y, x) == (a, p.b))
            {
                continue;
            }
            g.add_edge(NodeIndex::new(a), NodeIndex::new(p.b), *cost);
        }
    }
    let mst = petgraph::algo::min_spanning_tree(&g);
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n_bodies];
    for e in mst {
        if let petgraph::data::Element::Edge { source, target, .. } = e {
            adj[source].push(target);
            adj[target].push(source);
        }
    }
    for a in &mut adj {
        a.sort_unstable();
    }
    let (root, root_is_static) = match most_posed {
        Some(s) => {
            hang_subjects_by_their_root(&mut adj, s, pairs, excluded, tree_costs.min_free_dof);
            (s, true)
        }
        None => (floating_root(pairs, &adj)?, false),
    };
    let mut parent = vec![None; n_bodies];
    let mut seen = vec![false; n_bodies];
    let mut order = vec![root];
    seen[root] = true;
    let mut i = 0;
    while i < order.len() {
        let u = order[i];
        for &v in &adj[u] {
            if !seen[v] {
                seen[v] = true;
                parent[v] = Some(u);
                order.push(v);
            }
        }
        i += 1;
    }
    if hoist_ties(
        &mut parent,
        &order,
        pairs,
        excluded,
        tree_costs.tie_fit_margin,
    ) {
        order = breadth_first(root, &parent);
    }
    order.extend((0..n_bodies).filter(|&b| !seen[b]));
    Some(Tree {
        root,
        root_is_static,
        parent,
        order,
    })
}

/// The kinds of joint between which a tree can tie: about a fixed centre (spherical or
/// universal), a hinge, a slide.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum TieKind {
    Centred,
    Hinge,
    Slide,
}

/// Hangs a body on its grandparent instead of its parent, repeatedly, where the data fit both
/// trees exactly:
/// - both joints turn about a fixed centre (spherical or universal): two bodies turning on
///   balls about one centre each have a ball joint with the other too. A ball whose motion
///   is too small to tell it from a universal joint is typed universal, so the two count
///   alike;
/// - the parent's own joint, the child's joint with it and the child's pair with the
///   grandparent are all hinges, or all slides: two fingers sliding along one axis, or two
///   jaws turning on one pin, move relative to each other by a joint of the same type. The
///   child carries no other body and its pair with the grandparent fits within `margin`
///   ([`TreeCosts::tie_fit_margin`], in fit ratio: the largest rejected singular value over
///   its threshold) of its pair with the parent: two serial joints whose axes are a few
///   degrees apart pass a single-DoF test across both marginally, and a link that carries
///   others is no gripper's finger.
///
/// The shallower tree, the one with independent joint coordinates (as a roboticist draws a
/// gripper's fingers, both on the hand), is taken. Bodies in `order` (parents first), so each
/// is hoisted above ancestors already settled. Returns whether a parent changed.
fn hoist_ties(
    parent: &mut [Option<usize>],
    order: &[usize],
    pairs: &[PairDof],
    excluded: &[(usize, usize)],
    margin: f64,
) -> bool {
    let fit =
        |a: usize, b: usize| find_pair(pairs, Some(a), b).map_or(f64::INFINITY, |p| p.fit_ratio);
    let tied = |w: usize, u: usize, v: usize, carries_others: bool| match tie_kind(
        pairs, excluded, u, v,
    ) {
        Some(TieKind::Centred) => tie_kind(pairs, excluded, w, v) == Some(TieKind::Centred),
        Some(_) => {
            single_dof_triangle(pairs, excluded, w, u, v)
                && fit(w, v) <= fit(u, v) + margin
                && !carries_others
        }
        None => false,
    };
    let mut changed = false;
    for &v in order {
        while let Some(u) = parent[v]
            && let Some(w) = parent[u]
            && tied(w, u, v, parent.contains(&Some(v)))
        {
            parent[v] = Some(w);
            changed = true;
        }
    }
    changed
}

/// The kind of tie the pair between `a` and `b` can take part in; `None` for other joints and
/// for pairs in `excluded` (either order).
fn tie_kind(pairs: &[PairDof], excluded: &[(usize, usize)], a: usize, b: usize) -> Option<TieKind> {
    if excluded.contains(&(a, b)) || excluded.contains(&(b, a)) {
        return None;
    }
    match find_pair(pairs, Some(a), b)?.joint {
        JointKind::Spherical { .. } | JointKind::Universal { .. } => Some(TieKind::Centred),
        JointKind::Revolute { .. } => Some(TieKind::Hinge),
        JointKind::Prismatic { .. } => Some(TieKind::Slide),
        _ => None,
    }
}

/// Whether the pairs `w`-`u`, `u`-`v` and `w`-`v` are all hinges or all slides.
fn single_dof_triangle(
    pairs: &[PairDof],
    excluded: &[(usize, usize)],
    w: usize,
    u: usize,
    v: usize,
) -> bool {
    let k = tie_kind(pairs, excluded, u, v);
    matches!(k, Some(TieKind::Hinge | TieKind::Slide))
        && tie_kind(pairs, excluded, w, u) == k
        && tie_kind(pairs, excluded, w, v) == k
}

/// The bodies `v` of `tree` that [`spanning_tree`]'s exact-tie rule left on their parent `u`
/// only for the fit margin, as `(w, u, v)` with `w` the grandparent: the pairs `w`-`u`,
/// `u`-`v` and `w`-`v` are all hinges or all slides, and `v` carries no other body. Whether
/// `v` turns or slides with `u` about one axis, so that hanging it on `w` fits as well, is
/// for a whole-tree fit to tell. In order of `v`.
pub fn fit_margin_ties(pairs: &[PairDof], tree: &Tree) -> Vec<(usize, usize, usize)> {
    (0..tree.parent.len())
        .filter_map(|v| {
            let u = tree.parent[v]?;
            let w = tree.parent[u]?;
            (!tree.parent.contains(&Some(v)) && single_dof_triangle(pairs, &[], w, u, v))
                .then_some((w, u, v))
        })
        .collect()
}

/// The bodies `v` of `tree` that hang by a hinge on a parent `u` that itself hangs by a hinge
/// on `w`, where the two hinges turn about one line and `v`'s pair with `w` is a hinge or a
/// universal joint (`(w, u, v)`, in order of `v`; `v` may carry other bodies). Two fingers
/// whose knuckles flex about one line move relative to each other by a hinge about it, which
/// can test clearer than either finger's hinge on the palm: the finger on the palm has its own
/// coordinate (the tree a roboticist draws), on the other finger a difference of two. A
/// knuckle that also swings the finger sideways (a universal joint) can hide that second
/// angle in the pair test between two fingers and show it in the test with the palm. One
/// line: the median over the frames that pose `w` and `u` of the angle between the two axes
/// is at most `max_angle_rad`, and of the distances of `u`'s hinge line from the other's, at
/// the points nearest `u`'s and `v`'s origins, at most `max_offset` times the distance
/// between those origins. And `v`'s joint on `w` passes by `w`: the nearest of `w`'s placed
/// points to its hinge line (a universal joint's first axis through its centre) is within
/// `max_reach` times their RMS distance from `w`'s origin (the median over the frames), as
/// a knuckle line runs along the palm's edge, where a shoulder's axis seen from the pelvis
/// does not. Whether the two trees fit alike is for a whole-tree fit to tell (the
/// `sibling_ties` repair): serial hinges through one anchor a few degrees apart pass here.
pub fn collinear_hinge_ties(
    pairs: &[PairDof],
    poses: &BodyPoses,
    tree: &Tree,
    max_angle_rad: f64,
    max_offset: f64,
    max_reach: f64,
) -> Vec<(usize, usize, usize)> {
    // A pair's hinge (or, with `universal`, a universal joint's first axis through its
    // centre) as (axis, pivot) in the camera frame at frame `t`.
    let line_at =
        |x: usize, y: usize, t: usize, universal: bool| -> Option<(Vector3<f64>, Vector3<f64>)> {
            let p = find_pair(pairs, Some(x), y)?;
            let (axis, pivot) = match p.joint {
                JointKind::Revolute { axis, pivot } => (axis, pivot),
                JointKind::Universal { axis, centre, .. } if universal => (axis, centre),
                _ => return None,
            };
            let pose = poses
                .bodies
                .get(p.a?)?
                .cam_from_body
                .get(t)
                .copied()
                .flatten()?;
            Some((pose.rotation * axis, (pose * pivot).coords))
        };
    let origin = |b: usize, t: usize| -> Option<Vector3<f64>> {
        let pose = poses
            .bodies
            .get(b)?
            .cam_from_body
            .get(t)
            .copied()
            .flatten()?;
        Some(pose.translation.vector)
    };
    // A body's placed points (in its frame) and their RMS distance from its origin.
    let placed = |w: usize| -> (Vec<Point3<f64>>, f64) {
        let Some(track) = poses.bodies.get(w) else {
            return (Vec::new(), 0.0);
        };
        let points: Vec<Point3<f64>> = track
            .shape
            .iter()
            .zip(&track.placed)
            .filter_map(|(x, &ok)| ok.then_some(*x))
            .collect();
        let radius = (points.iter().map(|x| x.coords.norm_squared()).sum::<f64>()
            / points.len().max(1) as f64)
            .sqrt();
        (points, radius)
    };
    // The nearest of `w`'s `points` to the line (`axis`, `pivot`) at frame `t`, over their
    // RMS distance `radius` from `w`'s origin.
    let reach = |w: usize,
                 (points, radius): &(Vec<Point3<f64>>, f64),
                 t: usize,
                 axis: &Vector3<f64>,
                 pivot: &Vector3<f64>|
     -> Option<f64> {
        let pose = poses
            .bodies
            .get(w)?
            .cam_from_body
            .get(t)
            .copied()
            .flatten()?;
        let nearest = points
            .iter()
            .map(|x| {
                let d = (pose * x).coords - pivot;
                (d - axis * axis.dot(&d)).norm()
            })
            .reduce(f64::min)?;
        (*radius > 0.0).then_some(nearest / radius)
    };
    let hinge_at = |x: usize, y: usize, t: usize| line_at(x, y, t, false);
    let is_hinge = |x: usize, y: usize| {
        find_pair(pairs, Some(x), y).is_some_and(|p| matches!(p.joint, JointKind::Revolute { .. }))
    };
    let is_universal = |x: usize, y: usize| {
        find_pair(pairs, Some(x), y).is_some_and(|p| matches!(p.joint, JointKind::Universal { .. }))
    };
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    };
    (0..tree.parent.len())
        .filter_map(|v| {
            let u = tree.parent[v]?;
            let w = tree.parent[u]?;
            if !(is_hinge(w, u) && is_hinge(u, v) && (is_hinge(w, v) || is_universal(w, v))) {
                return None;
            }
            let (mut angles, mut offsets, mut reaches) = (Vec::new(), Vec::new(), Vec::new());
            let of_w = placed(w);
            for t in 0..poses.n_frames {
                if let Some(r) =
                    line_at(w, v, t, true).and_then(|(a, p)| reach(w, &of_w, t, &a, &p))
                {
                    reaches.push(r);
                }
                let (Some((a1, p1)), Some((a2, p2)), Some(ou), Some(ov)) = (
                    hinge_at(w, u, t),
                    hinge_at(u, v, t),
                    origin(u, t),
                    origin(v, t),
                ) else {
                    continue;
                };
                angles.push(a1.angle(&a2).min(a1.angle(&(-a2))));
                // Distance of the points of the second line nearest each origin from the
                // first line, over the origins' distance.
                let apart = (ov - ou).norm();
                if apart <= 0.0 {
                    continue;
                }
                let off = |o: &Vector3<f64>| {
                    let on_second = p2 + a2 * a2.dot(&(o - p2));
                    let d = on_second - p1;
                    (d - a1 * a1.dot(&d)).norm()
                };
                offsets.push(off(&ou).max(off(&ov)) / apart);
            }
            let (angle, offset, reach) = (median(angles)?, median(offsets)?, median(reaches)?);
            (angle <= max_angle_rad && offset <= max_offset && reach <= max_reach)
                .then_some((w, u, v))
        })
        .collect()
}

/// Bodies reachable from `root` through `parent`, breadth first, children by ascending id.
fn breadth_first(root: usize, parent: &[Option<usize>]) -> Vec<usize> {
    let mut order = vec![root];
    let mut i = 0;
    while i < order.len() {
        let u = order[i];
        order.extend((0..parent.len()).filter(|&v| parent[v] == Some(u)));
        i += 1;
    }
    order
}

/// The root of a tree with no static body, `adj` its undirected edges: a body whose motion
/// relative to the camera is a single-DoF joint's (an arm's first link on an unseen base),
/// else a centre of the largest tree (fewest edges to its farthest body: the pelvis or trunk
/// of a person, the palm of a hand); among several, the one that turns least relative to the
/// camera (RMS rotation over the frames it was posed in, zero when its rotation test finds
/// none), then whose centroid moves least, then the lowest id. `None` without bodies.
///
/// Rotations accumulate down a tree, but random joint motions can also cancel: on simulated
/// skeletons a shank turned less than the pelvis, so the least turn alone is only the
/// tie-break.
fn floating_root(pairs: &[PairDof], adj: &[Vec<usize>]) -> Option<usize> {
    root_among(pairs, adj, &vec![true; adj.len()])
}

/// [`floating_root`]'s rule among the bodies `among` marks.
fn root_among(pairs: &[PairDof], adj: &[Vec<usize>], among: &[bool]) -> Option<usize> {
    let n = adj.len();
    let rms = |t: &RankTest| {
        let sum: f64 = t.singular_values.iter().map(|v| v * v).sum();
        (sum / t.n_columns.max(1) as f64).sqrt()
    };
    let motion = |b: usize| {
        find_pair(pairs, None, b)
            .filter(|p| p.translation.n_columns > 0)
            .map_or((f64::INFINITY, f64::INFINITY), |p| {
                let turn = if p.rotation.rank > 0 {
                    rms(&p.rotation)
                } else {
                    0.0
                };
                (turn, rms(&p.translation))
            })
    };
    let least = |x: &usize, y: &usize| {
        let ((tx, dx), (ty, dy)) = (motion(*x), motion(*y));
        tx.total_cmp(&ty).then(dx.total_cmp(&dy)).then(x.cmp(y))
    };
    let on_the_world: Vec<usize> = (0..n)
        .filter(|&b| among[b])
        .filter(|&b| find_pair(pairs, None, b).is_some_and(|p| p.joint.is_single_dof()))
        .collect();
    if !on_the_world.is_empty() {
        return on_the_world.into_iter().min_by(least);
    }
    // Hops from `from` to every body of its tree (`usize::MAX` elsewhere).
    let hops = |from: usize| {
        let mut d = vec![usize::MAX; n];
        d[from] = 0;
        let mut queue = std::collections::VecDeque::from([from]);
        while let Some(u) = queue.pop_front() {
            for &v in &adj[u] {
                if d[v] == usize::MAX {
                    d[v] = d[u] + 1;
                    queue.push_back(v);
                }
            }
        }
        d
    };
    let (size, eccentricity): (Vec<usize>, Vec<usize>) = (0..n)
        .map(|b| {
            if !among[b] {
                return (0, usize::MAX);
            }
            let d = hops(b);
            let reached = d.iter().filter(|&&h| h != usize::MAX);
            (reached.clone().count(), reached.copied().max().unwrap_or(0))
        })
        .unzip();
    let largest = size.iter().copied().max().filter(|&l| l > 0)?;
    let centre = (0..n)
        .filter(|&b| size[b] == largest)
        .map(|b| eccentricity[b])
        .min()?;
    (0..n)
        .filter(|&b| size[b] == largest && eccentricity[b] == centre)
        .min_by(least)
}

/// Hangs each subject that moves freely relative to the static `root` by its own root: where
/// the tree joins a body `c` to the root by a multi-DoF pair of at least `min_dof` DoF (no
/// joint: a person walking past a static object), and every body on `c`'s side has such a
/// pair with the root (none is jointed to it), those bodies are a subject. The one
/// [`floating_root`]'s rule picks among them (a body hinged or sliding on the unseen world,
/// else a centre of the subject: the pelvis, not the shank whose pair happened to test
/// nearest a joint) takes the edge, unless it is `excluded`. A free subject's edge to the
/// scene is no joint, so any of its bodies could carry it, and the subject's tree is then
/// drawn as it would be with nothing static. `adj` is the tree's undirected edges.
fn hang_subjects_by_their_root(
    adj: &mut [Vec<usize>],
    root: usize,
    pairs: &[PairDof],
    excluded: &[(usize, usize)],
    min_dof: usize,
) {
    let free = |b: usize| {
        !excluded.contains(&(root, b))
            && !excluded.contains(&(b, root))
            && find_pair(pairs, Some(root), b)
                .is_some_and(|p| matches!(p.joint, JointKind::MultiDof) && p.dof >= min_dof)
    };
    // The tree without the root's edges, for the subjects' own centres; the moves below only
    // change the root's edges, so it holds for every subject.
    let mut without_root: Vec<Vec<usize>> = adj.to_vec();
    without_root[root].clear();
    for a in &mut without_root {
        a.retain(|&v| v != root);
    }
    for c in adj[root].clone() {
        if !free(c) {
            continue;
        }
        // The subject: the bodies reached from `c` without passing the root.
        let mut among = vec![false; adj.len()];
        among[c] = true;
        let mut stack = vec![c];
        while let Some(u) = stack.pop() {
            for &v in &adj[u] {
                if v != root && !among[v] {
                    among[v] = true;
                    stack.push(v);
                }
            }
        }
        // Free as a whole: a body held by the scene through fewer DoF is jointed to it, as a
        // robot's links are to their base, and its side of the tree is left as it is.
        if (0..adj.len()).any(|b| among[b] && !free(b)) {
            continue;
        }
        let Some(r) = root_among(pairs, &without_root, &among) else {
            continue;
        };
        if r == c {
            continue;
        }
        adj[root].retain(|&v| v != c);
        adj[c].retain(|&v| v != root);
        adj[root].push(r);
        adj[r].push(root);
        adj[root].sort_unstable();
        adj[r].sort_unstable();
    }
}

/// Frames each body is posed in (its test against the camera's columns).
fn posed_frames(n_bodies: usize, pairs: &[PairDof]) -> Vec<usize> {
    (0..n_bodies)
        .map(|b| find_pair(pairs, None, b).map_or(0, |p| p.translation.n_columns))
        .collect()
}

/// What the spanning tree's edge costs share: each body's posed frames ([`posed_frames`]),
/// the median distance between two bodies' centroids over every body pair, and the weights.
struct CostScale {
    posed: Vec<usize>,
    distance: Option<f64>,
    /// Median [`PairDof::ball_fit_rms_m`] over the pairs of moving bodies.
    ball_fit: Option<f64>,
    /// Whether each body is static (its pair with the camera has no DoF).
    fixed: Vec<bool>,
    costs: TreeCosts,
}

impl CostScale {
    fn of(n_bodies: usize, pairs: &[PairDof], costs: &TreeCosts) -> Self {
        let mut fixed = vec![false; n_bodies];
        for b in static_bodies(n_bodies, pairs) {
            fixed[b] = true;
        }
        let median = |value: &dyn Fn(&PairDof) -> Option<f64>| {
            let mut d: Vec<f64> = pairs
                .iter()
                .filter(|p| p.a.is_some())
                .filter_map(value)
                .filter(|d| d.is_finite())
                .collect();
            d.sort_by(f64::total_cmp);
            d.get(d.len() / 2).copied().filter(|&m| m > 0.0)
        };
        let moving = |p: &PairDof| p.a.is_some_and(|a| !fixed[a] && !fixed[p.b]);
        Self {
            posed: posed_frames(n_bodies, pairs),
            distance: median(&|p| p.distance_m),
            ball_fit: median(&|p| p.ball_fit_rms_m.filter(|_| moving(p))),
            fixed,
            costs: *costs,
        }
    }

    /// The spanning tree's cost of a pair between bodies `a` and `p.b`: [`edge_cost`] with
    /// its [`missed_share`], and the pair's distance (adjacent bodies first: a joint joins
    /// neighbours; [`TreeCosts::adjacency_weight`]).
    fn cost(&self, p: &PairDof, a: usize) -> f64 {
        // A ball joint's typing says no more than a multi-DoF pair's DoF do about which
        // segments are neighbours on skin: both are ranked by their ball fit, and by how far
        // the ball's centre lies from the farther body (priced as the distance below is). A
        // body rigid with a segment's neighbour (a scapula across the trunk) fits a ball as
        // well as the neighbour does, about a centre far from its own keypoints; the bodies'
        // centroids would not tell, since a forearm hangs beside the pelvis. A pair with a
        // static body keeps its DoF: a subject walking past the scene fits no ball to it,
        // and which of its bodies the tree hangs there is `hang_subjects_by_their_root`'s to
        // decide.
        let from = self.costs.ball_fit_from_dof;
        let dof = match p.joint {
            JointKind::MultiDof => Some(p.dof),
            JointKind::Spherical { .. } => Some(3),
            _ => None,
        };
        let scaled = |x: Option<f64>| match (x, self.distance) {
            (Some(x), Some(d)) if x.is_finite() => {
                self.costs.adjacency_weight * (x / d).min(self.costs.adjacency_cap)
            }
            _ => 0.0,
        };
        if dof.is_some_and(|d| d >= from)
            && !self.fixed[a]
            && !self.fixed[p.b]
            && let (Some(r), Some(m)) = (p.ball_fit_rms_m, self.ball_fit)
            && r.is_finite()
        {
            return 1.0 + from as f64 + r / (r + m) + scaled(p.ball_reach_m);
        }
        let near = scaled(p.distance_m);
        edge_cost(
            p,
            missed_share(p, self.posed[a].min(self.posed[p.b])),
            &self.costs,
        ) + near
    }
}

/// [`CostScale::cost`] of every pair between two bodies; `None` for pairs with the camera.
fn edge_costs(n_bodies: usize, pairs: &[PairDof], costs: &TreeCosts) -> Vec<Option<f64>> {
    let scale = CostScale::of(n_bodies, pairs, costs);
    pairs.iter().map(|p| Some(scale.cost(p, p.a?))).collect()
}

/// The single-DoF edges of `tree` (as `(parent, child)`) whose child another body outside its
/// subtree reaches by a single-DoF pair costing at most `margin` more: near ties the edge
/// costs cannot settle, which a whole-tree fit can. In order of the children.
pub fn near_tied_edges(
    n_bodies: usize,
    pairs: &[PairDof],
    tree: &Tree,
    margin: f64,
    costs: &TreeCosts,
) -> Vec<(usize, usize)> {
    let scale = CostScale::of(n_bodies, pairs, costs);
    let cost_of = |a: usize, b: usize| {
        let p = find_pair(pairs, Some(a), b).filter(|p| p.joint.is_single_dof())?;
        Some(scale.cost(p, p.a?))
    };
    let below = |c: usize, x: usize| {
        // Whether `x` is `c` or one of its descendants.
        let mut at = Some(x);
        while let Some(b) = at {
            if b == c {
                return true;
            }
            at = tree.parent.get(b).copied().flatten();
        }
        false
    };
    (0..n_bodies)
        .filter_map(|c| {
            let p = tree.parent.get(c).copied().flatten()?;
            let own = cost_of(p, c)?;
            (0..n_bodies)
                .filter(|&a| a != p && !below(c, a))
                .any(|a| cost_of(a, c).is_some_and(|alt| alt <= own + margin))
                .then_some((p, c))
        })
        .collect()
}

/// Joint positions of `pair.b` relative to `pair.a` at every frame, zero at the joint's
/// reference frame (returned as the second value): revolute angles in radians, unwrapped
/// through pi; prismatic displacements in metres along the axis; `None` where either body
/// has no pose or the joint is not single-DoF.
///
/// The reference frame is the common frame where the parent's orientation is most precise
/// (smallest trace of its rotation covariance; the child's breaks near-ties and decides when
/// the parent is the camera), the earliest on a tie. The model reports the joint's axis in
/// the camera frame through the parent's pose at this frame, so a frame where the parent had
/// three visible points would tilt that axis by the frame's own orientation error (25-38 deg
/// on random mechanisms at 2-3 mm noise with the first common frame as the reference).
pub fn joint_positions(poses: &BodyPoses, pair: &PairDof) -> (Vec<Option<f64>>, Option<usize>) {
    let x = relative_poses(poses, pair.a, pair.b);
    let spread = |body: Option<usize>, t: usize| {
        body.and_then(|b| poses.bodies[b].quality[t])
            .map_or(0.0, |q| q.rot_cov_per_sigma2.trace())
    };
    let mut best: Option<(usize, f64)> = None;
    for (t, xt) in x.iter().enumerate() {
        if xt.is_none() {
            continue;
        }
        let v = spread(pair.a, t) + 1e-3 * spread(Some(pair.b), t);
        if best.is_none_or(|(_, b)| v < b * (1.0 - 1e-9)) {
            best = Some((t, v));
        }
    }
    let Some((reference, _)) = best else {
        return (vec![None; poses.n_frames], None);
    };
    let Some(x0) = x[reference] else {
        return (vec![None; poses.n_frames], None);
    };
    let mut out: Vec<Option<f64>> = match &pair.joint {
        JointKind::Revolute { axis, .. } => x
            .iter()
            .map(|xk| xk.map(|xk| angle_about(&(xk.rotation * x0.rotation.inverse()), axis)))
            .collect(),
        JointKind::Prismatic { axis } => x
            .iter()
            .map(|xk| xk.map(|xk| axis.dot(&(xk.translation.vector - x0.translation.vector))))
            .collect(),
        _ => vec![None; poses.n_frames],
    };
    if matches!(pair.joint, JointKind::Revolute { .. }) {
        unwrap_angles(&mut out);
        // Unwrapping starts at the first frame with a value; shift the turns so the
        // reference frame is the zero.
        if let Some(zero) = out[reference] {
            for v in out.iter_mut().flatten() {
                *v -= zero;
            }
        }
    }
    (out, Some(reference))
}

/// The child's pose in the parent's frame at joint position zero (`parent_from_child`),
/// estimated from every common frame rather than the reference frame alone: each frame's
/// relative pose is carried back to zero through its own position (turned about the pivot
/// line, or slid along the axis), and the results are averaged, each frame weighted by the
/// inverse of its summed rotation variances (parent and child). `positions` and `reference`
/// are [`joint_positions`]' output, so zero stays at the reference frame on average. `None`
/// for a joint that is not single-DoF or has no common frame.
///
/// A single frame's relative pose carries that frame's noise into every frame that is
/// re-predicted from it: for a 3 cm body at 1-2 mm noise a few degrees of tilt, which a
/// whole-tree fit then spreads over the neighbouring joints.
pub fn joint_reference(
    poses: &BodyPoses,
    pair: &PairDof,
    positions: &[Option<f64>],
    reference: usize,
) -> Option<Isometry3<f64>> {
    let x = relative_poses(poses, pair.a, pair.b);
    let anchor = x.get(reference).copied().flatten()?;
    let spread = |body: Option<usize>, t: usize| {
        body.and_then(|b| poses.bodies[b].quality[t])
            .map_or(0.0, |q| q.rot_cov_per_sigma2.trace())
    };
    let (mut rot, mut trans, mut total) = (Vector4::zeros(), Vector3::zeros(), 0.0);
    for (t, (xt, qt)) in x.iter().zip(positions).enumerate() {
        let (Some(xt), Some(qt)) = (xt, qt) else {
            continue;
        };
        let back = match &pair.joint {
            JointKind::Revolute { axis, pivot } => {
                Translation3::from(pivot.coords)
                    * UnitQuaternion::from_axis_angle(&Unit::new_normalize(*axis), -qt)
                    * Translation3::from(-pivot.coords)
            }
            JointKind::Prismatic { axis } => Isometry3::from(Translation3::from(-axis * *qt)),
            _ => return None,
        };
        let zero = back * xt;
        let v = spread(pair.a, t) + spread(Some(pair.b), t);
        let w = if v > 0.0 { 1.0 / v } else { 1.0 };
        let mut c = zero.rotation.coords;
        if c.dot(&anchor.rotation.coords) < 0.0 {
            c = -c;
        }
        rot += c * w;
        trans += zero.translation.vector * w;
        total += w;
    }
    if total <= 0.0 || rot.norm() <= 0.0 {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::from(trans / total),
        UnitQuaternion::from_quaternion(Quaternion::from(rot)),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinetree_core::RankTest;
    use kinetree_core::nalgebra::{Point3, Vector3};

    fn pair(a: Option<usize>, b: usize, joint: JointKind, fit_ratio: f64) -> PairDof {
        let dof = match joint {
            JointKind::Rigid => 0,
            JointKind::Spherical { .. } => 3,
            JointKind::MultiDof => 6,
            _ => 1,
        };
        PairDof {
            a,
            b,
            reference_frame: 0,
            translation: RankTest::empty(),
            rotation: RankTest::empty(),
            centre: RankTest::empty(),
            sliding: RankTest::empty(),
            centre_uncentred: RankTest::empty(),
            axes: RankTest::empty(),
            dof,
            joint,
            fit_ratio,
            distance_m: None,
            ball_fit_rms_m: None,
            ball_reach_m: None,
        }
    }

    /// A body whose pairs are all multi-DoF (a segment whose neighbour has no body of its own,
    /// on skin markers) hangs on the body it fits a ball joint best with, whatever the rank
    /// tests' DoF, with `ball_fit_from_dof` at 4; by default the pair of fewest DoF wins. A
    /// three-DoF pair, and a pair with a static body, keep ranking by their DoF.
    #[test]
    fn multi_dof_pairs_rank_by_their_ball_fit() {
        let multi = |a: usize, b: usize, dof: usize, ball: f64| {
            let mut p = pair(Some(a), b, JointKind::MultiDof, 0.0);
            p.dof = dof;
            p.ball_fit_rms_m = Some(ball);
            p
        };
        let hinge = JointKind::Revolute {
            axis: Vector3::z(),
            pivot: Point3::origin(),
        };
        // Bodies 0-1-2 a hinged chain; body 3 near body 2 (a six-DoF pair fitting a ball to
        // 2 cm) and far from body 0 (`far_dof` DoF, 30 cm); body 0 static or moving.
        let pairs = |far_dof: usize, fixed: bool| {
            let base = if fixed {
                JointKind::Rigid
            } else {
                JointKind::MultiDof
            };
            vec![
                pair(None, 0, base, 0.1),
                pair(None, 1, JointKind::MultiDof, 0.0),
                pair(None, 2, JointKind::MultiDof, 0.0),
                pair(None, 3, JointKind::MultiDof, 0.0),
                pair(Some(0), 1, hinge.clone(), 0.2),
                pair(Some(1), 2, hinge.clone(), 0.2),
                multi(0, 2, 2, 0.1),
                multi(0, 3, far_dof, 0.3),
                multi(1, 3, 6, 0.2),
                multi(2, 3, 6, 0.02),
            ]
        };
        let by_ball = TreeCosts {
            ball_fit_from_dof: 4,
            ..TreeCosts::default()
        };
        let parent_of_3 =
            |p: &[PairDof], c: &TreeCosts| spanning_tree(4, p, c).expect("tree").parent[3];
        assert_eq!(parent_of_3(&pairs(5, false), &by_ball), Some(2));
        assert_eq!(
            parent_of_3(&pairs(5, false), &TreeCosts::default()),
            Some(0)
        );
        assert_eq!(parent_of_3(&pairs(3, false), &by_ball), Some(0));
        assert_eq!(parent_of_3(&pairs(5, true), &by_ball), Some(2));
        // A static body's six-DoF pair keeps its cost (7), even fitting a ball to 1 mm.
        let mut fixed = pairs(6, true);
        fixed[7].ball_fit_rms_m = Some(0.001);
        assert_eq!(parent_of_3(&fixed, &by_ball), Some(2));
        let mut moving = pairs(6, false);
        moving[7].ball_fit_rms_m = Some(0.001);
        assert_eq!(parent_of_3(&moving, &by_ball), Some(0));
    }

    /// From three DoF, a ball-typed pair is ranked by its ball fit and the fitted centre's
    /// reach as the multi-DoF pairs are: an arm (body 3) turns about a ball on a body rigid
    /// with its neighbour (body 1, whose keypoints are far from the centre though its
    /// centroid is near the arm's) as well as on the neighbour (body 2, a five-DoF pair that
    /// slides a little); the neighbour takes it at 3, the ball at 4.
    #[test]
    fn ball_pairs_rank_with_the_multi_dof_ones_from_three_dof() {
        let ball = JointKind::Spherical {
            centre: Point3::origin(),
        };
        let with = |a: usize, b: usize, joint: JointKind, dof: usize, fit: f64, reach: f64| {
            let mut p = pair(Some(a), b, joint, 0.0);
            p.dof = dof;
            p.ball_fit_rms_m = Some(fit);
            p.ball_reach_m = Some(reach);
            p.distance_m = Some(0.2);
            p
        };
        let mut pairs = vec![
            pair(None, 0, JointKind::MultiDof, 0.0),
            pair(None, 1, JointKind::MultiDof, 0.0),
            pair(None, 2, JointKind::MultiDof, 0.0),
            pair(None, 3, JointKind::MultiDof, 0.0),
            with(0, 1, ball.clone(), 3, 0.01, 0.1),
            with(0, 2, ball.clone(), 3, 0.012, 0.1),
            with(0, 3, JointKind::MultiDof, 6, 0.15, 0.5),
            with(1, 2, JointKind::MultiDof, 6, 0.03, 0.15),
            with(1, 3, ball.clone(), 3, 0.02, 0.35),
            with(2, 3, JointKind::MultiDof, 5, 0.025, 0.12),
        ];
        pairs[8].distance_m = Some(0.1);
        // The body the arm is joined to (the tree may root at the arm).
        let arm_on = |from: usize| {
            let c = TreeCosts {
                ball_fit_from_dof: from,
                ..TreeCosts::default()
            };
            let tree = spanning_tree(4, &pairs, &c).expect("tree");
            (0..3)
                .filter(|&b| tree.parent[3] == Some(b) || tree.parent[b] == Some(3))
                .collect::<Vec<usize>>()
        };
        assert_eq!(arm_on(3), vec![2]);
        assert_eq!(arm_on(4), vec![1]);
        assert_eq!(arm_on(7), vec![1]);
    }

    /// Poses of bodies at fixed camera positions `origins` (identity rotations) over `n`
    /// frames, body 0 with the keypoints `shape` (in its frame), the others with none.
    fn still_poses(origins: &[[f64; 3]], n: usize, shape: &[[f64; 3]]) -> BodyPoses {
        BodyPoses {
            n_frames: n,
            bodies: origins
                .iter()
                .enumerate()
                .map(|(b, o)| kinetree_core::BodyTrack {
                    points: Vec::new(),
                    shape: if b == 0 {
                        shape.iter().map(|&x| Point3::from(x)).collect()
                    } else {
                        Vec::new()
                    },
                    placed: vec![b == 0; if b == 0 { shape.len() } else { 0 }],
                    reference_frame: 0,
                    cam_from_body: vec![Some(Isometry3::translation(o[0], o[1], o[2])); n],
                    quality: vec![None; n],
                    frames_too_few_points: 0,
                    frames_degenerate: 0,
                })
                .collect(),
        }
    }

    /// A palm (body 0) with two fingers whose knuckles flex about one line, x through the
    /// origin along the palm's edge: the second finger, hung on the first by a hinge about
    /// that line, is a tie; a hinge 30 deg off the line, about a parallel line a finger's
    /// length away (the next phalanx), or with the palm's keypoints far from the line, is not.
    #[test]
    fn fingers_flexing_about_one_line_are_collinear_ties() {
        let hinge = |axis: Vector3<f64>, pivot: [f64; 3]| JointKind::Revolute {
            axis,
            pivot: Point3::from(pivot),
        };
        // Body frames at the bodies' origins: the line x through the camera origin is at
        // (., -y, -z) of each body's origin in its own frame.
        let origins = [[0.0, 0.0, -0.04], [0.03, 0.0, 0.01], [-0.03, 0.0, 0.01]];
        // The palm's keypoints on its face, up to its edge (z = 0.04 in its frame).
        let palm = [
            [-0.03, 0.0, 0.04],
            [0.03, 0.0, 0.04],
            [-0.03, 0.0, -0.04],
            [0.03, 0.0, -0.04],
        ];
        let poses = still_poses(&origins, 5, &palm);
        let at = |b: usize| [0.0, -origins[b][1], -origins[b][2]];
        let tree = Tree {
            root: 0,
            root_is_static: true,
            parent: vec![None, Some(0), Some(1)],
            order: vec![0, 1, 2],
        };
        let pairs = |second: JointKind| {
            vec![
                pair(Some(0), 1, hinge(Vector3::x(), at(0)), 0.5),
                pair(Some(1), 2, second, 0.3),
                pair(Some(0), 2, hinge(Vector3::x(), at(0)), 0.6),
            ]
        };
        let max_angle = 10f64.to_radians();
        let on_line = pairs(hinge(-Vector3::x(), at(1)));
        assert_eq!(
            collinear_hinge_ties(&on_line, &poses, &tree, max_angle, 0.25, 1.0),
            vec![(0, 1, 2)]
        );
        // Keypoints 5-7 cm below the line, 4 cm from the palm's origin in the RMS.
        let low = [
            [-0.03, 0.0, -0.01],
            [0.03, 0.0, -0.01],
            [-0.03, 0.0, -0.03],
            [0.03, 0.0, -0.03],
        ];
        let far = still_poses(&origins, 5, &low);
        assert!(collinear_hinge_ties(&on_line, &far, &tree, max_angle, 0.25, 1.0).is_empty());
        assert_eq!(
            collinear_hinge_ties(&on_line, &far, &tree, max_angle, 0.25, 2.0),
            vec![(0, 1, 2)]
        );
        let tilted = Vector3::new(30f64.to_radians().cos(), 30f64.to_radians().sin(), 0.0);
        for second in [
            hinge(tilted, at(1)),
            hinge(Vector3::x(), [at(1)[0], at(1)[1], at(1)[2] + 0.05]),
            JointKind::MultiDof,
        ] {
            assert!(
                collinear_hinge_ties(&pairs(second), &poses, &tree, max_angle, 0.25, 1.0)
                    .is_empty()
            );
        }
        // The angle and offset bounds are what decide: the tilted hinge's line leaves the
        // other's by 0.43 of the fingers' distance at their origins.
        let tilted = pairs(hinge(tilted, at(1)));
        assert_eq!(
            collinear_hinge_ties(&tilted, &poses, &tree, 31f64.to_radians(), 0.44, 1.0),
            vec![(0, 1, 2)]
        );
    }

    fn ball() -> JointKind {
        JointKind::Spherical {
            centre: Point3::origin(),
        }
    }

    /// A static base with two children on balls about one centre: the siblings' own ball
    /// joint fits best, but both hang on the base.
    #[test]
    fn siblings_on_balls_about_one_centre_hang_on_their_parent() {
        let pairs = vec![
            pair(None, 0, JointKind::Rigid, 0.1),
            pair(None, 1, JointKind::MultiDof, 0.0),
            pair(None, 2, JointKind::MultiDof, 0.0),
            pair(Some(0), 1, ball(), 0.5),
            pair(Some(0), 2, ball(), 0.9),
            pair(Some(1), 2, ball(), 0.1),
        ];
        let tree = spanning_tree(3, &pairs, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(0)]);
        assert_eq!(tree.order, vec![0, 1, 2]);
        // A parent turning on a hinge through the centre ties the same way.
        let mut hinge = pairs.clone();
        hinge[3] = pair(
            Some(0),
            1,
            JointKind::Revolute {
                axis: Vector3::z(),
                pivot: Point3::origin(),
            },
            0.5,
        );
        let tree = spanning_tree(3, &hinge, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(0)]);
        // Without a ball joint to the grandparent, the body stays where the tree hung it.
        let mut chain = pairs.clone();
        chain[4] = pair(Some(0), 2, JointKind::MultiDof, 0.0);
        let tree = spanning_tree(3, &chain, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(1)]);
        // Excluded edges are not taken back by the hoisting.
        let tree =
            spanning_tree_without(3, &pairs, &[(0, 2)], &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(1)]);
    }

    /// Two fingers on a static palm (body 0), each a proximal link on a universal joint (1 and
    /// 3) and a distal link on a hinge (2 and 4). The distal links flex about parallel axes,
    /// so their pair tests at two DoF: the tree still hangs the second finger on the palm by
    /// its universal joint, unless a universal edge costs more than a two-DoF one.
    #[test]
    fn a_universal_joint_to_the_palm_beats_a_two_dof_pair_between_fingers() {
        let universal = || JointKind::Universal {
            axis: Vector3::x(),
            child_axis: Vector3::y(),
            centre: Point3::origin(),
        };
        let hinge = || JointKind::Revolute {
            axis: Vector3::x(),
            pivot: Point3::origin(),
        };
        let mut across = pair(Some(2), 4, JointKind::MultiDof, 0.0);
        across.dof = 2;
        let mut pairs = vec![pair(None, 0, JointKind::Rigid, 0.1)];
        pairs.extend((1..5).map(|b| pair(None, b, JointKind::MultiDof, 0.0)));
        pairs.extend([
            pair(Some(0), 1, universal(), 0.4),
            pair(Some(0), 3, universal(), 0.5),
            pair(Some(1), 2, hinge(), 0.3),
            pair(Some(3), 4, hinge(), 0.3),
            across,
        ]);
        let tree = spanning_tree(5, &pairs, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(1), Some(0), Some(3)]);
        let dear = TreeCosts {
            universal_cost: 4.0,
            ..TreeCosts::default()
        };
        let tree = spanning_tree(5, &pairs, &dear).expect("tree");
        assert_eq!(tree.parent[3], Some(4));
    }

    /// Two hinges that fit a body about as well: the tree takes the one to the nearer body;
    /// without distances, the better fit.
    #[test]
    fn of_two_equal_fits_the_nearer_body_is_the_parent() {
        let hinge = || JointKind::Revolute {
            axis: Vector3::z(),
            pivot: Point3::origin(),
        };
        let at = |mut p: PairDof, d: f64| {
            p.distance_m = Some(d);
            p
        };
        let pairs = |fit_far: f64| {
            vec![
                pair(None, 0, JointKind::Rigid, 0.1),
                pair(None, 1, JointKind::MultiDof, 0.0),
                pair(None, 2, JointKind::MultiDof, 0.0),
                pair(None, 3, JointKind::MultiDof, 0.0),
                at(pair(Some(0), 1, hinge(), 0.2), 0.3),
                at(pair(Some(0), 2, hinge(), 0.2), 0.3),
                at(pair(Some(0), 3, hinge(), 0.9), 0.8),
                at(pair(Some(1), 3, hinge(), fit_far), 0.8),
                at(pair(Some(2), 3, hinge(), 0.3), 0.2),
                at(pair(Some(1), 2, JointKind::MultiDof, 0.0), 0.4),
            ]
        };
        let tree = spanning_tree(4, &pairs(0.3), &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent[3], Some(2));
        let tree = spanning_tree(4, &pairs(0.0), &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent[3], Some(2));
        // With the distance weighed at zero, or capped at the median's, the better fit wins.
        for costs in [
            TreeCosts {
                adjacency_weight: 0.0,
                ..TreeCosts::default()
            },
            TreeCosts {
                adjacency_cap: 0.0,
                ..TreeCosts::default()
            },
        ] {
            let tree = spanning_tree(4, &pairs(0.0), &costs).expect("tree");
            assert_eq!(tree.parent[3], Some(1));
        }
        // Without distances the better fit wins.
        let mut bare = pairs(0.0);
        for p in &mut bare {
            p.distance_m = None;
        }
        let tree = spanning_tree(4, &bare, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent[3], Some(1));
    }

    /// A subject moving freely past a static body: every pair with the static body has six
    /// DoF and the tree's cheapest one reaches the subject at an end of its chain; the subject
    /// is hung by its centre instead, unless the rule is off or a body of the subject is
    /// jointed to the scene or never tested against it.
    #[test]
    fn a_subject_moving_past_a_static_body_hangs_by_its_centre() {
        let free = |b: usize, extra: f64| {
            let mut p = pair(Some(0), b, JointKind::MultiDof, 0.0);
            p.translation.whitened = vec![100.0, extra];
            p
        };
        let ball = |a: usize, b: usize| pair(Some(a), b, ball(), 0.2);
        let mut pairs = vec![pair(None, 0, JointKind::Rigid, 0.1)];
        for b in 1..4 {
            pairs.push(pair(None, b, JointKind::MultiDof, 0.0));
        }
        // Body 3 ends the chain 1-2-3 and fits the scene best.
        pairs.extend([free(1, 5.0), free(2, 5.0), free(3, 0.1)]);
        pairs.extend([ball(1, 2), ball(2, 3)]);
        let tree = spanning_tree(4, &pairs, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(2), Some(0), Some(2)]);
        let off = TreeCosts {
            min_free_dof: 7,
            ..TreeCosts::default()
        };
        let tree = spanning_tree(4, &pairs, &off).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(2), Some(3), Some(0)]);
        // A body the scene holds by four DoF is jointed to it and carries the subject.
        let mut jointed = pairs.clone();
        jointed[4].dof = 4;
        let tree = spanning_tree(4, &jointed, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(1), Some(2)]);
        // A body never tested against the scene leaves the subject as the tree drew it.
        let unseen: Vec<PairDof> = pairs
            .iter()
            .filter(|p| !(p.a == Some(0) && p.b == 1))
            .cloned()
            .collect();
        let tree = spanning_tree(4, &unseen, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(2), Some(3), Some(0)]);
    }

    /// Three slides whose grandparent pair fits beyond the margin: the tree keeps the chain
    /// and lists the body as a fit-margin tie; within the margin it hoists the body and lists
    /// nothing; a body that carries another, or a pair of another type, is no tie.
    #[test]
    fn slides_beyond_the_fit_margin_are_listed_as_ties() {
        const TIE_FIT_MARGIN: f64 = 0.3;
        assert_eq!(TreeCosts::default().tie_fit_margin, TIE_FIT_MARGIN);
        let slide = || JointKind::Prismatic { axis: Vector3::x() };
        let pairs = |grandparent_fit: f64| {
            vec![
                pair(None, 0, JointKind::Rigid, 0.1),
                pair(None, 1, JointKind::MultiDof, 0.0),
                pair(None, 2, JointKind::MultiDof, 0.0),
                pair(Some(0), 1, slide(), 0.3),
                pair(Some(0), 2, slide(), grandparent_fit),
                pair(Some(1), 2, slide(), 0.3),
            ]
        };
        let far = pairs(0.3 + TIE_FIT_MARGIN + 0.2);
        let tree = spanning_tree(3, &far, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(1)]);
        assert_eq!(fit_margin_ties(&far, &tree), vec![(0, 1, 2)]);
        // A wider margin takes the same pairs for an exact tie.
        let wide = TreeCosts {
            tie_fit_margin: TIE_FIT_MARGIN + 0.3,
            ..TreeCosts::default()
        };
        let tree = spanning_tree(3, &far, &wide).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(0)]);
        let near = pairs(0.3 + TIE_FIT_MARGIN / 2.0);
        let tree = spanning_tree(3, &near, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(0)]);
        assert!(fit_margin_ties(&near, &tree).is_empty());
        // A hinge among the three pairs: no tie.
        let mut mixed = far.clone();
        mixed[3] = pair(
            Some(0),
            1,
            JointKind::Revolute {
                axis: Vector3::z(),
                pivot: Point3::origin(),
            },
            0.3,
        );
        let tree = spanning_tree(3, &mixed, &TreeCosts::default()).expect("tree");
        assert_eq!(tree.parent, vec![None, Some(0), Some(1)]);
        assert!(fit_margin_ties(&mixed, &tree).is_empty());
        // The middle body's child carries a body of its own: not a finger.
        let carried = Tree {
            root: 0,
            root_is_static: true,
            parent: vec![None, Some(0), Some(1), Some(2)],
            order: vec![0, 1, 2, 3],
        };
        assert!(fit_margin_ties(&far, &carried).is_empty());
    }
}
