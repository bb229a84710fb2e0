"""CyberRunner's observation of the labyrinth, built for one board or a batch of boards.

The single env (:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv`) and the batched one
(:class:`~bimgame.envs.labyrinth_vector.LabyrinthVectorEnv`) both observe ``obs_mode="cyberrunner"``
through :func:`cyberrunner_observation`, so the two cannot drift apart. Facts from CyberRunner's
repository ``thomasbi1/cyberrunner``: ``cyberrunner_dreamer/cyberrunner_dreamer/env.py`` at commit
``6bdf8ee512ee24aa7801fcbe437d68a05d35df69`` (the ``Dict`` of ``image``, ``states`` (tilt, position)
and ``goal`` (the relative path), and their normalisation) and
``cyberrunner_state_estimation/core/measurements.py`` (the 64 × 64 sub-image at 1 mm per pixel).

**The marble's motion** (``motion=True``, not CyberRunner's): a ``"motion"`` part of 2 values, the
marble's observed velocity — the change of its position between the previous observation and this
one, times the control rate, divided by :data:`MOTION_SCALE` (0 at an episode's first observation).
It is computed from the observations alone (what stacking two frames gives a feed-forward network);
CyberRunner's DreamerV3 infers velocity in its recurrent world model, and a recurrent policy could too,
but reading a 3 mm step out of positions normalised by the board's 276 mm is a fine difference to
learn. Off by default.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

__all__ = [
    "CROP_SIZE",
    "CROP_PIXEL",
    "CYBERRUNNER_TILT_NORM",
    "CYBERRUNNER_PARTS",
    "CYBERRUNNER_FLAT_SIZE",
    "PATH_AHEAD",
    "PATH_SPACING",
    "GOAL_NORM",
    "MOTION_PART",
    "MOTION_SCALE",
    "cyberrunner_flat_size",
    "cyberrunner_space",
    "cyberrunner_observation",
    "marble_motion",
    "check_motion",
    "MOTION_OBS_MODES",
    "flatten_cyberrunner",
    "unflatten_cyberrunner",
]

#: The observation modes the marble's ``motion`` is part of (:func:`check_motion`).
MOTION_OBS_MODES = ("cyberrunner", "cyberrunner_flat", "pixels")
#: CyberRunner's relative path: 5 points, 60 path points (12 mm) apart, the first at the marble's
#: nearest path point (``env.py``: ``get_rel_path(..., self.num_rel_path, 60)``; ``path.py``).
PATH_AHEAD = 5
PATH_SPACING = 60 * 0.0002
#: CyberRunner's divisors of its relative path (``env.py``: ``goal_norm_max``): the k-th point's x and y
#: by k × 12 mm (k = 1 … 5).
GOAL_NORM = np.repeat(PATH_SPACING * np.arange(1, PATH_AHEAD + 1), 2)
#: CyberRunner normalises its observed tilt by 10° and the marble's position (from the board's
#: lower-left corner) by the board's size (``env.py``: ``norm_max``).
CYBERRUNNER_TILT_NORM = math.radians(10.0)
#: CyberRunner's marble-centred crop: 64 × 64 pixels at 1 mm per pixel (``measurements.py``).
CROP_SIZE, CROP_PIXEL = 64, 1e-3
#: CyberRunner's observation, part by part: each key of the ``Dict`` and its shape, in the order of its
#: flat form (``obs_mode="cyberrunner_flat"``, :func:`flatten_cyberrunner`).
CYBERRUNNER_PARTS = (("image", (1, CROP_SIZE, CROP_SIZE)), ("states", (4,)), ("goal", (2 * PATH_AHEAD,)))
#: The optional part after them (``motion=True``): the marble's observed velocity, x and y.
MOTION_PART = ("motion", (2,))
#: The motion's divisor (m/s): the expert's marble moves at 0.15 m/s on average and at most ≈ 0.55 m/s
#: on the easy layout, so the values stay of order 1.
MOTION_SCALE = 0.25
#: Length of the flat form without the motion: 64 · 64 crop pixels, 4 states, 10 goal values (4110).
CYBERRUNNER_FLAT_SIZE = sum(math.prod(shape) for _, shape in CYBERRUNNER_PARTS)


def cyberrunner_flat_size(motion: bool = False) -> int:
    """Length of the flat observation: 4110, or 4112 with the marble's motion."""
    return CYBERRUNNER_FLAT_SIZE + (math.prod(MOTION_PART[1]) if motion else 0)


def _parts(motion: bool) -> tuple[tuple[str, tuple[int, ...]], ...]:
    return (*CYBERRUNNER_PARTS, MOTION_PART) if motion else CYBERRUNNER_PARTS


