"""What every learner shares, so that no learner imports another: the settings that shape a network,
building a network from them, reading which network and task a run directory holds, loading its
weights, and the greedy-and-sampled evaluation every learner reports.

:class:`NetworkSettings` is a dataclass the learners' own settings inherit from (A3C, pre-training),
so each network setting is declared once and a run's ``config.json`` stays flat. A run directory
says what it holds in ``config.json``: A3C runs store their whole settings under ``"a3c"``,
pre-training and DAgger runs store ``"task"`` and ``"network"`` (runs written before this layout
stored an ``"a3c"`` block there too; :func:`read_run` reads both).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, ClassVar, Protocol, Self

import numpy as np

from bimgame.envs.gate_bearings import gate_bearings_size
from bimgame.envs.labyrinth_cyberrunner import MOTION_OBS_MODES
from bimgame.envs.labyrinth_surroundings import surroundings_scale
from bimgame.envs.mazes import maze_encoding_size
from bimgame.envs.puzzles import LABYRINTH, MAZE, NETWORK_OBS, PuzzleSpec, puzzle, puzzle_task_setting, state_obs_scale
from bimgame.learn.checkpoints import load_weights
from bimgame.learn.cyberrunner import check_cyberrunner_network, cyberrunner_net_config
from bimgame.learn.encoders import MAZE_FRAMES
from bimgame.learn.evaluations import evaluate_greedy_and_sampled, evaluation_seed
from bimgame.learn.learner_settings import MAX_STEPS, FlatSettings, ScheduleSettings, check_at_most
from bimgame.learn.maze_runs import check_env_rules, maze_network, network_env_options, run_rules
from bimgame.learn.nets import (
    PRECISIONS,
    NetConfig,
    RecurrentActorCritic,
    ValueNetwork,
    build_network,
    build_value_network,
)
from bimgame.learn.pixel_network import pixel_net_config
from bimgame.learn.policy_heads import check_action_type
from bimgame.learn.runs import CONFIG, KIND_A3C, KIND_VALUE, read_run_config
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.maze import MazeSpec
from bimgame.util.settings import from_dict, require_int

__all__ = [
    "NetworkSettings",
    "RunInfo",
    "read_run",
    "load_run_network",
    "load_value_network",
    "network_settings_of",
    "init_network_settings",
    "LearnerSettings",
    "EvaluatedRun",
    "run_evaluation",
    "MAX_SEED",
    "MAX_NETWORK_SIZE",
    "check_seed",
]

#: The largest seed a run takes: seeds go to numpy's and torch's generators (torch's takes 64 bits at
#: most); 32 bits is numpy's classic seed range, plenty for distinct runs.
MAX_SEED = 2**32 - 1
#: The largest LSTM or encoder size (the paper's is 256): larger is a typo that would fail only when
#: the weights no longer fit in memory.
MAX_NETWORK_SIZE = 4096
#: The network settings that are True or False.
_SWITCHES = (
    "tilt_input",
    "keypoints",
    "subtract_background",
    "aux_heads",
    "asymmetric_critic",
    "maze_encoding",
    "gate_bearings",
    "surroundings",
    "motion",
)


def check_seed(owner: str, value: Any) -> None:
    """Raise ``ValueError`` naming ``owner`` unless ``value`` is an integer from 0 to :data:`MAX_SEED`
    (a negative seed is refused by numpy, one of 2**64 or more by torch — deep inside a run)."""
    if not (isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MAX_SEED):
        raise ValueError(f"{owner}.seed must be an integer from 0 to {MAX_SEED}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class NetworkSettings:
    """The settings that shape a recurrent actor-critic (or a value network): its observations, sizes
    and inputs. A3C, pre-training and DAgger build their networks from these."""

    obs: str = "pixels"
    """Observation: ``pixels`` (84×84, the paper's Conv-Conv-FC-LSTM), ``state`` (MLP-LSTM) or, on the
    labyrinth only, ``cyberrunner`` (CyberRunner's crop around the marble: :mod:`bimgame.learn.cyberrunner`)."""
    hidden: int | None = None
    """LSTM size; None: 256 for pixels (the paper's) and cyberrunner, 128 for state observations."""
    features: int | None = None
    """Encoder output size; None: 256 for pixels (the paper's FC 256) and cyberrunner, 128 for state."""
    tilt_input: bool = True
    """Feed the board tilt to the LSTM (see :mod:`bimgame.learn.nets`). False: no tilt input to the LSTM,
    the paper's exact input."""
    keypoints: bool = False
    """Pixels: add spatial soft-argmax keypoints to the conv encoder (see :mod:`bimgame.learn.nets`)."""
    subtract_background: bool = False
    """Pixels: subtract the empty board's frame (the maze's or the labyrinth's:
    :mod:`bimgame.learn.pixel_network`) before the convolutions (see :mod:`bimgame.learn.nets`)."""
    aux_heads: bool | None = None
    """Train auxiliary heads that predict the simulator's state (marble position, velocity, channel,
    tilt) from the network's features; the policy still acts from its observations alone (see
    :mod:`bimgame.learn.nets`). None: on for pixels (what makes pixels learn at all; measured in
    ``docs/pixels/README.md``), off for state observations (the state is the observation) and, in a
    learner's settings, on the labyrinth (the heads read the maze's state layout:
    :func:`~bimgame.learn.learner_settings.puzzle_defaults`)."""
    asymmetric_critic: bool = False
    """The value head also reads the simulator's state (training only; a departure from the paper,
    whose critic sees what the actor sees). Off by default: it did not help (``docs/pixels/README.md``)."""
    precision: str | None = None
    """Pixels and cyberrunner: the encoder's compute, ``fp32`` or ``bf16`` (bfloat16 autocast). None:
    ``bf16`` for pixels on a CPU with native bfloat16 arithmetic (AVX512-BF16 or AMX; ≈ 1.5× faster
    there), else ``fp32``."""
    action_type: str = "discrete"
    """The policy's actions: ``discrete`` (the paper's 5: no-op, ±1 tilt step about x or y) or
    ``continuous`` (a Gaussian over the tilt change about x and y, in [-1, 1] tilt steps; PPO only)."""
    maze_encoding: bool = False
    """State observations end with the maze's encoding (each wall's openness at 32 angles, see
    :mod:`bimgame.envs.mazes`): what the envs of a run on many mazes (``num_mazes``) observe. Set
    by ``num_mazes``; pixels show the maze instead."""
    maze_frame: str = "board"
    """With ``maze_encoding``: the network reads the encoding as observed (``board``) or turned to start
    at the marble's angle (``marble``), where the gates nearest the marble are always in the same
    inputs (:func:`~bimgame.learn.encoders.marble_frame`)."""
    gate_bearings: bool = False
    """With ``maze_encoding``: the state observations also hold each wall's nearest gate as seen from the
    marble (sine and cosine of its bearing, its half-width: :mod:`bimgame.envs.gate_bearings`), which the
    network reads beside the encoding. Off by default: not in the observations of earlier runs and
    datasets."""
    surroundings: bool = False
    """The labyrinth's state observations also hold what lies around the marble: the nearest holes and
    the distances to the walls (:mod:`bimgame.envs.labyrinth_surroundings`). Off by default: not in the
    observations of earlier runs."""
    motion: bool = False
    """The labyrinth's observation also shows the marble's motion: CyberRunner's (``obs="cyberrunner"``)
    holds its observed velocity, the change of its position since the previous observation
    (:mod:`bimgame.envs.labyrinth_cyberrunner`; not CyberRunner's, whose world model infers it); pixels
    (``obs="pixels"``) are two frames, the previous observation's and this one's
    (:mod:`bimgame.envs.labyrinth_pixels`). Off by default."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        if self.obs not in NETWORK_OBS:
            raise ValueError(f"{owner}.obs must be one of {NETWORK_OBS}, got {self.obs!r}")
        default_size = 128 if self.obs == "state" else 256
        for name in ("hidden", "features"):
            value = getattr(self, name)
            if value is None:
                object.__setattr__(self, name, default_size)
                continue
            require_int(owner, name, value, 1)
            if value > MAX_NETWORK_SIZE:
                raise ValueError(
                    f"{owner}.{name} must be at most {MAX_NETWORK_SIZE} (the paper's networks use 256), got {value!r}"
                )
        pixels = self.obs == "pixels"
        if self.aux_heads is None:
            object.__setattr__(self, "aux_heads", pixels)
        if self.precision is None:
            object.__setattr__(self, "precision", "bf16" if pixels and native_bf16() else "fp32")
        for name in _SWITCHES:
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{owner}.{name} must be True or False, got {getattr(self, name)!r}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"{owner}.precision must be one of {PRECISIONS}, got {self.precision!r}")
        check_action_type(owner, self.action_type)
        check_cyberrunner_network(owner, self)
        self._check_state_parts(owner, pixels)

    def _check_state_parts(self, owner: str, pixels: bool) -> None:
        """The parts only state observations have: the maze's encoding, its frame, gate bearings and
        the labyrinth's surroundings."""
        if self.maze_encoding and pixels:
            raise ValueError(f"{owner}.maze_encoding applies to state observations only (pixels show the maze)")
        if self.maze_frame not in MAZE_FRAMES:
            raise ValueError(f"{owner}.maze_frame must be one of {MAZE_FRAMES}, got {self.maze_frame!r}")
        if self.maze_frame != "board" and pixels:
            raise ValueError(f"{owner}.maze_frame applies to state observations only (pixels show the maze)")
        for name in ("gate_bearings", "surroundings"):
            if getattr(self, name) and self.obs != "state":
                raise ValueError(f"{owner}.{name} applies to state observations only, got obs {self.obs!r}")
        if self.motion and self.obs not in MOTION_OBS_MODES:
            raise ValueError(
                f"{owner}.motion applies to obs 'cyberrunner' (the marble's observed velocity) and 'pixels' (the "
                f"previous frame) only, got obs {self.obs!r}"
            )
        if self.gate_bearings and self.maze_frame != "board":
            raise ValueError(
                f"{owner}.gate_bearings with maze_frame {self.maze_frame!r}: the bearings are already relative to "
                "the marble; use maze_frame 'board'"
            )

    @property
    def privileged(self) -> bool:
        """Whether learning needs the simulator's state besides the observations."""
        return self.aux_heads or self.asymmetric_critic

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(NetworkSettings))

    def network_settings(self) -> NetworkSettings:
        """Just the network settings (of a learner's settings, which inherit them)."""
        return network_settings_of(dataclasses.asdict(self))

    def net_config(self, maze: PuzzleSpec | None = None) -> tuple[NetConfig, dict[str, Any]]:
        """The network sizes and the fixed inputs to build it with (``obs_scale`` or ``background``,
        keyword arguments of :func:`~bimgame.learn.nets.build_network`) on the board ``maze`` (a task's
        :attr:`~bimgame.envs.puzzles.Puzzle.spec`: the maze's or the labyrinth's; None: MERL's maze)."""
        maze = maze or MazeSpec.merl()
        features, hidden, precision = self.features, self.hidden, self.precision
        # __post_init__ replaced None by the defaults.
        assert features is not None and hidden is not None and precision is not None
        scale = state_obs_scale(maze)
        # The maze's encoding is in [0, 1], but it is 128 inputs, ~25 of them open at once: with Adam
        # every weight moves about as far per update, so their sum moves the first layer ~25× as fast
        # as one state input does (read in the marble's frame, PPO's policy lost its entropy in the
        # first 40k steps). Divided by √128 the encoding's pathway moves at about a state input's pace.
        encoding = maze_encoding_size(maze) if isinstance(maze, MazeSpec) and self.maze_encoding else 0
        # The bearings are a few values of order 1 (sine, cosine, half-width in bins): taken as they are.
        bearings = gate_bearings_size(maze) if isinstance(maze, MazeSpec) and encoding and self.gate_bearings else 0
        maze_scale = [np.full(encoding, np.sqrt(encoding), dtype=np.float32), np.ones(bearings, dtype=np.float32)]
        obs_scale = np.concatenate([scale, *maze_scale]) if encoding else scale
        if isinstance(maze, LabyrinthSpec) and self.surroundings:
            obs_scale = np.concatenate([scale, surroundings_scale()])
        privileged: dict[str, Any] = (
            {
                "privileged_size": len(scale),
                "state_layout": LABYRINTH if isinstance(maze, LabyrinthSpec) else MAZE,
                "aux_heads": self.aux_heads,
                "asymmetric_critic": self.asymmetric_critic,
            }
            if self.privileged
            else {}
        )
        inputs: dict[str, Any] = {"privileged_scale": scale} if self.privileged else {}
        if self.obs == "cyberrunner":
            return cyberrunner_net_config(self, maze, privileged), inputs
        if self.obs == "pixels":
            net_config, background = pixel_net_config(self, maze, privileged)
            return net_config, {"background": background, **inputs}
        net_config = NetConfig(
            encoder="mlp",
            obs_shape=(len(obs_scale),),
            features=features,
            hidden=hidden,
            tilt_input=self.tilt_input,
            action_type=self.action_type,
            maze_size=encoding + bearings,
            maze_frame=self.maze_frame,
            **privileged,
        )
        return net_config, {"obs_scale": obs_scale, **inputs}

    def build_policy(self, seed: int, maze: PuzzleSpec | None = None) -> RecurrentActorCritic:
        """A fresh actor-critic, initialised from ``seed``."""
        net_config, inputs = self.net_config(maze)
        return build_network(net_config, seed=seed, **inputs)

    def build_value(self, seed: int, maze: PuzzleSpec | None = None) -> ValueNetwork:
        """A fresh value-only network V̂ with the same encoder, initialised from ``seed``."""
        net_config, inputs = self.net_config(maze)
        return build_value_network(net_config, seed=seed, **inputs)

    #: What a settings dict of this class is called in errors ("unknown A3C settings [...]").
    SETTINGS_NAME: ClassVar[str] = "network settings"

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Self:
        return from_dict(cls, values, cls.SETTINGS_NAME)


def native_bf16() -> bool:
    """Whether this CPU computes in bfloat16 natively (the ``avx512_bf16`` or ``amx_bf16`` flag of
    /proc/cpuinfo; False where that file does not exist). Without it bf16 autocast is emulated and
    slower than float32."""
    try:
        with open("/proc/cpuinfo") as handle:
            flags = next((line for line in handle if line.startswith("flags")), "").split()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def network_settings_of(values: dict[str, Any]) -> NetworkSettings:
    """The network settings in a flat settings dict (e.g. a stored A3C config); other keys are ignored."""
    return NetworkSettings(**{k: values[k] for k in NetworkSettings.field_names() if k in values})


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """What a run directory holds, read from its ``config.json`` (:func:`read_run`)."""

    run_dir: Path
    kind: str
    """:data:`~bimgame.learn.runs.KIND_A3C`, ``pretrained-policy``, ``value-function``, ``dagger-policy``."""
    task: str
    network: NetworkSettings
    seed: int
    """The seed the run's network was initialised from (and its evaluation seed derives from)."""
    time_limit: int
    """The episode time limit the run trained and evaluates with."""
    config: dict[str, Any]
    """The whole ``config.json``."""


def read_run(source: str | Path) -> RunInfo:
    """The kind, task and network of the run in ``source`` (its directory or a file in it); raises
    ``ValueError`` naming what is missing."""
    source = Path(source)
    run_dir = source.parent if source.is_file() else source
    stored = read_run_config(run_dir)
    kind = stored.get("kind", KIND_A3C)
    block = stored.get("a3c")
    stored_task: Any  # as config.json has it; puzzle() checks it
    try:
        if isinstance(block, dict):  # A3C runs, and pre-training/DAgger runs of the earlier layout
            stored_task, network, seed = block.get("task"), network_settings_of(block), block.get("seed", 0)
            limit = block.get("max_episode_steps")
        elif isinstance(stored.get("network"), dict) and "task" in stored:
            stored_task, network = stored["task"], NetworkSettings.from_dict(stored["network"])
            seed = stored.get("seed", 0)
            limit = stored.get("max_episode_steps")
        else:
            raise ValueError("it names no task and network ('a3c', or 'task' and 'network')")
        task = puzzle(stored_task).task
        if not (isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed <= MAX_SEED):
            raise ValueError(f"seed must be an integer from 0 to {MAX_SEED}, got {seed!r}")
        if limit is not None and not (isinstance(limit, int) and not isinstance(limit, bool) and limit >= 1):
            raise ValueError(f"max_episode_steps must be an integer >= 1, got {limit!r}")
    except (ValueError, TypeError) as error:
        raise ValueError(f"{run_dir / CONFIG}: {error}") from None
    return RunInfo(
        run_dir=run_dir,
        kind=kind,
        task=task,
        network=network,
        seed=int(seed),
        time_limit=int(limit or puzzle(task).time_limit),
        config=stored,
    )


def init_network_settings(source: str | Path) -> dict[str, Any]:
    """The network settings of the run that ``--init`` points at, as a dict ({} for a bare checkpoint
    file outside a run); refuses a value function (V̂ is no policy to start from)."""
    source = Path(source)
    if not source.exists():
        raise ValueError(f"--init: {source} does not exist")
    run_dir = source.parent if source.is_file() else source
    if not (run_dir / CONFIG).is_file():
        return {}
    run = read_run(run_dir)
    if run.kind == KIND_VALUE:
        raise ValueError(
            f"--init: {source} holds a value function (V̂); pass it to --value-reward. --init takes "
            f"a pre-trained policy (bimgame pretrain) or an A3C run"
        )
    return run.network.to_dict()


def load_run_network(source: str | Path) -> tuple[RecurrentActorCritic, RunInfo, int]:
    """The policy network of a run — ``source`` is its directory or a checkpoint file in it — with
    the checkpoint's weights; returns (network, run, step)."""
    source = Path(source)
    expected = "a run directory (with config.json and checkpoint.pt) or a checkpoint file inside one"
    if not source.exists():
        raise ValueError(f"{source} does not exist; expected {expected}")
    run_dir = source.parent if source.is_file() else source
    if not (run_dir / CONFIG).is_file():
        what = (
            f"{source} is a file outside a training run (no {CONFIG} next to it)"
            if source.is_file()
            else f"{source} is not a training run (no {CONFIG})"
        )
        raise ValueError(f"{what}; expected {expected}")
    run = read_run(run_dir)
    if run.kind == KIND_VALUE:
        raise ValueError(f"{run.run_dir} holds a value function (V̂), not a policy; use it with --value-reward")
    net = run.network.build_policy(run.seed, puzzle(run.task).spec)
    step = load_weights(net, source)
    return net, run, step


def load_value_network(source: str | Path) -> tuple[ValueNetwork, RunInfo]:
    """The frozen V̂ of a value pre-training run (``bimgame pretrain --value-only``)."""
    run = read_run(source)
    if run.kind != KIND_VALUE:
        raise ValueError(
            f"{run.run_dir} holds a {run.kind} run, not a value function; train one with "
            f"'bimgame pretrain --value-only'"
        )
    net = run.network.build_value(run.seed)
    load_weights(net, Path(source) if Path(source).is_file() else run.run_dir)
    net.eval()
    for param in net.parameters():
        param.requires_grad_(False)
    return net, run


@dataclasses.dataclass(frozen=True)
class LearnerSettings(FlatSettings):
    """What every on-policy learner's settings (A3C's, PPO's) hold besides their parts: the task, the
    seed and the time limit, checked here once; a subclass adds its parts (and settings of its own)."""

    task: str = "STG1"
    """FULL, STG1 … STG4 (the circular maze's), or LABYRINTH-EASY, -MEDIUM, -HARD (CyberRunner's
    labyrinth: :mod:`bimgame.envs.puzzles`)."""
    seed: int = 0
    """Seeds everything the run draws: the network's initial weights, the environments, the sampling
    and the evaluations."""
    max_episode_steps: int | None = None
    """Time limit; None uses the task's (STG1 300, STG2 500, STG3 750, STG4/FULL 1000, labyrinth 3000)."""
    num_mazes: int | None = None
    """Train on random mazes (:mod:`bimgame.sim.maze_sets`): this many training mazes from number
    ``start_maze`` on, one drawn per episode; 0: unlimited (a new maze every episode). None: MERL's
    maze only. Evaluations during the run use the same mazes; ``bimgame score --mazes test`` scores
    the held-out ones."""
    start_maze: int = 0
    """The first training maze's number (with ``num_mazes``)."""
    off_path_rule: str | None = None
    """The labyrinth only: when the marble is off the path (an episode ends there), for training and the
    run's evaluations: ``tolerance`` (no path segment near it in sight) or ``cyberrunner`` (no path point
    in its free box, CyberRunner's test: :mod:`bimgame.sim.labyrinth_box_sight`). None: the env's default,
    ``tolerance``."""
    fail_reward: float | None = None
    """The labyrinth only: the training reward of a step that falls into a hole or leaves the path (a
    penalty if below 0). None: the env's, CyberRunner's 0. Evaluations during the run use it too;
    ``bimgame score`` scores with the env's."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        object.__setattr__(self, "task", puzzle_task_setting(owner, self.task))
        check_env_rules(owner, self.task, self.off_path_rule, self.fail_reward)
        check_seed(owner, self.seed)  # numpy's seed sequences take no negative seeds, torch none of 2**64
        require_int(owner, "max_episode_steps", self.max_episode_steps, 1, optional=True)
        check_at_most(owner, "max_episode_steps", self.max_episode_steps, MAX_STEPS, "1e12 environment steps")
        network = maze_network(
            owner, self.task, getattr(self, "network", None), num_mazes=self.num_mazes, start_maze=self.start_maze
        )
        self.check_parts()
        if network is not getattr(self, "network", None):
            object.__setattr__(self, "network", network)

    @property
    def maze_options(self) -> dict[str, Any]:
        """The env arguments of the run's mazes (empty on MERL's maze alone), or on the labyrinth of its
        observation extras and env rules (off-path rule, reward of a fall)."""
        return network_env_options(getattr(self, "network", None), self.num_mazes, self.start_maze, run_rules(self))

    @property
    def time_limit(self) -> int:
        return self.max_episode_steps or puzzle(self.task).time_limit


class EvaluatedRun(Protocol):
    """What :func:`run_evaluation` reads of a learner's settings (A3C's, PPO's)."""

    @property
    def task(self) -> str: ...
    @property
    def seed(self) -> int: ...
    @property
    def network(self) -> NetworkSettings: ...
    @property
    def schedule(self) -> ScheduleSettings: ...
    @property
    def time_limit(self) -> int: ...
    @property
    def maze_options(self) -> dict[str, Any]: ...


def run_evaluation(net: RecurrentActorCritic, config: EvaluatedRun) -> dict[str, float]:
    """A run's periodic and final evaluation: greedy and sampled, over its ``eval_episodes`` episodes
    from its evaluation seed, on its task and time limit — the same start positions every time."""
    return evaluate_greedy_and_sampled(
        net,
        task=config.task,
        obs=config.network.obs,
        episodes=config.schedule.eval_episodes,
        seed=evaluation_seed(config.seed),
        time_limit=config.time_limit,
        mazes=config.maze_options,
    )
