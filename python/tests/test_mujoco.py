"""The MJCF export loaded in MuJoCo: its forward kinematics, with the model's own joint
coordinates as qpos, against the poses the whole-tree fit gives the same frames."""

import mujoco
import numpy as np

import kinetree


def quaternion_wxyz(rotation_vector):
    """The unit quaternion (w, x, y, z) of a rotation vector."""
    angle = np.linalg.norm(rotation_vector)
    if angle < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = rotation_vector / angle
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def check_forward_kinematics(model, tracks, every=7):
    """Sets every joint's qpos from the observer's fit at every `every`-th frame where all
    are known, runs MuJoCo's kinematics, and compares each body's pose with the same fit's
    pose (relative to the root when it is static, since the MJCF world is then its frame).
    Returns the frames compared and the largest rotation (rad) and translation (m) gaps."""
    mj = mujoco.MjModel.from_xml_string(model.to_mjcf())
    data = mujoco.MjData(mj)
    observed = kinetree.observe(model, tracks)
    root = model.bodies[model.root_body]

    def address(joint):
        """The first qpos entry of the MJCF joint named `joint`."""
        return mj.jnt_qposadr[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, joint)]

    compared, worst_angle, worst_shift = 0, 0.0, 0.0
    for t in range(0, model.n_frames, every):
        qpos = np.zeros(mj.nq)
        known = True
        for j in model.joints:
            name = f"body{j.parent}_to_body{j.child}"
            column = f"{j.type}_{j.parent}_{j.child}"
            if j.type in ("revolute", "prismatic"):
                value = observed.positions[t, observed.joint_names.index(column)]
                known &= bool(np.isfinite(value))
                qpos[address(name)] = value
            elif j.type == "spherical":
                first = observed.joint_names.index(column + "_rx")
                vector = observed.positions[t, first : first + 3]
                known &= bool(np.isfinite(vector).all())
                qpos[address(name) : address(name) + 4] = quaternion_wxyz(vector)
            elif j.type == "universal":
                # Two hinges, `<name>_1` and `<name>_2`, one per angle.
                first = observed.joint_names.index(column + "_q1")
                for i in range(2):
                    value = observed.positions[t, first + i]
                    known &= bool(np.isfinite(value))
                    qpos[address(f"{name}_{i + 1}")] = value
            else:
                known = False
        poses = observed.poses[t]
        known &= bool(np.isfinite(poses).all())
        if not known:
            continue
        world = np.eye(4)
        if root.is_static:
            world = np.linalg.inv(poses[root.id])
        else:
            # The configuration's first six columns: the root's origin and rotation vector.
            first = observed.joint_names.index(f"root_{root.id}_x")
            origin = observed.positions[t, first : first + 3]
            turn = observed.positions[t, first + 3 : first + 6]
            free = address(f"body{root.id}_free")
            qpos[free : free + 3] = origin
            qpos[free + 3 : free + 7] = quaternion_wxyz(turn)
        data.qpos[:] = qpos
        mujoco.mj_kinematics(mj, data)
        for body in model.bodies:
            expected = world @ poses[body.id]
            b = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, f"body{body.id}")
            rotation = data.xmat[b].reshape(3, 3)
            gap = rotation.T @ expected[:3, :3]
            angle = np.arccos(np.clip((np.trace(gap) - 1) / 2, -1.0, 1.0))
            worst_angle = max(worst_angle, angle)
            worst_shift = max(worst_shift, np.linalg.norm(data.xpos[b] - expected[:3, 3]))
        compared += 1
    return compared, worst_angle, worst_shift


def test_mjcf_of_a_skeleton_moves_as_the_fitted_poses():
    tracks, _ = kinetree.simulate("skeleton", seed=2)
    model = kinetree.discover(tracks)
    types = [j.type for j in model.joints]
    assert types.count("spherical") >= 9 and types.count("revolute") >= 3, types
    text = model.to_mjcf()
    assert text.count('type="ball"') == types.count("spherical")
    compared, angle, shift = check_forward_kinematics(model, tracks)
    # The same fit gives the coordinates and the poses, so they agree to rounding; a wrong
    # frame, sign or centre gives tens of degrees and centimetres.
    assert compared >= 20, compared
    assert angle < 1e-6 and shift < 1e-6, (angle, shift)


def test_mjcf_of_a_skeleton_with_universal_joints():
    tracks, _ = kinetree.simulate("skeleton-universal", seed=1)
    model = kinetree.discover(tracks)
    types = [j.type for j in model.joints]
    assert types.count("universal") == 4 and types.count("spherical") >= 5, types
    text = model.to_mjcf()
    assert text.count('type="hinge"') == types.count("revolute") + 2 * types.count("universal")
    compared, angle, shift = check_forward_kinematics(model, tracks)
    assert compared >= 20, compared
    assert angle < 1e-6 and shift < 1e-6, (angle, shift)


def test_mjcf_of_a_mechanism_with_slides_and_balls():
    tracks, _ = kinetree.simulate(
        "random", seed=6, joints=4, tree=True, prismatic_fraction=0.4, spherical_fraction=0.5,
        frames=300,
    )
    model = kinetree.discover(tracks)
    types = {j.type for j in model.joints}
    assert {"revolute", "prismatic", "spherical"} <= types, types
    compared, angle, shift = check_forward_kinematics(model, tracks)
    assert compared >= 10, compared
    assert angle < 1e-6 and shift < 1e-6, (angle, shift)


def test_mjcf_of_a_mechanism_with_no_static_body_has_a_free_root():
    tracks, truth = kinetree.simulate("random", seed=5, joints=3, prismatic_fraction=0.0,
                                      spherical_fraction=0.5, frames=300)
    base = np.asarray(truth["point_body"]) == 0
    moving = tracks[:, ~base, :]
    model = kinetree.discover(moving)
    assert model.static_body is None
    assert "spherical" in [j.type for j in model.joints]
    assert "<freejoint" in model.to_mjcf()
    compared, angle, shift = check_forward_kinematics(model, moving)
    assert compared >= 10, compared
    assert angle < 1e-6 and shift < 1e-6, (angle, shift)


def test_mjcf_of_a_skeleton_with_a_floating_pelvis_has_a_free_root():
    tracks, truth = kinetree.simulate("skeleton-floating", seed=2)
    assert truth["mechanism"]["joints"][0]["type"] == "free"
    model = kinetree.discover(tracks)
    assert model.static_body is None and model.root_joint == "free"
    root_points = model.bodies[model.root_body].points
    # The root is the pelvis (true body 1; body 0 is the unseen world).
    assert set(np.asarray(truth["point_body"])[root_points]) == {1}
    text = model.to_mjcf()
    assert text.count("<freejoint") == 1
    compared, angle, shift = check_forward_kinematics(model, tracks)
    assert compared >= 20, compared
    assert angle < 1e-6 and shift < 1e-6, (angle, shift)
