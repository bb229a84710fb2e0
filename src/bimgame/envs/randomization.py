"""Domain randomisation for sim-to-real transfer: per-episode physics, actuation and camera.

A policy trained on one exact simulator learns its quirks; one trained on a family of simulators
whose parameters vary from episode to episode has to cope with what the real puzzle may differ in
(Tobin et al. 2017, Peng et al. 2018). :class:`Randomization` lists ranges; the envs take it as
``randomize=`` and draw one value per range at every reset (autoresets included) from the env's own
seeded generator, so the same seed gives the same draws and the same episode. ``randomize=None``
(the default) draws nothing and changes nothing.

How each part takes effect:

- **Physics** (friction, marble mass and radius, servo limit): set on the MuJoCo model per episode
  by :meth:`~bimgame.sim.physics.MazeSim.set_parameters` (~30 µs, against ~3 ms for rebuilding
  the model; ``benchmarks/bench_randomization.py``). The vector env keeps one model copy per env and
  steps them all in its one ``mujoco.rollout`` call, which accepts a model per initial state.
- **Actuation** (tilt step scale, tilt error, latency): applied to the commanded tilt changes before
  they reach the servos, see :meth:`EpisodeRandomizer.tilt_deltas`.
- **Camera** (pixel observations only): applied to the uint8 frames with numpy, batched, see
  :meth:`EpisodeRandomizer.pixels`. State observations are exact measurements, so observation
  ranges with ``obs_mode="state"`` are refused rather than silently ignored.

Per-step noise (tilt error, pixel noise) is counter-based: at reset each episode draws one 63-bit
key from the env's generator; the noise of step ``t`` is read from a fixed table of standard normals
at an offset hashed from (key, t). Drawing 7056 fresh normals per 84×84 frame would cost ~70 µs a
frame (~4.4 ms per step of 64 envs), more than everything else here together; the counter also
makes a frame's noise independent of how often it is rendered (same-step autoreset renders twice).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from bimgame.envs.camera import CameraView
from bimgame.sim.maze import Friction, MazeSpec
from bimgame.sim.render import MazeRenderer
from bimgame.util.settings import from_dict, is_integer, is_real

__all__ = [
    "Randomization",
    "EpisodeRandomizer",
    "RANDOMIZATION_PRESETS",
    "randomization_preset",
    "max_marble_radius_scale",
    "max_camera_shift",
    "PHYSICS_FIELDS",
    "ACTION_FIELDS",
    "OBSERVATION_FIELDS",
    "MAX_LATENCY",
    "MAX_BLUR",
    "MAX_CAMERA_ROTATION",
]

MAX_LATENCY = 2  #: largest action latency (whole action steps)
MAX_BLUR = 3.0  #: largest blur sigma (px): the marble is ~5.6 px wide at 84 px
MAX_CAMERA_ROTATION = 15.0  #: largest camera rotation (degrees): a sanity bound, rotation keeps the board in view
NOISE_TABLE_SIZE = 1 << 20  #: standard normals (float32) the per-step noise is read from
NOISE_TABLE_SEED = 0x5EED  #: fixed: the table is part of the code, the per-episode keys are drawn

PHYSICS_FIELDS = (
    "sliding_friction",
    "torsional_friction",
    "rolling_friction",
    "marble_mass",
    "marble_radius",
    "max_tilt",
)
ACTION_FIELDS = ("tilt_step", "tilt_error", "latency")
OBSERVATION_FIELDS = ("brightness", "contrast", "pixel_noise", "blur", "camera_shift", "camera_rotation")

Range = tuple[float, float] | None


@dataclasses.dataclass(frozen=True)
class Randomization:
    """Ranges ``(low, high)`` from which each episode draws its parameters uniformly (``latency``:
    an integer uniformly in ``low..high``). A field left at None keeps the nominal value and draws
    nothing. Scales multiply the maze's nominal value (:class:`~bimgame.sim.maze.MazeSpec`), so
    ``(0.7, 1.3)`` is ±30%. Bad ranges raise ``ValueError`` naming the field, the value and what is
    allowed; bounds that depend on the maze and image size are checked when an env is built."""

    sliding_friction: Range = None
    """Scale of the marble's sliding friction coefficient (MuJoCo ``friction[0]``, nominal 0.5). A
    rolling marble does not slip, so it mostly matters for the low-friction (sliding) variant. > 0."""
    torsional_friction: Range = None
    """Scale of the torsional (spin) friction (m, nominal 1e-5). MuJoCo raises coefficients below
    1e-5 to 1e-5; the model leaves such a term out instead (see ``contact_condim``), so scales < 1
    of MERL's nominal value switch torsional friction off. > 0."""
    rolling_friction: Range = None
    """Scale of the rolling friction (m, nominal 1e-6, below MuJoCo's 1e-5 floor and so left out):
    on MERL's maze only draws ≥ 10 add rolling resistance (a deceleration ≈ (5/7)·g·roll/radius). > 0."""
    marble_mass: Range = None
    """Scale of the marble's mass (and, with it, of its moment of inertia). > 0."""
    marble_radius: Range = None
    """Scale of the marble's radius in the physics (contacts, inertia, resting height). The pixel
    observation, start placement, ``marble_xy``/``sim_state`` checks and the geodesic distance keep
    the nominal radius; a ``sim_state`` start keeps its recorded height. > 0, at most
    :func:`max_marble_radius_scale`: the marble must still pass the narrowest opening of the maze."""
    max_tilt: Range = None
    """Scale of the servo limit (nominal 5°); at most 30° in all. > 0."""
    tilt_step: Range = None
    """Scale of the tilt change one action commands (the discrete step, or a continuous action's
    unit). > 0."""
    tilt_error: Range = None
    """Standard deviation, in nominal tilt steps, of Gaussian noise added to each non-zero component
    of every applied tilt change (a no-op leaves the servos at rest, so it has no error). ≥ 0."""
    latency: tuple[int, int] | None = None
    """Delay in whole action steps: the tilt change applied is the one commanded ``latency`` steps
    earlier (a no-op while the episode has fewer). Integers in 0..2."""
    brightness: Range = None
    """Offset added to every pixel (gray levels). In [-255, 255]."""
    contrast: Range = None
    """Scale of the pixels' distance from mid-gray (127.5): ``(p − 127.5)·contrast + 127.5``. In (0, 10]."""
    pixel_noise: Range = None
    """Standard deviation of Gaussian noise added to every pixel of every frame (gray levels). In [0, 255]."""
    blur: Range = None
    """Sigma (px) of a Gaussian blur (a defocused camera; 0 for none). In [0, 3]."""
    camera_shift: Range = None
    """Camera offset (px), drawn separately for x (right) and y (down). Its magnitude is at most
    :func:`max_camera_shift` (≈ 2 px for MERL's maze at 84 px): the marble stays wholly in view."""
    camera_rotation: Range = None
    """Camera rotation (degrees, counter-clockwise on the image, about its centre, the board's
    centre). In [-15, 15]."""

    def __post_init__(self) -> None:
        for name, (low, high, open_low, what) in _ALLOWED.items():
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _check_range(name, value, low, high, open_low, what))

    @classmethod
    def from_value(cls, value: Randomization | Mapping[str, Any] | None) -> Randomization | None:
        """``randomize=`` as given to an env: None, a :class:`Randomization` or a dict of its fields."""
        if value is None or isinstance(value, Randomization):
            return value
        if isinstance(value, Mapping):
            return from_dict(cls, dict(value), "randomize fields")
        raise ValueError(f"randomize must be None, a Randomization or a dict of its fields, got {value!r}")

    def active(self, fields: tuple[str, ...]) -> tuple[str, ...]:
        """The fields of ``fields`` that are set."""
        return tuple(name for name in fields if getattr(self, name) is not None)

    def check(self, maze: MazeSpec, obs_mode: str, obs_size: int) -> None:
        """The bounds that depend on the env: ``ValueError`` naming the field otherwise."""
        observed = self.active(OBSERVATION_FIELDS)
        if observed and obs_mode != "pixels":
            raise ValueError(
                f"Randomization fields {list(observed)} randomise the camera and need "
                f"obs_mode='pixels'; with obs_mode={obs_mode!r} leave them at None (state "
                "observations are exact measurements)"
            )
        limit = max_marble_radius_scale(maze)
        if self.marble_radius is not None and self.marble_radius[1] > limit[0]:
            raise ValueError(
                f"Randomization.marble_radius = {self.marble_radius!r}: the high end must be at "
                f"most {limit[0]:.4f} (a {limit[0] * maze.marble_radius * 2e3:.2f} mm marble), or "
                f"the marble no longer passes the narrowest opening, {limit[1]}"
            )
        if self.max_tilt is not None and self.max_tilt[1] * maze.max_tilt > math.radians(30) + 1e-12:
            raise ValueError(
                f"Randomization.max_tilt = {self.max_tilt!r}: the servo limit must stay at most 30°, "
                f"so the high end must be at most {math.radians(30) / maze.max_tilt:.4f} "
                f"(nominal {math.degrees(maze.max_tilt):.3g}°)"
            )
        shift = max_camera_shift(maze, obs_size)
        if self.camera_shift is not None and max(abs(v) for v in self.camera_shift) > shift:
            raise ValueError(
                f"Randomization.camera_shift = {self.camera_shift!r}: allowed within "
                f"[-{shift:.3f}, {shift:.3f}] px (the rim's width at obs_size={obs_size}), so the "
                "marble stays wholly in view"
            )

    def names(self) -> tuple[str, ...]:
        """The names of the drawn values :meth:`draw` returns (and ``info["randomization"]`` reports,
        all but ``noise_key``), in draw order."""
        names: list[str] = []
        for name in self.active(tuple(f.name for f in dataclasses.fields(self))):
            names += ["camera_shift_x", "camera_shift_y"] if name == "camera_shift" else [name]
        return tuple(names + (["noise_key"] if self.tilt_error is not None or self.pixel_noise is not None else []))

    def draw(self, rng: np.random.Generator) -> dict[str, float | int]:
        """One episode's parameters, drawn from ``rng`` in field order (``camera_shift``: x, then y),
        then, if per-step noise is on, the episode's noise key."""
        values: dict[str, float | int] = {}
        for field in dataclasses.fields(self):
            bounds = getattr(self, field.name)
            if bounds is None:
                continue
            if field.name == "latency":
                values["latency"] = int(rng.integers(bounds[0], bounds[1] + 1))
            elif field.name == "camera_shift":
                values["camera_shift_x"] = float(rng.uniform(*bounds))
                values["camera_shift_y"] = float(rng.uniform(*bounds))
            else:
                values[field.name] = float(rng.uniform(*bounds))
        if self.tilt_error is not None or self.pixel_noise is not None:
            values["noise_key"] = int(rng.integers(0, 2**63))
        return values