def cyberrunner_space(flat: bool, motion: bool = False) -> spaces.Space:
    """The observation space of one board: the ``Dict`` or, ``flat``, its ``Box`` (pixels in 0–255,
    the rest unbounded)."""
    if flat:
        crop, size = CROP_SIZE * CROP_SIZE, cyberrunner_flat_size(motion)
        low = np.concatenate([np.zeros(crop), np.full(size - crop, -np.inf)])
        high = np.concatenate([np.full(crop, 255.0), np.full(size - crop, np.inf)])
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
    parts: dict[str, spaces.Space] = {"image": spaces.Box(0, 255, (1, CROP_SIZE, CROP_SIZE), np.uint8)}
    for key, shape in _parts(motion)[1:]:
        parts[key] = spaces.Box(-np.inf, np.inf, shape, np.float32)
    return spaces.Dict(parts)


def marble_motion(xy: np.ndarray, previous_xy: np.ndarray, control_hz: float) -> np.ndarray:
    """The ``"motion"`` part of boards whose marble moved from ``previous_xy`` to ``xy`` (…, 2) m in
    one step at ``control_hz``: float32 (…, 2), velocity / :data:`MOTION_SCALE`."""
    return ((np.asarray(xy) - np.asarray(previous_xy)) * (control_hz / MOTION_SCALE)).astype(np.float32)


def check_motion(motion: object, obs_mode: str) -> None:
    """``ValueError`` unless ``motion`` is a bool, and False outside the observations that have it:
    CyberRunner's (its ``"motion"`` part) and pixels (the previous frame: :mod:`bimgame.envs.labyrinth_pixels`)."""
    if not isinstance(motion, bool) or (motion and obs_mode not in MOTION_OBS_MODES):
        raise ValueError(
            f"motion must be True or False and is part of the observation modes {MOTION_OBS_MODES} only "
            f"(CyberRunner's: the marble's observed velocity; pixels: the previous frame), got motion={motion!r} "
            f"with obs_mode {obs_mode!r}"
        )


def cyberrunner_observation(
    raster: Any,
    board_size: tuple[float, float],
    xy: np.ndarray,
    tilt: np.ndarray,
    relative: np.ndarray,
    motion: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """CyberRunner's ``Dict`` observation of N boards: ``raster`` (a
    :class:`~bimgame.sim.labyrinth_render.LabyrinthRaster` on the 1 mm sheet) draws each crop around
    the marble at ``xy`` (N, 2) m (board frame, origin at the centre); ``tilt`` (N, 2) rad;
    ``relative`` (N, 10) the path points ahead relative to the marble (m), divided by
    :data:`GOAL_NORM`; ``motion`` (N, 2) from
    :func:`marble_motion`, or None without that part."""
    w, h = board_size
    position = np.stack([(xy[:, 0] + w / 2) / w, (xy[:, 1] + h / 2) / h], axis=1)
    obs = {
        "image": np.stack([raster.crop(p, CROP_SIZE)[None] for p in xy]),
        "states": np.concatenate([tilt / CYBERRUNNER_TILT_NORM, position], axis=1).astype(np.float32),
        "goal": (relative / GOAL_NORM).astype(np.float32),
    }
    if motion is not None:
        obs["motion"] = np.asarray(motion, dtype=np.float32)
    return obs


def flatten_cyberrunner(obs: dict[str, np.ndarray]) -> np.ndarray:
    """CyberRunner's ``Dict`` observation as one float32 vector (…, 4110) — one board's, or a batch's
    (…, the leading axes of each part): the crop's 64 × 64 pixels row by row, their values as the
    ``uint8`` image has them (0–255; a network scales them), then ``"states"`` (4), then ``"goal"``
    (10), then ``"motion"`` (2) if the observation has it (4112). Exact: float32 holds every uint8 and
    float32 value, so :func:`unflatten_cyberrunner` gives the ``Dict`` back bit for bit."""
    batch = np.shape(obs["states"])[:-1]
    parts = [np.asarray(obs[key]).reshape(*batch, -1) for key, _ in _parts(MOTION_PART[0] in obs)]
    return np.concatenate(parts, axis=-1, dtype=np.float32)


def unflatten_cyberrunner(flat: np.ndarray) -> dict[str, np.ndarray]:
    """The ``Dict`` observation of :func:`flatten_cyberrunner`'s vector(s) (…, 4110 or 4112):
    ``"image"`` (…, 1, 64, 64) uint8, ``"states"`` (…, 4) and ``"goal"`` (…, 10) float32, and
    ``"motion"`` (…, 2) for 4112 values."""
    flat = np.asarray(flat, dtype=np.float32)
    sizes = {cyberrunner_flat_size(motion): motion for motion in (False, True)}
    if flat.ndim == 0 or flat.shape[-1] not in sizes:
        raise ValueError(
            f"a flat CyberRunner observation has {' or '.join(map(str, sizes))} values (the second with the "
            f"marble's motion), got shape {flat.shape}"
        )
    parts, start = {}, 0
    for key, shape in _parts(sizes[flat.shape[-1]]):
        size = math.prod(shape)
        part = flat[..., start : start + size].reshape(*flat.shape[:-1], *shape)
        parts[key] = part.astype(np.uint8) if key == "image" else part
        start += size
    return parts
