"""One episode of the labyrinth's MPC expert as its dataset stores it (used by
:mod:`bimgame.expert.labyrinth_datasets`): recorded step by step, saved as one ``.npz`` file, read
back checked, and written into the Minari dataset.

An episode of T steps holds (the names of its ``.npz`` file, :data:`EPISODE_KEYS`):

- ``observations`` (T+1, 17) float32: the env's ``obs_mode="state"`` observations, from ``reset``'s
  to the last step's;
- ``actions``: (T, 2) float32 tilt-rate fractions in [-1, 1] as executed (continuous), or (T,) int64
  actions 0..4 (discrete);
- ``rewards`` (T,) float64, ``terminations``, ``truncations`` (T,) bool (truncated: the time limit
  ended it);
- ``tilt`` (T+1, 2) float64: the board's tilt (rad), what a network takes besides its observation;
- ``sim_states`` (T+1, S) float64: MuJoCo physics states (``env.sim.get_state()``), and
  ``segments`` (T+1,) int64, ``progress`` (T+1,) float64: the marble's path segment and progress
  (m). From a physics state and the progress, :meth:`~bimgame.envs.labyrinth_env.LabyrinthEnv.observe_state`
  renders any observation of that step exactly (pixels, CyberRunner's);
- per episode: ``seed`` (its reset seed), ``success``, ``failure`` (``"hole"``, ``"off_path"``,
  ``"time"``; ``""`` when successful), ``time_s`` (steps / control rate: the completion time of a
  successful episode).

Episode ``i`` of a run with seed ``seed`` starts from ``reset(seed=episode_seed(seed, i))``, with the
expert's generator seeded with the same number (as the maze's expert episodes,
:func:`~bimgame.expert.mpc.run_expert_episode`): it depends on the run seed and its index only.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from minari.data_collector import EpisodeBuffer

from bimgame.envs.labyrinth_env import LabyrinthEnv, labyrinth_max_episode_steps
from bimgame.expert.labyrinth_mpc import LabyrinthMPC, LabyrinthMPCConfig
from bimgame.expert.minari_build import DatasetError, episode_path, load_episode_arrays, write_minari
from bimgame.expert.pool import EpisodeOutcome
from bimgame.util.seeding import episode_seed

__all__ = [
    "EPISODE_KEYS",
    "FAILURES",
    "ALGORITHM_NAME",
    "LABYRINTH_WRITER",
    "STATE_SIZE",
    "record_labyrinth_episode",
    "labyrinth_episode_job",
    "read_labyrinth_episode",
    "labyrinth_episode_buffer",
    "labyrinth_env_kwargs",
    "episode_time_limit",
    "write_labyrinth_minari",
]

EPISODE_KEYS = (
    "actions",
    "rewards",
    "terminations",
    "truncations",
    "observations",
    "tilt",
    "sim_states",
    "segments",
    "progress",
    "seed",
    "success",
    "failure",
    "time_s",
)
#: How an unsuccessful episode ended: in a hole, off the path, or at the time limit.
FAILURES = ("hole", "off_path", "time")
ALGORITHM_NAME = "LabyrinthRandomShootingMPC"
#: The Minari build process's writer of the labyrinth's datasets (``module:function``).
LABYRINTH_WRITER = "bimgame.expert.labyrinth_episodes:write_labyrinth_minari"
#: Length of the labyrinth's state observation (``obs_mode="state"``).
STATE_SIZE = 17


# ------------------------------------------------------------------------------------ recording
def record_labyrinth_episode(env: LabyrinthEnv, expert: LabyrinthMPC, *, seed: int, max_steps: int) -> dict[str, Any]:
    """Play one episode of ``expert`` on ``env`` (a state-observation :class:`LabyrinthEnv`, no
    wrappers) from ``env.reset(seed=seed)``, truncated after ``max_steps``, and return its arrays
    (the module docstring's). The expert gets the true physics state and the env's path segment,
    as :func:`~bimgame.expert.labyrinth_mpc.run_labyrinth_expert_episode` gives them."""
    obs, info = env.reset(seed=seed)
    expert.reset()
    steps: dict[str, list[Any]] = {
        "observations": [obs],
        "sim_states": [env.sim.get_state()],
        "tilt": [info["tilt"]],
        "segments": [info["segment"]],
        "progress": [info["progress"]],
    }
    actions, rewards, terminations, truncations = [], [], [], []
    for step in range(max_steps):
        action = _executable(expert.act(steps["sim_states"][-1], steps["segments"][-1]), env.action_type)
        obs, reward, terminated, _, info = env.step(action)
        actions.append(action)
        rewards.append(reward)
        terminations.append(terminated)
        truncations.append(not terminated and step == max_steps - 1)
        for key, value in (("observations", obs), ("sim_states", env.sim.get_state()), ("tilt", info["tilt"])):
            steps[key].append(value)
        steps["segments"].append(info["segment"])
        steps["progress"].append(info["progress"])
        if terminated:
            break
    success = bool(info["is_success"])
    failure = "" if success else "hole" if info["over_hole"] else "off_path" if info["off_path"] else "time"
    continuous = env.action_type == "continuous"
    return {
        "actions": np.array(actions, dtype=np.float32).reshape(-1, 2) if continuous else np.array(actions, np.int64),
        "rewards": np.array(rewards, dtype=np.float64),
        "terminations": np.array(terminations, dtype=bool),
        "truncations": np.array(truncations, dtype=bool),
        "observations": np.array(steps["observations"], dtype=np.float32),
        "tilt": np.array(steps["tilt"], dtype=np.float64),
        "sim_states": np.array(steps["sim_states"], dtype=np.float64),
        "segments": np.array(steps["segments"], dtype=np.int64),
        "progress": np.array(steps["progress"], dtype=np.float64),
        "seed": np.int64(seed),
        "success": np.bool_(success),
        "failure": np.str_(failure),
        "time_s": np.float64(len(actions) / env.control_hz),
    }


def _executable(action: Any, action_type: str) -> Any:
    """The expert's action as the env executes it and the dataset records it: a float32 pair within
    the action space's [-1, 1] (the expert's rate levels are already), or an int."""
    if action_type == "discrete":
        return int(action)
    return np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)


def episode_time_limit(control_hz: int, max_steps: int | None) -> int:
    """Steps an episode may last: ``max_steps``, or CyberRunner's 54.5 s at ``control_hz`` (3000 at 55 Hz)."""
    return max_steps if max_steps is not None else labyrinth_max_episode_steps(control_hz)