# name: (lowest, highest, lowest excluded, unit and meaning) of the values a range may take.
_ALLOWED: dict[str, tuple[float, float, bool, str]] = {
    "sliding_friction": (0.0, math.inf, True, "scales > 0"),
    "torsional_friction": (0.0, math.inf, True, "scales > 0"),
    "rolling_friction": (0.0, math.inf, True, "scales > 0"),
    "marble_mass": (0.0, math.inf, True, "scales > 0"),
    "marble_radius": (0.0, math.inf, True, "scales > 0 (at most what the maze's gates allow)"),
    "max_tilt": (0.0, math.inf, True, "scales > 0 (a servo limit of at most 30°)"),
    "tilt_step": (0.0, math.inf, True, "scales > 0"),
    "tilt_error": (0.0, math.inf, False, "standard deviations >= 0, in tilt steps"),
    "latency": (0, MAX_LATENCY, False, f"whole action steps, integers in 0..{MAX_LATENCY}"),
    "brightness": (-255.0, 255.0, False, "gray levels in [-255, 255]"),
    "contrast": (0.0, 10.0, True, "scales in (0, 10]"),
    "pixel_noise": (0.0, 255.0, False, "standard deviations in [0, 255] gray levels"),
    "blur": (0.0, MAX_BLUR, False, f"sigmas in [0, {MAX_BLUR:g}] px"),
    "camera_shift": (-math.inf, math.inf, False, "pixels (at most the rim's width in pixels either way)"),
    "camera_rotation": (
        -MAX_CAMERA_ROTATION,
        MAX_CAMERA_ROTATION,
        False,
        f"degrees in [-{MAX_CAMERA_ROTATION:g}, {MAX_CAMERA_ROTATION:g}]",
    ),
}


