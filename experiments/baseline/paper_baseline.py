#!/usr/bin/env python3
"""The paper's pipeline in plain numpy and scipy: the speed baseline of `docs/benchmarks.md`.

Pair-distance statistics over every frame (scipy's `pdist`, summed with numpy), a one-sided
chi-square test of each pair's distance variance against the sensor noise, average-linkage
clustering, per-frame Kabsch-Umeyama poses (batched SVDs), the ranks of every pair of bodies'
relative rotations and of the translation left once a fixed joint point is fitted, and a
minimum spanning tree over the degrees of freedom. It has none of kinetree's repairs, and it
is meant for what a straightforward implementation costs, not for its answers; its test checks
that it finds the scale scenario's chain all the same.

    python paper_baseline.py tracks.npy --noise-sigma 0.001 [-o model.json]

Prints the bodies, the joints and each stage's wall-clock time.
"""

import argparse
import json
import sys
import time

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import pdist
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

# Average dissimilarity (the probability that a pair is not rigid) under which clusters join.
CUT = 0.9
# A singular value counts toward a rank when it exceeds this many noise standard deviations.
RANK_STD = 4.0
# Bodies posed together in fewer frames get no joint.
MIN_FRAMES = 10


def pair_statistics(x):
    """Per pair of points (condensed, as scipy's `pdist` orders them): the frames that show
    both, and the sums of their distance and of its square over those frames."""
    t, n, _ = x.shape
    count = np.zeros(n * (n - 1) // 2)
    total = np.zeros_like(count)
    square = np.zeros_like(count)
    for frame in x:
        # A hidden point's NaN makes each of its distances NaN.
        d = pdist(frame)
        seen = ~np.isnan(d)
        d[~seen] = 0.0
        count += seen
        total += d
        square += d * d
    return count, total, square


def dissimilarity(count, total, square, sigma):
    """The chi-square probability that each pair's distance varies more than noise would make
    it (distance noise variance 2 sigma^2); 1 for pairs seen together in fewer than 3 frames."""
    with np.errstate(invalid="ignore", divide="ignore"):
        variance = (square - total * total / count) / (count - 1.0)
        dof = count - 1.0
        q = chi2.cdf(dof * variance / (2.0 * sigma * sigma), dof)
    return np.where(count >= 3, q, 1.0)


def clusters(q):
    """Average-linkage clusters of the condensed dissimilarities `q`, cut at CUT; clusters of
    fewer than three points are dropped."""
    labels = fcluster(linkage(q, method="average"), t=CUT, criterion="distance")
    bodies = [np.flatnonzero(labels == k) for k in np.unique(labels)]
    return [b for b in bodies if len(b) >= 3]


def kabsch(reference, observed, weights):
    """Per frame, the rotation and translation carrying `reference` (m, 3) onto `observed`
    (f, m, 3) over the points with weight 1; frames with fewer than three such points get NaN."""
    w = weights[..., None]
    n = weights.sum(axis=1)
    ok = n >= 3
    safe = np.maximum(n, 1.0)[:, None]
    ref_c = (w * reference[None]).sum(axis=1) / safe
    obs = np.nan_to_num(observed)
    obs_c = (w * obs).sum(axis=1) / safe
    h = np.einsum("fmi,fmj->fij", w * (reference[None] - ref_c[:, None]), obs - obs_c[:, None])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.matmul(vt.transpose(0, 2, 1), u.transpose(0, 2, 1))))
    fix = np.ones((len(d), 3))
    fix[:, 2] = d
    r = np.matmul(vt.transpose(0, 2, 1) * fix[:, None, :], u.transpose(0, 2, 1))
    t = obs_c - np.einsum("fij,fj->fi", r, ref_c)
    r[~ok] = np.nan
    t[~ok] = np.nan
    return r, t


def body_poses(x, points):
    """A body's reference shape (its points in the frame that shows most of them, the others
    carried there from the frames that show them) and its pose in every frame."""
    obs = x[:, points]
    seen = ~np.isnan(obs).any(axis=2)
    best = int(seen.sum(axis=1).argmax())
    reference = np.where(seen[best][:, None], obs[best], np.nan)
    known = seen[best].copy()
    for _ in range(2):
        r, t = kabsch(np.nan_to_num(reference), obs, (seen & known).astype(float))
        posed = ~np.isnan(r[:, 0, 0])
        # Every point's place: the mean over the posed frames of its observation carried back.
        back = np.einsum("fji,fmj->fmi", r[posed], obs[posed] - t[posed][:, None])
        reference = np.nanmean(np.where(seen[posed][..., None], back, np.nan), axis=0)
        known = ~np.isnan(reference).any(axis=1)
    r, t = kabsch(np.nan_to_num(reference), obs, (seen & known).astype(float))
    return reference, r, t


def rank(values, threshold):
    """Singular values of the rows (RMS along each direction) above `threshold`."""
    s = np.linalg.svd(values, compute_uv=False) / np.sqrt(len(values))
    return int((s > threshold).sum())


