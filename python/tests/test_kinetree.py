"""The Python package: discover, observe, simulate, read_tracks, models and errors."""

import json
import os
import pathlib
import subprocess
import threading
import time

import numpy as np
import pytest

import kinetree

ROOT = pathlib.Path(__file__).resolve().parents[2]


def cli_binary():
    """The kinetree binary that `cargo test` or `cargo build` leaves in target/."""
    if "KINETREE_BIN" in os.environ:
        return os.environ["KINETREE_BIN"]
    built = [ROOT / "target" / p / "kinetree" for p in ("release", "debug")]
    built = [p for p in built if p.exists()]
    if not built:
        pytest.fail("no kinetree binary: build it with `cargo build` or set KINETREE_BIN")
    # The latest build is the one of this checkout.
    return str(max(built, key=lambda p: p.stat().st_mtime))


@pytest.fixture(scope="module")
def arm():
    tracks, truth = kinetree.simulate("paper-arm", seed=3)
    return tracks, truth


def test_simulate_gives_tracks_and_truth(arm):
    tracks, truth = arm
    assert tracks.dtype == np.float64 and tracks.shape == (100, 23, 3)
    assert len(truth["mechanism"]["bodies"]) == 3
    random_tracks, random_truth = kinetree.simulate(
        "random", seed=5, joints=4, tree=True, dropout=0.2, frames=80
    )
    assert random_tracks.shape[0] == 80
    assert np.isnan(random_tracks).any(), "dropout hides samples as NaN"
    assert len(random_truth["mechanism"]["joints"]) == 4
    with pytest.raises(kinetree.ConfigError, match="unknown mechanism"):
        kinetree.simulate("gantry")
    dense, _ = kinetree.simulate("scale", points=120, frames=20)
    assert dense.shape == (20, 120, 3)
    with pytest.raises(kinetree.ConfigError, match="n_points"):
        kinetree.simulate("paper-arm", points=120)
    rigid, _ = kinetree.simulate("skeleton-clinical", frames=30)
    skin, _ = kinetree.simulate("skeleton-clinical", frames=30, soft_tissue=0.01)
    assert rigid.shape == skin.shape and not np.allclose(rigid, skin, equal_nan=True)
    with pytest.raises(kinetree.ConfigError, match="soft_tissue"):
        kinetree.simulate("paper-arm", soft_tissue=0.005)


def test_discover_finds_the_paper_arm(arm):
    tracks, truth = arm
    model = kinetree.discover(tracks, noise_sigma=0.001)
    assert len(model.bodies) == 3
    assert [j.type for j in model.joints] == ["revolute", "revolute"]
    assert model.chain == [0, 1, 2]
    assert model.point_body.shape == (23,) and model.point_body.dtype == np.int64
    assert model.noise_source == "given" and model.noise_sigma == 0.001
    # Every keypoint on a body, each body's points listed in point_body.
    for body in model.bodies:
        assert (model.point_body[body.points] == body.id).all()
        assert body.shape.shape == (len(body.points), 3)
    # The same partition of the keypoints as the simulator's (up to the bodies' labels).
    true_body = np.asarray(truth["point_body"])
    for body in model.bodies:
        assert len(set(true_body[body.points])) == 1
    assert len({int(true_body[b.points[0]]) for b in model.bodies}) == 3
    for joint in model.joints:
        assert joint.axis.shape == (3,)
        assert abs(np.linalg.norm(joint.axis) - 1) < 1e-9
        assert joint.positions.shape == (100,) and joint.position_std.shape == (100,)
        assert np.isfinite(joint.positions).mean() > 0.9
        # The position moves over the recording, by well over its standard deviation.
        assert np.nanstd(joint.positions) > 10 * np.nanmedian(joint.position_std)
        # The axis and pivot bounds of a well-seen hinge: well under a degree and a
        # millimetre, and not zero.
        assert 0 < joint.axis_std_deg < 1 and 0 < joint.pivot_std_m < 1e-3
    # Estimated noise: about the simulated 1 mm.
    estimated = kinetree.discover(tracks)
    assert estimated.noise_source == "estimated"
    assert 0.0005 < estimated.noise_sigma < 0.002