#: Named randomisations (what ``A3CConfig.randomize`` and ``bimgame train --randomize`` take).
#: ``physics``: what a real board differs by — friction ±30% (sliding and spin), mass ±20%, a
#: marble up to 5% smaller or 3% larger (the gates allow 3.7%), servo steps ±20% with a 0.1-step
#: error, up to 2 steps of latency and a servo limit ±10%. ``camera``: lighting and mounting of a
#: camera for pixel policies — brightness ±20 gray levels, contrast ±20%, noise up to 6 levels,
#: blur up to 0.8 px, a shift up to 2 px and a rotation up to 3°. ``all``: both.
RANDOMIZATION_PRESETS: dict[str, Randomization] = {}


def randomization_preset(name: str) -> Randomization:
    """The randomisation called ``name`` in :data:`RANDOMIZATION_PRESETS`."""
    if name not in RANDOMIZATION_PRESETS:
        raise ValueError(f"unknown randomisation {name!r}; allowed: {', '.join(RANDOMIZATION_PRESETS)}")
    return RANDOMIZATION_PRESETS[name]


def _check_range(name: str, value: Any, lowest: float, highest: float, open_low: bool, what: str) -> tuple:
    integer = name == "latency"
    kind = "integers" if integer else "finite numbers"
    ok = (
        isinstance(value, (tuple, list))
        and len(value) == 2
        and all(is_integer(v) if integer else is_real(v) and math.isfinite(v) for v in value)
    )
    if ok:
        low, high = (int(v) if integer else float(v) for v in value)
        ok = low <= high and (low > lowest if open_low else low >= lowest) and high <= highest
    if not ok:
        raise ValueError(
            f"Randomization.{name} must be None or a (low, high) pair of {kind} with low <= high, {what}; got {value!r}"
        )
    return low, high