def labyrinth_episode_job(
    layout: str,
    action_type: str,
    control_hz: int,
    index: int,
    seed: int,
    config: LabyrinthMPCConfig,
    max_steps: int | None,
) -> EpisodeOutcome:
    """Episode ``index`` of the run ``seed`` (what a worker runs, :func:`bimgame.expert.pool.run_jobs`):
    (index, the episode's arrays, seconds it took)."""
    start = time.perf_counter()
    reset_seed = episode_seed(seed, index)
    env = LabyrinthEnv(layout, action_type=action_type, control_hz=control_hz, obs_mode="state")
    expert = LabyrinthMPC.for_env(env, config, rng=np.random.default_rng(reset_seed))
    try:
        episode = record_labyrinth_episode(
            env, expert, seed=reset_seed, max_steps=episode_time_limit(control_hz, max_steps)
        )
    finally:
        expert.close()
        env.close()
    return index, episode, time.perf_counter() - start


# ------------------------------------------------------------------------------- reading back
def read_labyrinth_episode(path: Path, index: int, expected_seed: int, action_type: str) -> dict[str, np.ndarray]:
    """An episode file's arrays, checked for completeness and consistency (else DatasetError naming
    the file and what is wrong): episode ``index`` of seed ``expected_seed``, with ``action_type`` actions."""
    data = load_episode_arrays(path, EPISODE_KEYS)
    if int(data["index"]) != index or int(data["seed"]) != expected_seed:
        raise DatasetError(
            f"episode file {path} holds episode {int(data['index'])} with seed {int(data['seed'])}, "
            f"expected episode {index} with seed {expected_seed}"
        )
    problem = _inconsistency(data, action_type)
    if problem:
        raise DatasetError(f"episode file {path} is inconsistent: {problem}")
    return data