def pair_dof(a, b, sigma):
    """The degrees of freedom of body b against body a from their poses, with the joint type,
    and the RMS miss of the fixed joint point (for ties); None without enough frames."""
    both = ~np.isnan(a["r"][:, 0, 0]) & ~np.isnan(b["r"][:, 0, 0])
    if both.sum() < MIN_FRAMES:
        return None
    # Poses of frames centred on each body's points, so that a translation's noise is its
    # centroid's, with the rotation's noise over the distance between the bodies on top.
    ra, ta, rb, tb = a["r"][both], a["at"][both], b["r"][both], b["at"][both]
    rel_r = np.matmul(ra.transpose(0, 2, 1), rb)
    rel_t = np.einsum("fji,fj->fi", ra, tb - ta)
    turn = np.matmul(rel_r, rel_r[0].T)
    rotvec = Rotation.from_matrix(turn).as_rotvec()
    rot_std = np.hypot(a["rot_std"], b["rot_std"])
    lever = np.linalg.norm(rel_t, axis=1).mean()
    trans_std = np.hypot(a["trans_std"], b["trans_std"]) + a["rot_std"] * lever
    rot_rank = rank(rotvec, RANK_STD * rot_std)
    if rot_rank == 0:
        trans_rank = rank(rel_t - rel_t.mean(axis=0), RANK_STD * trans_std)
        kind = {0: "rigid", 1: "prismatic"}.get(trans_rank, "multi_dof")
        return trans_rank, kind, 0.0
    # A point fixed in both frames: c_a = R c_b + t for every frame, in least squares.
    k = len(rel_r)
    lhs = np.concatenate([np.tile(np.eye(3), (k, 1, 1)), -rel_r], axis=2).reshape(3 * k, 6)
    solution, *_ = np.linalg.lstsq(lhs, rel_t.reshape(3 * k), rcond=None)
    miss = np.sqrt(np.mean((lhs @ solution - rel_t.reshape(3 * k)) ** 2))
    # The point's miss grows with the lever of the child's rotation noise; allow for it.
    fixed = miss <= RANK_STD * (trans_std + b["rot_std"] * np.linalg.norm(solution[3:]))
    if rot_rank == 1 and fixed:
        return 1, "revolute", miss
    if fixed:
        return 3, "spherical", miss
    return 6, "multi_dof", miss


def discover(x, sigma):
    """Bodies, joints and stage times of tracks `x` (frames, points, 3) at noise `sigma`."""
    times = {}
    start = time.perf_counter()
    count, total, square = pair_statistics(x)
    times["pair statistics"] = time.perf_counter() - start
    start = time.perf_counter()
    groups = clusters(dissimilarity(count, total, square, sigma))
    times["clustering"] = time.perf_counter() - start
    start = time.perf_counter()
    bodies = []
    for points in groups:
        reference, r, t = body_poses(x, points)
        centre = np.nanmean(reference, axis=0)
        arm = np.nan_to_num(reference - centre)
        # The rotation's noise about its worst-determined axis: sigma over the square root of
        # the points' least moment of inertia, scaled by the share of points a frame shows.
        inertia = np.eye(3) * (arm * arm).sum() - arm.T @ arm
        shown = np.mean(~np.isnan(x[:, points]).any(axis=2))
        least = max(np.linalg.eigvalsh(inertia)[0] * shown, 1e-12)
        bodies.append(
            {
                "points": points,
                "r": r,
                "t": t,
                # Where the frame centred on the body's points sits: R centre + t.
                "at": np.einsum("fij,j->fi", r, centre) + t,
                "rot_std": sigma / np.sqrt(least),
                "trans_std": sigma / np.sqrt(len(points) * shown),
            }
        )
    times["poses"] = time.perf_counter() - start
    start = time.perf_counter()
    nb = len(bodies)
    weight = np.zeros((nb, nb))
    kinds = {}
    for i in range(nb):
        for j in range(i + 1, nb):
            found = pair_dof(bodies[i], bodies[j], sigma)
            if found is None:
                continue
            dof, kind, miss = found
            # Fewer DoF first; among equals, the better-fitting joint point.
            weight[i, j] = dof + 1.0 + min(miss / sigma, 1e3) * 1e-6
            kinds[(i, j)] = (dof, kind)
    tree = minimum_spanning_tree(weight).toarray()
    tree = tree + tree.T
    # The root: the body that moves least against the camera.
    motion = [np.nanstd(b["t"], axis=0).sum() for b in bodies]
    root = int(np.argmin(motion)) if nb else 0
    order, parents = breadth_first_order(tree, root, directed=False)
    joints = []
    for child in order[1:]:
        parent = int(parents[child])
        dof, kind = kinds[(min(parent, child), max(parent, child))]
        joints.append({"parent": parent, "child": int(child), "type": kind, "dof": dof})
    times["pair tests and tree"] = time.perf_counter() - start
    return bodies, root, joints, times


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tracks", help="a .npy of shape (frames, points, 3), NaN where hidden")
    parser.add_argument("--noise-sigma", type=float, required=True, help="metres")
    parser.add_argument("-o", "--output", help="write the bodies and joints as JSON")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    x = np.load(args.tracks)
    if x.ndim != 3 or x.shape[2] != 3:
        sys.exit(f"{args.tracks}: expected shape (frames, points, 3), found {x.shape}")
    read = time.perf_counter() - start
    bodies, root, joints, times = discover(x.astype(np.float64), args.noise_sigma)
    times = {"reading": read, **times}
    print(f"{len(bodies)} bodies, root body {root}")
    for j in joints:
        print(f"  joint body {j['parent']} -> body {j['child']}: {j['type']}")
    for name, seconds in times.items():
        print(f"  {name:<22}{seconds:8.3f} s")
    print(f"  {'total':<22}{sum(times.values()):8.3f} s")
    if args.output:
        out = {
            "bodies": [[int(p) for p in b["points"]] for b in bodies],
            "root": root,
            "joints": joints,
            "seconds": times,
        }
        with open(args.output, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