def max_marble_radius_scale(maze: MazeSpec) -> tuple[float, str]:
    """The largest marble-radius scale with which the marble still passes every gate and channel of
    ``maze``, and which opening sets it. A gate's narrowest point is its chord at the wall's inner
    face; the box pieces that model a wall lie up to ``arc_tolerance`` inside the true circles, so
    each opening is taken ``2 · arc_tolerance`` narrower (MERL's maze: wall 1's 21.4° gates, 13.37 mm
    at its inner face, allow ×1.037 — a 6.58 mm radius against 6.35 mm)."""
    margin = 2 * maze.arc_tolerance
    openings: list[tuple[float, str]] = []
    previous = 0.0
    for k, wall in enumerate(maze.walls):
        what = "the centre region" if k == 0 else f"channel {k}"
        openings.append((wall.inner_radius - previous, f"{what} ({(wall.inner_radius - previous) * 1e3:.2f} mm wide)"))
        for j, gate in enumerate(wall.gates):
            chord = 2 * wall.inner_radius * math.sin(min(gate.width, math.pi) / 2)
            where = (
                f"walls[{k}].gates[{j}] ({math.degrees(gate.width):.1f}° wide, "
                f"{chord * 1e3:.2f} mm at the wall's inner face)"
            )
            openings.append((chord, where))
        previous = wall.outer_radius
    openings.append(
        (maze.rim_radius - previous, f"the outermost channel ({(maze.rim_radius - previous) * 1e3:.2f} mm)")
    )
    width, name = min(openings)
    return (width - margin) / (2 * maze.marble_radius), name


def max_camera_shift(maze: MazeSpec, obs_size: int) -> float:
    """Largest camera offset (px, per axis) that keeps the marble wholly in view: the frame's edge
    lies ``rim_thickness`` beyond the rim, which the marble never crosses (rotation about the centre
    never brings it nearer the edge than that)."""
    extent = maze.rim_radius + maze.rim_thickness
    return maze.rim_thickness / (2 * extent / obs_size)


def observation_space(
    space: spaces.Box, randomize: Randomization | None, maze: MazeSpec, n_marbles: int, obs_mode: str
) -> spaces.Box:
    """State observations' tilt bounds widened for a servo limit scaled above 1."""
    if randomize is None or randomize.max_tilt is None or randomize.max_tilt[1] <= 1 or obs_mode != "state":
        return space
    low, high = space.low.copy(), space.high.copy()
    tilt = slice(4 * n_marbles, 4 * n_marbles + 2)
    high[tilt] = maze.max_tilt * randomize.max_tilt[1] + 0.01
    low[tilt] = -high[tilt]
    return spaces.Box(low, high, dtype=space.dtype)


