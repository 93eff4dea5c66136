"""Discover the kinematic structure of an articulated mechanism from tracked 3D keypoints.

Tracks are a float64 array of shape ``(T, N, 3)``: T frames of N keypoints, in metres, with
all three coordinates NaN where a keypoint is hidden. :func:`discover` finds the rigid bodies
(the static background included), which keypoint belongs to which, the joints between bodies
with their axes, the kinematic tree and every joint's position over time, and returns them as
a :class:`Model`. Its fields are numpy arrays; :meth:`Model.to_json` gives the same file as
``kinetree discover`` on the command line.

>>> import kinetree
>>> tracks, truth = kinetree.simulate("paper-arm", seed=0)
>>> model = kinetree.discover(tracks, noise_sigma=0.001)
>>> [j.type for j in model.joints]
['revolute', 'revolute']

Errors are :class:`KinetreeError`, a :class:`ValueError`, or one of its subclasses:
:class:`InputError`, :class:`ConfigError`, :class:`FileError`, :class:`ModelError` and
:class:`TooLargeError`. The message is the library's own, naming what is wrong and where.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _kinetree
from ._kinetree import (
    ConfigError,
    FileError,
    InputError,
    KinetreeError,
    ModelError,
    TooLargeError,
)

__version__ = _kinetree.version()

#: The pipeline for motion-capture markers on skin, as TOML for :func:`discover`'s ``config``:
#: the noise level from each marker's most rigid partners, the distance std-dev as
#: dissimilarity, 3 mm / 0.02 rad of joint model error. ``kinetree discover`` takes it for C3D
#: and TRC files; arrays from :func:`read_tracks` need it given.
MOTION_CAPTURE: str = _kinetree.MOTION_CAPTURE

__all__ = [
    "Body",
    "ConfigError",
    "FileError",
    "InputError",
    "Joint",
    "KinetreeError",
    "MOTION_CAPTURE",
    "Model",
    "ModelError",
    "Observation",
    "TooLargeError",
    "discover",
    "observe",
    "read_model",
    "read_tracks",
    "simulate",
    "view",
]

Config = Union[None, str, Mapping[str, Any], "os.PathLike[str]"]


def _vector(value: Optional[Sequence[float]]) -> Optional[np.ndarray]:
    """A float array, or None where the model has none."""
    return None if value is None else np.asarray(value, dtype=np.float64)


def _vectors(values: Optional[Sequence[Optional[Sequence[float]]]], n: int) -> np.ndarray:
    """A per-frame ``(T, k)`` float array with NaN rows where the model has null; ``(T, 0)``
    when absent."""
    if not values:
        return np.zeros((n, 0))
    width = max((len(v) for v in values if v is not None), default=0)
    return np.array(
        [[np.nan] * width if v is None else v for v in values], dtype=np.float64
    ).reshape(n, width)


def _series(values: Optional[Sequence[Optional[float]]], n: int) -> np.ndarray:
    """A per-frame float array with NaN where the model has null (all NaN when absent)."""
    if values is None:
        return np.full(n, np.nan)
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


@dataclass(frozen=True)
class Body:
    """A rigid body: its keypoints and where it sits in the tree.

    Attributes:
        id: The body's index; body 0 is the root (the static body when there is one).
        points: The indices of its keypoints, ascending (int64).
        is_static: Whether it does not move against the camera.
        parent: The parent body's id; None for the root and for a detached body.
        frames_registered: Frames in which it had a pose of its own.
        median_residual_m: Median RMS residual of its rigid fit, metres.
        shape: ``(len(points), 3)`` positions of its keypoints in the body frame, NaN for a
            keypoint that could not be placed.
    """

    id: int
    points: np.ndarray
    is_static: bool
    parent: Optional[int]
    frames_registered: int
    median_residual_m: Optional[float]
    shape: np.ndarray


@dataclass(frozen=True)
class Joint:
    """A joint between a parent and a child body.

    Attributes:
        type: ``"revolute"``, ``"prismatic"``, ``"spherical"``, ``"universal"``, ``"rigid"``
            or ``"multi_dof"``.
        parent, child: Body ids.
        axis: Unit axis ``(3,)`` in the camera frame at ``reference_frame`` (a universal
            joint's first axis, fixed in the parent); None for spherical and multi-DoF
            joints.
        point: A point ``(3,)`` on a revolute axis, or a spherical or universal joint's
            centre, in the camera frame; None otherwise.
        axis_in_parent, point_in_parent: The same in the parent's body frame.
        second_axis, second_axis_in_parent: A universal joint's second axis, fixed in the
            child, at joint position zero, in the camera frame and the parent's body frame;
            None for other joints.
        reference_frame: The frame at which the position is zero.
        positions: ``(T,)`` joint position per frame, radians or metres, NaN where the frame
            does not determine it.
        position_std: ``(T,)`` standard deviation of each position.
        smoothed_positions, smoothed_std: ``(T,)`` the positions smoothed over time and
            their standard deviations (NaN where not given).
        coordinates: ``(T, k)`` coordinates of a joint of more than one (a spherical
            joint's rotation vector, a universal joint's two angles, radians), NaN where
            unknown; ``(T, 0)`` otherwise.
        coordinate_std: ``(T, k)`` their standard deviations.
        range: ``(min, max)`` of the positions, or None.
        axis_std_deg: The axis direction's standard deviation (RMS angle), degrees: the
            Cramér-Rao bound from the whole-tree fit of every frame (a universal joint's
            first axis); None for joints the fit does not follow and for ball and multi-DoF
            joints.
        pivot_std_m: The same for a revolute axis line's position across the axis, metres.
        centre_std_m: The same for a ball or universal joint's centre in the parent's frame
            (RMS distance), metres.
        second_axis_std_deg: The same for a universal joint's second axis in the child's
            frame, degrees.
        dof: The estimated relative degrees of freedom.
        fit: How the whole-tree fit treats it: ``"followed"``, ``"freed"`` or
            ``"typed_by_fit"``.
    """

    type: str
    parent: int
    child: int
    axis: Optional[np.ndarray]
    point: Optional[np.ndarray]
    axis_in_parent: Optional[np.ndarray]
    point_in_parent: Optional[np.ndarray]
    reference_frame: int
    positions: np.ndarray
    position_std: np.ndarray
    smoothed_positions: np.ndarray
    smoothed_std: np.ndarray
    range: Optional[Tuple[float, float]]
    dof: int
    fit: Optional[str]
    coordinates: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    coordinate_std: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    second_axis: Optional[np.ndarray] = None
    second_axis_in_parent: Optional[np.ndarray] = None
    axis_std_deg: Optional[float] = None
    pivot_std_m: Optional[float] = None
    centre_std_m: Optional[float] = None
    second_axis_std_deg: Optional[float] = None


class Model:
    """A discovered model: bodies, joints, tree and joint positions.

    Built by :func:`discover`, :meth:`Model.from_json` or :func:`read_model`. The fields are
    read from the model JSON (``docs/model-schema.md`` describes every one); :attr:`data`
    holds that JSON as a dict for the fields not given as attributes (``pairs``, ``trace``).

    Attributes:
        n_frames, n_points: The size of the tracks it was discovered on.
        point_body: ``(N,)`` int64 body of every keypoint, -1 for a keypoint on no body.
        shared_points: ``(S, 2)`` int64 rows ``[point, body]``: keypoints that belong to a
            second body as well (markers on a joint's axis); ``point_body`` names the first.
        point_labels: Marker names when the input had them, else None.
        noise_sigma: The per-coordinate noise standard deviation used, metres.
        noise_source: ``"given"`` or ``"estimated"``.
        static_body: The static body's id, or None.
        root_body: The root of the tree.
        root_joint: ``"fixed"`` when the root is the static body, ``"free"`` when nothing is
            static and the root moves with six coordinates (first in :func:`observe`'s
            configuration).
        chain: Bodies in chain order when the structure is a chain, else None.
        bodies: One :class:`Body` per body, by id.
        joints: One :class:`Joint` per body with a parent.
        warnings: Every warning as a dict with its ``kind``.
    """

    def __init__(self, text: str) -> None:
        """Builds a model from JSON text already checked by the library (use
        :meth:`from_json`)."""
        self._json = text
        data = json.loads(text)
        self.data: Dict[str, Any] = data
        self.n_frames: int = data["n_frames"]
        self.n_points: int = data["n_points"]
        self.point_body: np.ndarray = np.asarray(data["point_body"], dtype=np.int64)
        self.shared_points: np.ndarray = np.asarray(
            data.get("shared_points", []), dtype=np.int64
        ).reshape(-1, 2)
        self.point_labels: Optional[List[str]] = data.get("point_labels")
        self.noise_sigma: float = data["noise"]["sigma_m"]
        self.noise_source: str = data["noise"]["source"]
        self.static_body: Optional[int] = data.get("static_body")
        self.root_body: int = data["root_body"]
        self.root_joint: str = data.get(
            "root_joint", "fixed" if self.static_body is not None else "free"
        )
        self.chain: Optional[List[int]] = data.get("chain")
        self.warnings: List[Dict[str, Any]] = data.get("warnings", [])
        self.bodies: List[Body] = [
            Body(
                id=b["id"],
                points=np.asarray(b["points"], dtype=np.int64),
                is_static=b["is_static"],
                parent=b.get("parent"),
                frames_registered=b["frames_registered"],
                median_residual_m=b.get("median_residual_m"),
                shape=np.array(
                    [[np.nan] * 3 if p is None else p for p in (b.get("shape") or [])],
                    dtype=np.float64,
                ).reshape(-1, 3),
            )
            for b in data["bodies"]
        ]
        t = self.n_frames
        self.joints: List[Joint] = [
            Joint(
                type=j["type"],
                parent=j["parent"],
                child=j["child"],
                axis=_vector(j.get("axis")),
                point=_vector(j.get("point")),
                axis_in_parent=_vector(j.get("axis_in_parent")),
                point_in_parent=_vector(j.get("point_in_parent")),
                reference_frame=j["reference_frame"],
                positions=_series(j.get("positions"), t),
                position_std=_series(j.get("position_std"), t),
                smoothed_positions=_series(j.get("smoothed_positions"), t),
                smoothed_std=_series(j.get("smoothed_std"), t),
                range=None if j.get("range") is None else tuple(j["range"]),
                dof=j["dof"],
                fit=j.get("fit"),
                coordinates=_vectors(j.get("coordinates"), t),
                coordinate_std=_vectors(j.get("coordinate_std"), t),
                second_axis=_vector(j.get("second_axis")),
                second_axis_in_parent=_vector(j.get("second_axis_in_parent")),
                axis_std_deg=j.get("axis_std_deg"),
                pivot_std_m=j.get("pivot_std_m"),
                centre_std_m=j.get("centre_std_m"),
                second_axis_std_deg=j.get("second_axis_std_deg"),
            )
            for j in data["joints"]
        ]

    @classmethod
    def from_json(cls, text: Union[str, bytes]) -> "Model":
        """Reads model JSON (as ``kinetree discover`` writes it), checking the schema's rules.

        Raises:
            FileError: The text is not JSON of a model.
            ModelError: The model breaks a rule of the schema; the message names the field.
        """
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        return cls(_kinetree.model_json(text))

    def to_json(self) -> str:
        """The model JSON, byte for byte as ``kinetree discover -o model.json`` writes it."""
        return self._json

    def to_urdf(self) -> str:
        """The model as URDF, as ``kinetree export --format urdf`` writes it."""
        return _kinetree.export_model(self._json, "urdf")

    def to_mjcf(self) -> str:
        """The model as MJCF for MuJoCo, as ``kinetree export --format mjcf`` writes it.

        Each joint's ``qpos`` is the model's own coordinate: a hinge's or slide's position, a
        ball's quaternion ``w x y z`` of its rotation vector; a root that is not static moves
        on a free joint.
        """
        return _kinetree.export_model(self._json, "mjcf")

    def save(self, path: Union[str, "os.PathLike[str]"]) -> None:
        """Writes :meth:`to_json` to ``path``."""
        with open(path, "w", encoding="utf-8") as f:
            f.write(self._json)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Model) and other._json == self._json

    def __hash__(self) -> int:
        return hash(self._json)

    def __repr__(self) -> str:
        joints = ", ".join(f"{j.type} {j.parent}->{j.child}" for j in self.joints)
        return (
            f"Model({len(self.bodies)} bodies, {len(self.joints)} joints [{joints}], "
            f"{self.n_frames} frames x {self.n_points} points)"
        )


@dataclass(frozen=True)
class Observation:
    """Joint positions of tracks from a model (:func:`observe`).

    Attributes:
        joint_names: The CLI's column names: when the root is not static, its pose first
            (``root_<id>_x``, ``_y``, ``_z``, ``_rx``, ``_ry``, ``_rz``: origin and rotation
            vector in the camera frame); then ``<type>_<parent>_<child>`` per joint, three
            per spherical joint (``_rx``, ``_ry``, ``_rz``, its rotation vector in the
            parent's frame from the reference pose).
        positions: ``(T, C)`` joint positions (radians, unwrapped, or metres), NaN where the
            frame does not determine one.
        std: ``(T, C)`` their standard deviations.
        residual_in_sigma: ``(T,)`` RMS distance of each frame's keypoints from the fitted
            model, in units of the model's noise; NaN for a frame with no visible keypoint.
        unexplained: Frames whose residual exceeds ``unexplained_bound``: their positions are
            not to be trusted (tracks in millimetres, other points, another mechanism).
        unexplained_bound: The residual bound, in sigma.
        poses: ``(T, B, 4, 4)`` every body's camera-from-body transform in the fitted
            configuration, NaN where not determined. The body frame is the model's: origin
            at the body's centroid, the camera's axes at the body's reference frame.
        pose_std: ``(T, B, 2)`` each pose's standard deviation at the model's noise level,
            rotation (radians) and origin (metres), each in its worst direction; NaN where
            unknown.
    """

    joint_names: List[str]
    positions: np.ndarray
    std: np.ndarray
    residual_in_sigma: np.ndarray
    unexplained: List[int] = field(default_factory=list)
    unexplained_bound: float = float("nan")
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 4, 4)))
    pose_std: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2)))


def _tracks(tracks: Any) -> np.ndarray:
    """The tracks as a C-ordered float64 ``(T, N, 3)`` array."""
    try:
        array = np.ascontiguousarray(tracks, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"tracks must be a float array of shape (T, N, 3): {e}") from None
    if array.ndim != 3 or array.shape[2] != 3:
        raise InputError(
            f"wrong shape: expected (T, N, 3) (frames, keypoints, xyz), found {array.shape}"
        )
    return array


def _config(config: Config) -> Tuple[Optional[str], Optional[str]]:
    """(TOML text, JSON text) of a pipeline config given as a dict, TOML text or TOML file."""
    if config is None:
        return None, None
    if isinstance(config, Mapping):
        try:
            return None, json.dumps(config)
        except (TypeError, ValueError) as e:
            raise ConfigError(f"config dict: {e}") from None
    if isinstance(config, os.PathLike):
        try:
            with open(config, encoding="utf-8") as f:
                return f.read(), None
        except OSError as e:
            raise FileError(f"{os.fspath(config)}: {e}") from None
    if isinstance(config, str):
        return config, None
    raise ConfigError(
        f"config must be a dict, TOML text or a path to a TOML file, not {type(config).__name__}"
    )


def discover(
    tracks: Any,
    noise_sigma: Optional[float] = None,
    config: Config = None,
    *,
    max_memory_gib: Optional[float] = None,
) -> Model:
    """Discovers the bodies, joints, tree and joint positions in tracked keypoints.

    Args:
        tracks: ``(T, N, 3)`` keypoint positions in metres, NaN where a keypoint is hidden
            (any float array-like; converted to float64).
        noise_sigma: Per-coordinate noise standard deviation in metres; estimated from the
            data when None.
        config: The pipeline's stages and repairs, in the schema of a config file's
            ``[pipeline]`` table: a dict (``{"clustering": {"kind": "spectral"}}``), TOML
            text, or the path of a TOML file. Unknown keys are errors.
        max_memory_gib: Refuse a discovery whose estimated memory exceeds this (default 8).

    Returns:
        The :class:`Model`.

    Raises:
        InputError: Tracks of the wrong shape, partly NaN points, infinite coordinates, too
            few frames or points.
        ConfigError: A config key or value that is not valid; the message names the key.
        TooLargeError: A discovery beyond the memory limit.

    The discovery runs without the global interpreter lock, so other Python threads go on.
    """
    array = _tracks(tracks)
    toml_text, json_text = _config(config)
    return Model(
        _kinetree.discover(
            array,
            noise_sigma=noise_sigma,
            config_toml=toml_text,
            config_json=json_text,
            max_memory_gib=max_memory_gib,
        )
    )


def observe(
    model: Model,
    tracks: Any,
    smooth: bool = False,
    *,
    unexplained_factor: float = 3.0,
) -> Observation:
    """Joint positions of (new) tracks of the model's keypoints, frame by frame.

    Args:
        model: A discovered :class:`Model`.
        tracks: ``(T, N, 3)`` tracks of the model's N keypoints, NaN where hidden.
        smooth: Return the positions smoothed over the frames (a Kalman smoother weighting
            each frame by its standard deviation) instead of each frame's own fit.
        unexplained_factor: A frame is flagged as not explained when its residual exceeds
            this many times the model's own re-prediction RMS.

    Raises:
        InputError: Tracks of another number of keypoints or of the wrong shape.
    """
    array = _tracks(tracks)
    names, positions, std, residual, unexplained, bound, poses, pose_std = _kinetree.observe(
        model.to_json(),
        array,
        smooth=smooth,
        unexplained_factor=unexplained_factor,
    )
    return Observation(
        joint_names=list(names),
        positions=positions,
        std=std,
        residual_in_sigma=residual,
        unexplained=list(unexplained),
        unexplained_bound=bound,
        poses=poses,
        pose_std=pose_std,
    )


def view(
    model: Model,
    tracks: Any,
    path: Union[None, str, "os.PathLike[str]"] = None,
    *,
    title: str = "kinetree model",
    max_samples: int = 2_000_000,
    fps: Optional[float] = None,
) -> str:
    """The interactive 3D view of a model and tracks of its keypoints, as ``kinetree view``
    writes it: one self-contained HTML page (no network needed) with the keypoints coloured
    by body, the links, joint axes and pivots, play/pause, a time slider, orbit/zoom and the
    joint positions over time.

    Args:
        model: A discovered :class:`Model`.
        tracks: ``(T, N, 3)`` tracks of the model's keypoints (those it was discovered on, or
            new frames), NaN where hidden.
        path: Where to write the page; not written when None.
        title: The page's title.
        max_samples: Most keypoint samples (frames x keypoints) in the page; a longer
            recording keeps every k-th frame.
        fps: Playback rate, frames per second (default 30).

    Returns:
        The page's HTML. In a notebook, write it to a file and show it with
        ``IPython.display.IFrame(path, width=1100, height=600)``.
    """
    html = _kinetree.view_html(
        model.to_json(), _tracks(tracks), title, max_samples=max_samples, fps=fps
    )
    if path is not None:
        with open(path, "w", encoding="utf-8") as f:
            f.write(html)
    return html


def simulate(
    mechanism: str = "paper-arm",
    seed: int = 0,
    *,
    joints: int = 3,
    tree: bool = False,
    prismatic_fraction: float = 0.3,
    spherical_fraction: float = 0.0,
    noise_sigma: float = 0.001,
    dropout: float = 0.0,
    frames: Optional[int] = None,
    points: Optional[int] = None,
    soft_tissue: Optional[float] = None,
) -> Tuple[np.ndarray, Optional[Dict[str, Any]]]:
    """Simulates tracks of a mechanism, as ``kinetree simulate`` does.

    Args:
        mechanism: ``"paper-arm"`` (the paper's 2-DoF arm), ``"random"``, ``"skeleton"`` (a
            human-like skeleton of ball joints and hinges), ``"skeleton-universal"`` (the
            same with universal wrists and ankles), ``"skeleton-floating"`` (the same with
            a freely moving pelvis and nothing static), ``"skeleton-clinical"`` (the
            floating skeleton with a clinical marker set), ``"gripper-parallel"`` or
            ``"gripper-angular"`` (an arm with two fingers that slide along, or turn about,
            one axis), ``"hand"`` (a palm with four fingers and a thumb), ``"hidden-link"``
            (an arm whose wrist link is seen in part of the frames), ``"slender-planar"`` or
            ``"slender"`` (an arm of rods a few millimetres thick turning about parallel, or
            random, axes), or ``"scale"`` (a base and four links R-R-P-R with ``points``
            keypoints inside them, as dense tracks).
        seed: Seed of every random choice.
        joints, tree, prismatic_fraction, spherical_fraction: For random mechanisms: the
            number of joints (also of a slender arm), whether bodies attach as a tree rather than a chain, the chance
            of a slide, and the chance that a joint that is not a slide is a ball joint.
        noise_sigma: Per-coordinate noise, metres.
        dropout: Extra random occlusion fraction.
        frames: Number of frames (default 100 for the paper arm, 200 for random ones).
        points: Number of keypoints of ``"scale"`` (default 1000).
        soft_tissue: For the skeletons: each marker drifts from its place by a slow offset
            of at most this many metres per coordinate (default none).

    Returns:
        ``(tracks, truth)``: the ``(T, N, 3)`` tracks, NaN where hidden, and the ground truth
        (mechanism, point ownership, joint positions) as a dict.
    """
    tracks, truth = _kinetree.simulate(
        mechanism,
        seed=seed,
        joints=joints,
        tree=tree,
        prismatic_fraction=prismatic_fraction,
        spherical_fraction=spherical_fraction,
        noise_sigma=noise_sigma,
        dropout=dropout,
        frames=frames,
        points=points,
        soft_tissue=soft_tissue,
    )
    return tracks, None if truth is None else json.loads(truth)


def read_tracks(
    path: Union[str, "os.PathLike[str]"],
    *,
    tracks_key: Optional[str] = None,
    visibility_key: Optional[str] = None,
    occluded_key: Optional[str] = None,
    max_memory_gib: float = 8.0,
    labels: bool = False,
) -> Union[np.ndarray, Tuple[np.ndarray, Optional[List[str]]]]:
    """Reads a tracks file: ``.npy``, ``.npz`` (a point tracker's archive), ``.csv``,
    ``.c3d`` or ``.trc`` (motion capture).

    Args:
        path: The file; the extension picks the format.
        tracks_key, visibility_key, occluded_key: ``.npz`` only: the names of the
            ``(T, N, 3)`` tracks array (default ``tracks``) and of a ``(T, N)`` visibility or
            occlusion array (default: ``visibility``, else ``occluded``, when present).
        max_memory_gib: Refuse files whose declared size needs more memory than this.
        labels: Also return the point labels (C3D marker names; None for other files).

    Returns:
        The ``(T, N, 3)`` float64 array, NaN where hidden; with ``labels=True``, the array
        and the labels.

    Raises:
        FileError: A file that cannot be read or does not follow its format; a missing
            ``.npz`` array (the message lists the archive's arrays).
    """
    tracks, names = _kinetree.read_tracks(
        os.fspath(path),
        tracks_key=tracks_key,
        visibility_key=visibility_key,
        occluded_key=occluded_key,
        max_memory_gib=max_memory_gib,
    )
    return (tracks, names) if labels else tracks


def read_model(path: Union[str, "os.PathLike[str]"]) -> Model:
    """Reads a model JSON file written by ``kinetree discover`` or :meth:`Model.save`.

    Raises:
        FileError: The file cannot be read or is not model JSON.
        ModelError: The model breaks a rule of the schema.
    """
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        raise FileError(f"{os.fspath(path)}: {e}") from None
    return Model.from_json(text)