def _inconsistency(data: dict[str, np.ndarray], action_type: str) -> str:
    """What is wrong with an episode's arrays ("" if nothing)."""
    actions = data["actions"]
    steps = len(actions)
    if steps < 1:
        return "no steps"
    if any(len(data[key]) != steps for key in ("rewards", "terminations", "truncations")):
        return "rewards, terminations and truncations must have one entry per action"
    if any(len(data[key]) != steps + 1 for key in ("observations", "tilt", "sim_states", "segments", "progress")):
        return "observations, tilt, sim_states, segments and progress must have one entry more than the actions"
    if data["observations"].shape[1:] != (STATE_SIZE,):
        return f"observations have shape {data['observations'].shape}, not (T+1, {STATE_SIZE})"
    ends = data["terminations"] | data["truncations"]
    if not ends[-1] or ends[:-1].any():
        return "the episode must end at its last step and only there"
    if action_type == "continuous":
        if actions.dtype != np.float32 or actions.shape != (steps, 2) or not np.all(np.abs(actions) <= 1):
            return f"continuous actions must be (T, 2) float32 in [-1, 1], got {actions.dtype} {actions.shape}"
    elif actions.dtype != np.int64 or actions.shape != (steps,) or actions.min() < 0 or actions.max() > 4:
        return f"discrete actions must be (T,) int64 in 0..4, got {actions.dtype} {actions.shape}"
    failure = str(data["failure"])
    if bool(data["success"]) != (failure == "") or (failure and failure not in FAILURES):
        return f"success {bool(data['success'])} with failure {failure!r} (allowed: '', {', '.join(FAILURES)})"
    if bool(data["success"]) and not data["terminations"][-1]:
        return "a successful episode must end terminated"
    return ""


# -------------------------------------------------------------------------------------- Minari
def labyrinth_episode_buffer(index: int, data: dict[str, np.ndarray]) -> EpisodeBuffer:
    """An episode file's arrays as Minari's buffer: the physics states, tilts, path segments and
    progress as infos (T+1 of each, as the observations), the reset seed as the episode's seed."""
    infos = {
        "sim_state": data["sim_states"],
        "tilt": data["tilt"],
        "segment": data["segments"],
        "progress": data["progress"],
    }
    return EpisodeBuffer(
        id=index,
        seed=int(data["seed"]),
        observations=data["observations"],
        actions=data["actions"],
        rewards=data["rewards"],
        terminations=data["terminations"],
        truncations=data["truncations"],
        infos=infos,
    )


def labyrinth_env_kwargs(manifest: dict[str, Any]) -> dict[str, Any]:
    """The arguments of ``gym.make(manifest["env_id"], ...)`` that make the env a dataset was played in."""
    return {
        "action_type": manifest["action_type"],
        "control_hz": manifest["control_hz"],
        "obs_mode": "state",
        "max_episode_steps": episode_time_limit(manifest["control_hz"], manifest["max_steps"]),
    }


def write_labyrinth_minari(out_dir: Path, manifest: dict[str, Any], episodes: int, chunk: int) -> None:
    """The labyrinth dataset's writer (the build process runs it,
    :func:`~bimgame.expert.minari_build.run_build_process`): episode i's file holds the episode of
    seed ``episode_seed(manifest["seed"], i)``."""
    seed, action_type = manifest["seed"], manifest["action_type"]
    write_minari(
        manifest,
        episodes,
        chunk,
        lambda index: read_labyrinth_episode(
            episode_path(out_dir, index), index, episode_seed(seed, index), action_type
        ),
        algorithm_name=ALGORITHM_NAME,
        description=_description(manifest),
        buffer=labyrinth_episode_buffer,
        env_kwargs=labyrinth_env_kwargs(manifest),
    )


def _description(manifest: dict[str, Any]) -> str:
    limit = episode_time_limit(manifest["control_hz"], manifest["max_steps"])
    return (
        f"Expert trajectories of bimgame's random-shooting MPC expert on CyberRunner's labyrinth "
        f"({ALGORITHM_NAME}, acting on simulator states; bimgame.expert.labyrinth_mpc) on {manifest['env_id']} "
        f"({manifest['layout']} layout, {manifest['action_type']} actions at {manifest['control_hz']} Hz): "
        f"{manifest['episodes']} episodes; episode i starts from "
        f"reset(seed=bimgame.util.seeding.episode_seed({manifest['seed']}, i)); time limit {limit} steps; "
        f"MPC config {json.dumps(manifest['mpc_config'])}; bimgame {manifest['bimgame_version']}. "
        "Observations are the 17 state values; infos['sim_state'] (T+1, S) MuJoCo physics states and "
        "infos['progress'] (T+1,) path progress (m) re-render any observation exactly "
        "(LabyrinthEnv.observe_state; bimgame.expert.labyrinth_datasets.load_labyrinth_sequences), "
        "infos['tilt'] (T+1, 2) is the board's tilt (rad), infos['segment'] the marble's path segment."
    )