def test_to_json_is_the_cli_file(arm, tmp_path):
    tracks, _ = arm
    npy = tmp_path / "tracks.npy"
    np.save(npy, tracks)
    out = tmp_path / "model.json"
    subprocess.run(
        [cli_binary(), "discover", str(npy), "--noise-sigma", "0.001", "--no-poses"]
        + ["-o", str(out)],
        check=True,
        capture_output=True,
    )
    model = kinetree.discover(tracks, noise_sigma=0.001)
    assert model.to_json() == out.read_text()
    # With its poses file, the CLI's model names it, and the file holds what observe gives.
    named = tmp_path / "named.json"
    subprocess.run(
        [cli_binary(), "discover", str(npy), "--noise-sigma", "0.001", "-o", str(named)],
        check=True,
        capture_output=True,
    )
    assert json.loads(named.read_text())["body_poses_file"] == "named.poses.npy"
    table = np.load(tmp_path / "named.poses.npy")
    seen = kinetree.observe(model, tracks)
    assert table.shape == (100, 3, 9)
    np.testing.assert_allclose(table[..., 4:7], seen.poses[..., :3, 3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(table[..., 7:], seen.pose_std, rtol=0, atol=1e-15)
    again = kinetree.Model.from_json(out.read_text())
    assert again == model and again.to_json() == model.to_json()
    saved = tmp_path / "saved.json"
    model.save(saved)
    assert kinetree.read_model(saved) == model
    # The CLI reads what Python saved.
    shown = subprocess.run(
        [cli_binary(), "inspect", str(saved)], check=True, capture_output=True, text=True
    )
    assert "revolute" in shown.stdout


def test_config_as_dict_toml_text_or_file(arm, tmp_path):
    tracks, _ = arm
    as_dict = kinetree.discover(
        tracks, noise_sigma=0.001, config={"clustering": {"kind": "spectral"}}
    )
    as_text = kinetree.discover(tracks, noise_sigma=0.001, config='clustering = { kind = "spectral" }')
    path = tmp_path / "pipeline.toml"
    path.write_text('[pipeline]\nclustering = { kind = "spectral" }\n')
    as_file = kinetree.discover(tracks, noise_sigma=0.001, config=path)
    assert as_dict == as_text == as_file
    assert as_dict.data["stages"]["clustering"] != kinetree.discover(
        tracks, noise_sigma=0.001
    ).data["stages"]["clustering"]


def test_motion_capture_settings_are_the_cli_preset(arm):
    tracks, _ = arm
    model = kinetree.discover(tracks, config=kinetree.MOTION_CAPTURE)
    assert model.data["stages"]["dissimilarity"] == "distance_std"
    assert kinetree.discover(tracks).data["stages"]["dissimilarity"] != "distance_std"


def test_markers_on_a_joint_axis_are_shared_by_both_bodies():
    tracks, truth = kinetree.simulate("skeleton-clinical", seed=0, dropout=0.2)
    model = kinetree.discover(tracks)
    assert model.shared_points.ndim == 2 and model.shared_points.shape[1] == 2
    assert len(model.shared_points) >= 2
    for point, body in model.shared_points:
        # Listed by both bodies; point_body names the other one.
        assert point in model.bodies[body].points
        assert model.point_body[point] not in (-1, body)
        assert point in model.bodies[model.point_body[point]].points


def test_errors_are_value_errors_naming_the_problem(arm):
    tracks, _ = arm
    with pytest.raises(kinetree.InputError, match=r"\(T, N, 3\)"):
        kinetree.discover(np.zeros((10, 5, 2)))
    with pytest.raises(kinetree.InputError, match=r"\(T, N, 3\)"):
        kinetree.discover(np.zeros((10, 5)))
    frame, point = np.argwhere(~np.isnan(tracks[..., 0]))[50]
    partly = tracks.copy()
    partly[frame, point, 1] = np.nan
    with pytest.raises(kinetree.InputError, match=f"frame {frame}, point {point}"):
        kinetree.discover(partly)
    infinite = tracks.copy()
    infinite[1, 0, 0] = np.inf
    with pytest.raises(kinetree.InputError, match="infinite"):
        kinetree.discover(infinite)
    with pytest.raises(kinetree.InputError, match="frames"):
        kinetree.discover(tracks[:1])
    with pytest.raises(kinetree.ConfigError, match="clusterin"):
        kinetree.discover(tracks, config={"clusterin": {"kind": "spectral"}})
    with pytest.raises(kinetree.ConfigError, match="pipeline.clustering"):
        kinetree.discover(tracks, config={"clustering": {"kind": "nope"}})
    with pytest.raises(kinetree.ConfigError, match="None"):
        kinetree.discover(tracks, config={"noise_sigma_m": None})
    with pytest.raises(kinetree.ConfigError):
        kinetree.discover(tracks, config=42)
    with pytest.raises(kinetree.TooLargeError, match="GiB"):
        kinetree.discover(tracks, max_memory_gib=1e-9)
    with pytest.raises(kinetree.TooLargeError, match="bodies over 100 frames"):
        kinetree.discover(tracks, config={"max_minutes": 1e-6})
    with pytest.raises(kinetree.FileError):
        kinetree.Model.from_json("{not json")
    model = kinetree.discover(tracks, noise_sigma=0.001)
    broken = json.loads(model.to_json())
    broken["joints"][0]["child"] = 99
    with pytest.raises(kinetree.ModelError, match=r"joints\[0\]"):
        kinetree.Model.from_json(json.dumps(broken))
    with pytest.raises(kinetree.InputError, match="23 points"):
        kinetree.observe(model, tracks[:, :10])
    with pytest.raises(kinetree.FileError, match="no-such-file"):
        kinetree.read_tracks("no-such-file.npy")
    for cls in (
        kinetree.InputError,
        kinetree.ConfigError,
        kinetree.FileError,
        kinetree.ModelError,
        kinetree.TooLargeError,
    ):
        assert issubclass(cls, kinetree.KinetreeError) and issubclass(cls, ValueError)


def test_observe_recovers_the_joint_positions(arm):
    tracks, _ = arm
    model = kinetree.discover(tracks, noise_sigma=0.001)
    seen = kinetree.observe(model, tracks)
    assert seen.positions.shape == (100, 2) and seen.std.shape == (100, 2)
    assert seen.joint_names == ["revolute_0_1", "revolute_1_2"]
    assert seen.poses.shape == (100, 3, 4, 4)
    # Each known pose has its two standard deviations, positive, sub-degree and
    # sub-millimetre at 1 mm of noise.
    assert seen.pose_std.shape == (100, 3, 2)
    known = np.isfinite(seen.poses[:, :, 0, 0])
    assert (np.isfinite(seen.pose_std[..., 0]) == known).all()
    assert np.nanmax(seen.pose_std[..., 0]) < np.radians(1)
    assert np.nanmax(seen.pose_std[..., 1]) < 0.001
    assert np.nanmin(seen.pose_std) > 0
    # On the tracks it was discovered on, the observer agrees with the model's positions.
    for k, joint in enumerate(model.joints):
        both = np.isfinite(joint.positions) & np.isfinite(seen.positions[:, k])
        assert both.mean() > 0.9
        # Revolute positions are unwrapped from each one's own start: equal up to turns.
        gap = joint.positions[both] - seen.positions[both, k]
        gap = np.angle(np.exp(1j * gap))
        assert np.abs(gap).max() < 0.01
    assert seen.unexplained == []
    assert np.nanmedian(seen.residual_in_sigma) < 3
    smoothed = kinetree.observe(model, tracks, smooth=True)
    assert smoothed.positions.shape == (100, 2)
    # Tracks in millimetres are not explained by a model in metres.
    wrong = kinetree.observe(model, tracks * 1000)
    assert len(wrong.unexplained) > 50


def test_read_tracks_npz_npy_and_csv(arm, tmp_path):
    tracks, _ = arm
    hidden = tracks.copy()
    hidden[::7, 3] = np.nan
    visible = ~np.isnan(hidden[..., 0])
    zeroed = np.nan_to_num(hidden, nan=0.0)
    np.save(tmp_path / "t.npy", hidden)
    np.savez(tmp_path / "plain.npz", tracks=zeroed, visibility=visible)
    np.savez_compressed(
        tmp_path / "tracker.npz", coords=zeroed.astype(np.float32), occ=~visible
    )
    for read in (
        kinetree.read_tracks(tmp_path / "t.npy"),
        kinetree.read_tracks(tmp_path / "plain.npz"),
    ):
        np.testing.assert_array_equal(read, hidden)
    named = kinetree.read_tracks(tmp_path / "tracker.npz", tracks_key="coords", occluded_key="occ")
    np.testing.assert_allclose(named, hidden, rtol=1e-6, atol=1e-7)
    assert np.array_equal(np.isnan(named), np.isnan(hidden))
    with pytest.raises(kinetree.FileError, match="coords, occ"):
        kinetree.read_tracks(tmp_path / "tracker.npz")
    # The CLI's own files read the same.
    sim = tmp_path / "sim"
    subprocess.run(
        [cli_binary(), "simulate", "--seed", "3", "-o", str(sim)], check=True, capture_output=True
    )
    from_csv = kinetree.read_tracks(sim / "tracks.csv")
    np.testing.assert_array_equal(from_csv, kinetree.read_tracks(sim / "tracks.npz"))
    np.testing.assert_array_equal(from_csv, tracks)
    _, labels = kinetree.read_tracks(sim / "tracks.npy", labels=True)
    assert labels is None


def test_discovery_releases_the_interpreter_lock():
    tracks, _ = kinetree.simulate("random", seed=2, joints=5, tree=True, frames=400)
    result = {}

    def work():
        started = time.perf_counter()
        result["model"] = kinetree.discover(tracks)
        result["seconds"] = time.perf_counter() - started

    thread = threading.Thread(target=work)
    ticks = 0
    thread.start()
    while thread.is_alive():
        ticks += 1
        time.sleep(0.001)
    thread.join()
    assert len(result["model"].bodies) >= 2
    # With the lock held through the discovery this thread could not tick at all.
    assert result["seconds"] > 0.05, "the discovery is long enough to measure"
    # Sleeping 1 ms a tick, a free thread ticks hundreds of times a second; allow a
    # loaded machine a twentieth of that.
    assert ticks > 0.05 * result["seconds"] / 0.001, (ticks, result["seconds"])


def test_view_writes_the_cli_page(arm, tmp_path):
    tracks, _ = arm
    model = kinetree.discover(tracks, noise_sigma=0.001)
    path = tmp_path / "view.html"
    html = kinetree.view(model, tracks, path, title="arm")
    assert path.read_text() == html
    assert html.startswith("<!doctype html>") and "<title>arm</title>" in html
    # The same page as the CLI's for the same model and tracks.
    model.save(tmp_path / "model.json")
    np.save(tmp_path / "tracks.npy", tracks)
    cli_page = tmp_path / "cli.html"
    subprocess.run(
        [cli_binary(), "view", str(tmp_path / "model.json"), str(tmp_path / "tracks.npy"),
         "--title", "arm", "-o", str(cli_page)],
        check=True,
        capture_output=True,
    )
    assert cli_page.read_text() == html
    with pytest.raises(kinetree.ConfigError, match="max_samples"):
        kinetree.view(model, tracks, max_samples=0)
