"""The Minari (HDF5) file of a human recording, written by a child process.

As for the expert's datasets (:mod:`bimgame.expert.minari_build`), HDF5 does not survive a failed
write cleanly, so a child process writes the file into a temporary datasets root and only that
process can fail; its error output is captured and a full disk is recognised in it. The child runs
in a session of its own, so the Ctrl-C that stops ``bimgame play`` does not stop the last build.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import traceback
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import minari
import numpy as np
from minari.data_collector import EpisodeBuffer

from bimgame.expert.minari_build import episode_path, read_episode
from bimgame.expert.references import references_for
from bimgame.util.files import disk_full_errno
from bimgame.util.processes import exit_when_parent_dies

__all__ = ["ALGORITHM_NAME", "run_build_process", "read_human_episode"]

#: Minari's ``algorithm_name`` of human recordings (the expert's datasets say ``RandomShootingMPC``).
ALGORITHM_NAME = "human (bimgame play)"
_CHUNK = 64
#: Seconds a build may take before it is given up (and retried): a hung child must not hang the server's exit.
BUILD_TIMEOUT = 900
_ERROR_LINES = 30
_DISK_FULL_EXITS = (errno.ENOSPC, errno.EDQUOT)
_SCRIPT = ("import json, sys\n"
           "job = json.load(sys.stdin)\n"
           "sys.path[:] = job['sys_path']\n"
           "from bimgame.play.minari_human import _build_process_main\n"
           "_build_process_main(job)\n")


def read_human_episode(out_dir: Path, index: int) -> dict[str, np.ndarray]:
    """Episode file ``index`` of a recording, checked as the expert's are (its seed is its own)."""
    path = episode_path(out_dir, index)
    try:
        with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as archive:
            seed = int(archive["seed"])
    except Exception:  # read_episode names the problem
        seed = -1
    return read_episode(path, index, seed)


def run_build_process(out_dir: Path, manifest: dict, episodes: int, build_root: Path) -> None:
    """Write the Minari dataset of episode files 0 … ``episodes``-1 of ``out_dir`` into the datasets
    root ``build_root`` with a child process; raises ``OSError(ENOSPC)`` for a full disk, else a
    ``RuntimeError`` with the end of the child's error output."""
    job = {"sys_path": sys.path, "parent_pid": os.getpid(), "out_dir": str(out_dir), "manifest": manifest,
           "episodes": episodes}
    result = subprocess.run([sys.executable, "-c", _SCRIPT], input=json.dumps(job).encode(), capture_output=True,
                            env={**os.environ, "MINARI_DATASETS_PATH": str(build_root)}, start_new_session=True,
                            timeout=BUILD_TIMEOUT, check=False)
    output = result.stderr.decode(errors="replace")
    if result.returncode == 0:
        return
    code = result.returncode if result.returncode in _DISK_FULL_EXITS else disk_full_errno(output)
    if code is not None:
        raise OSError(code, os.strerror(code))
    how = f"killed by signal {-result.returncode}" if result.returncode < 0 else f"exit status {result.returncode}"
    tail = "\n".join(output.rstrip().splitlines()[-_ERROR_LINES:])
    raise RuntimeError(f"building the Minari dataset of {out_dir} failed ({how}):\n{tail}")


def _build_process_main(job: dict) -> None:
    exit_when_parent_dies(job["parent_pid"])
    try:
        _write_minari(Path(job["out_dir"]), job["manifest"], int(job["episodes"]))
    except BaseException as error:
        code = disk_full_errno(error)
        if code is None:
            traceback.print_exc()
            code = 1
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def _buffers(out_dir: Path, indices: range) -> list[EpisodeBuffer]:
    buffers = []
    for index in indices:
        data = read_human_episode(out_dir, index)
        buffers.append(EpisodeBuffer(
            id=index, seed=int(data["seed"]), observations=data["observations"], actions=data["actions"],
            rewards=data["rewards"], terminations=data["terminations"], truncations=data["truncations"],
            infos={"sim_state": data["sim_states"], "channel": data["channels"]}))
    return buffers


def _write_minari(out_dir: Path, manifest: dict, episodes: int) -> None:
    kwargs: dict[str, Any] = {"obs_mode": "state"}
    if manifest["max_steps"] is not None:
        kwargs["max_episode_steps"] = manifest["max_steps"]
    env = gym.make(manifest["env_id"], **kwargs)
    pair = references_for(manifest["task"]) if manifest["max_steps"] is None else None
    scores = {} if pair is None else {"ref_min_score": pair[0], "ref_max_score": pair[1]}
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"`(code_permalink|author_email)` is set to None")
            dataset = minari.create_dataset_from_buffers(
                dataset_id=manifest["dataset_id"], buffer=_buffers(out_dir, range(min(_CHUNK, episodes))),
                env=env, eval_env=env.spec, algorithm_name=ALGORITHM_NAME, author="people playing bimgame play",
                description=_description(manifest, episodes), data_format="hdf5",
                requirements=[f"bimgame=={manifest['bimgame_version']}"], **scores)
            for start in range(_CHUNK, episodes, _CHUNK):
                dataset.update_dataset_from_buffer(_buffers(out_dir, range(start, min(start + _CHUNK, episodes))))
    finally:
        env.close()


def _description(manifest: dict, episodes: int) -> str:
    limit = manifest["max_steps"] if manifest["max_steps"] is not None else "the task's registered limit"
    return (f"Human play recorded with 'bimgame play --record' on {manifest['env_id']} (source: human): "
            f"{episodes} episodes; time limit {limit} steps. Only steps a person controlled are recorded: an "
            "episode the person took over from an agent starts at the physics state of the take-over "
            "(infos['sim_state'][0]); one handed back to the agent, reset or stopped early ends truncated. "
            "Observations are state observations; infos['sim_state'] (T+1, S) MuJoCo physics states and "
            "infos['channel'] (T+1, n) task channels re-render pixel observations exactly "
            "(bimgame.expert.datasets.iterate_sequences(..., obs='pixels')).")