@functools.cache
def _noise_table() -> np.ndarray:
    return np.random.default_rng(NOISE_TABLE_SEED).standard_normal(NOISE_TABLE_SIZE, dtype=np.float32)


def _hash(keys: np.ndarray, counters: np.ndarray) -> np.ndarray:
    """SplitMix64 of ``key + counter · golden ratio`` (uint64 arrays, wrapping arithmetic)."""
    z = keys + counters.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _noise_offsets(keys: np.ndarray, counters: np.ndarray, stream: int, length: int) -> np.ndarray:
    """Offsets into the noise table of windows ``length`` long: stream 0 tilt error, 1 pixels."""
    hashed = _hash(keys, np.asarray(counters, dtype=np.uint64) * np.uint64(2) + np.uint64(stream))
    return (hashed % np.uint64(NOISE_TABLE_SIZE - length + 1)).astype(np.int64)


class EpisodeRandomizer:
    """The drawn parameters of a batch of ``batch`` envs (1 for the single env) and their effects.

    :meth:`reset_row` draws an env's episode; :meth:`physics` gives what to set on its model;
    :meth:`tilt_deltas` turns commanded tilt changes into applied ones; :meth:`pixels` transforms
    frames (``raster``: the observations' :class:`~bimgame.sim.render.MazeRenderer`, needed with
    camera ranges); :meth:`info` reports the draws. Everything per step is batched over the envs.
    """

    def __init__(self, randomize: Randomization, maze: MazeSpec, batch: int, raster: MazeRenderer | None = None):
        self.randomize = randomize
        self.maze = maze
        self.batch = int(batch)
        self.physical = bool(randomize.active(PHYSICS_FIELDS))
        self.acting = bool(randomize.active(ACTION_FIELDS))
        self.observing = bool(randomize.active(OBSERVATION_FIELDS))
        self.values = {
            key: np.zeros(batch, dtype=np.int64 if key == "latency" else np.float64)
            for key in randomize.names()
            if key != "noise_key"
        }
        self.noise_keys = np.zeros(batch, dtype=np.uint64)
        self.history = np.zeros((batch, MAX_LATENCY, 2))  # commanded tilt changes, oldest first
        self.raster = raster
        self.camera: CameraView | None = None
        if self.observing:
            if raster is None:
                raise ValueError("camera randomisation needs the observations' raster (raster=)")
            blur = 0 if randomize.blur is None else math.ceil(3 * randomize.blur[1])
            self.camera = CameraView(raster, self.batch, blur)

    # ------------------------------------------------------------------ per episode
    def reset_row(self, row: int, rng: np.random.Generator) -> None:
        """Draw env ``row``'s next episode from its generator and reset its latency history."""
        self.set_row(row, self.randomize.draw(rng))

    def set_row(self, row: int, values: Mapping[str, float | int]) -> None:
        """Install an episode's draws (from :meth:`reset_row`, or a pickled env) in row ``row``."""
        for key, array in self.values.items():
            array[row] = values[key]
        self.noise_keys[row] = np.uint64(values.get("noise_key", 0))
        self.history[row] = 0.0
        if self.camera is not None:
            get = self.row(row).get  # an absent key: nominal
            self.camera.set_row(
                row,
                get("camera_shift_x", 0.0),
                get("camera_shift_y", 0.0),
                get("camera_rotation", 0.0),
                get("blur", 0.0),
                get("contrast", 1.0),
                get("brightness", 0.0),
                get("pixel_noise", 0.0),
            )

    def row(self, row: int) -> dict[str, float | int]:
        """Env ``row``'s draws as plain Python numbers (the single env's ``info["randomization"]``)."""
        return {key: array[row].item() for key, array in self.values.items()}

    def state(self, row: int) -> dict[str, float | int]:
        """What :meth:`set_row` needs to restore env ``row``'s episode: its draws and noise key (the
        latency history is saved separately)."""
        return {**self.row(row), "noise_key": int(self.noise_keys[row])}

    def info(self) -> dict[str, np.ndarray]:
        """The draws of every env, (batch,) arrays per parameter (copies)."""
        return {key: array.copy() for key, array in self.values.items()}

    def physics(self, row: int) -> dict[str, Any]:
        """Keyword arguments of :meth:`~bimgame.sim.physics.MazeSim.set_parameters` for env ``row``."""
        get, maze, f = self.row(row).get, self.maze, self.maze.friction
        return {
            "friction": Friction(
                slide=f.slide * get("sliding_friction", 1.0),
                spin=f.spin * get("torsional_friction", 1.0),
                roll=f.roll * get("rolling_friction", 1.0),
                static=f.static,
            ),
            "marble_mass": maze.marble_mass * get("marble_mass", 1.0),
            "marble_radius": maze.marble_radius * get("marble_radius", 1.0),
            "max_tilt": maze.max_tilt * get("max_tilt", 1.0),
        }

    # ------------------------------------------------------------------ per step
    def tilt_deltas(self, commanded: np.ndarray, rows: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The tilt changes (rad, (b, 2)) applied to envs ``rows`` at their step ``steps`` (steps
        since reset, before this one) for ``commanded`` nominal ones: delayed by the latency, scaled
        by the tilt step scale, plus the tilt error on each non-zero component."""
        applied = commanded
        if "latency" in self.values:
            history = self.history[rows]
            latency = self.values["latency"][rows]
            choices = np.concatenate([history, commanded[:, None]], axis=1)  # t-2, t-1, t
            applied = choices[np.arange(len(rows)), MAX_LATENCY - latency]
            history[:, :-1] = history[:, 1:]
            history[:, -1] = commanded
            self.history[rows] = history
        if "tilt_step" in self.values:
            applied = applied * self.values["tilt_step"][rows, None]
        if "tilt_error" in self.values:
            table = _noise_table()
            offsets = _noise_offsets(self.noise_keys[rows], steps, 0, 2)
            noise = np.stack([table[offsets], table[offsets + 1]], axis=1).astype(np.float64)
            np.multiply(noise, self.values["tilt_error"][rows, None] * self.maze.tilt_step, out=noise)
            applied = applied + np.where(applied != 0.0, noise, 0.0)
        return applied

    def pixels(self, frames: np.ndarray, frame_index: np.ndarray, marble_xy: np.ndarray) -> np.ndarray:
        """The camera's view of frames ``(batch, 1, S, S)`` uint8 drawn by ``raster`` (every row, in
        order) with marbles at board positions ``marble_xy`` (batch, n, 2): camera offset and
        rotation (bilinear, edges repeated), blur, contrast and brightness, the pixel noise of frame
        ``frame_index`` (steps since reset), rounded to new uint8 frames."""
        camera, raster = self.camera, self.raster
        if camera is None or raster is None:
            raise RuntimeError("pixels() needs camera randomisation (an observing EpisodeRandomizer)")
        noise = None
        if "pixel_noise" in self.values:
            n = camera.size**2
            noise = camera.buffer("noise", (self.batch, n))
            table = _noise_table()
            for row, offset in enumerate(_noise_offsets(self.noise_keys, frame_index, 1, n).tolist()):
                noise[row] = table[offset : offset + n]
        return camera.apply(frames, raster.world_to_pixel(marble_xy), noise)


_PHYSICS: dict[str, Any] = dict(
    sliding_friction=(0.7, 1.3),
    torsional_friction=(0.7, 1.3),
    marble_mass=(0.8, 1.2),
    marble_radius=(0.95, 1.03),
    max_tilt=(0.9, 1.1),
    tilt_step=(0.8, 1.2),
    tilt_error=(0.0, 0.1),
    latency=(0, 2),
)
_CAMERA: dict[str, Any] = dict(
    brightness=(-20.0, 20.0),
    contrast=(0.8, 1.2),
    pixel_noise=(0.0, 6.0),
    blur=(0.0, 0.8),
    camera_shift=(-2.0, 2.0),
    camera_rotation=(-3.0, 3.0),
)
RANDOMIZATION_PRESETS.update(
    physics=Randomization(**_PHYSICS), camera=Randomization(**_CAMERA), all=Randomization(**_PHYSICS, **_CAMERA)
)
