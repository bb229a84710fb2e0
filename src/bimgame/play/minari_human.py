"""The Minari (HDF5) file of a human recording, written by a child process.

As for the expert's datasets (:mod:`bimgame.expert.minari_build`), HDF5 does not survive a failed
write cleanly, so a child process writes the file into a temporary datasets root and only that
process can fail; its error output is captured and a full disk is recognised in it. The child runs
in a session of its own, so the Ctrl-C that stops ``bimgame play`` does not stop the last build.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimgame.expert import minari_build
from bimgame.expert.minari_build import episode_path, read_episode, write_minari

__all__ = ["ALGORITHM_NAME", "run_build_process", "read_human_episode", "write_human_minari"]

#: Minari's ``algorithm_name`` of human recordings (the expert's datasets say ``RandomShootingMPC``).
ALGORITHM_NAME = "human (bimgame play)"
_CHUNK = 64
#: Seconds a build may take before it is given up (and retried): a hung child must not hang the server's exit.
BUILD_TIMEOUT = 900


def read_human_episode(out_dir: Path, index: int) -> dict[str, np.ndarray]:
    """Episode file ``index`` of a recording, checked as the expert's are (its seed is its own)."""
    return read_episode(episode_path(out_dir, index), index, None)


def run_build_process(out_dir: Path, manifest: dict, episodes: int, build_root: Path) -> None:
    """Write the Minari dataset of episode files 0 … ``episodes``-1 of ``out_dir`` into the datasets
    root ``build_root`` with the expert datasets' build process
    (:func:`bimgame.expert.minari_build.run_build_process`), in a session of its own and with a
    timeout; raises ``OSError(ENOSPC)`` for a full disk, else a ``RuntimeError`` with the end of
    the child's error output."""
    minari_build.run_build_process(
        out_dir,
        manifest,
        build_root,
        _CHUNK,
        episodes=episodes,
        writer="bimgame.play.minari_human:write_human_minari",
        timeout=BUILD_TIMEOUT,
        own_session=True,
    )


def write_human_minari(out_dir: Path, manifest: dict, episodes: int, chunk: int) -> None:
    """The recording's writer (the build process runs it)."""
    write_minari(
        manifest,
        episodes,
        chunk,
        lambda index: read_human_episode(out_dir, index),
        algorithm_name=ALGORITHM_NAME,
        description=_description(manifest, episodes),
        author="people playing bimgame play",
    )


def _description(manifest: dict, episodes: int) -> str:
    limit = manifest["max_steps"] if manifest["max_steps"] is not None else "the task's registered limit"
    return (
        f"Human play recorded with 'bimgame play --record' on {manifest['env_id']} (source: human): "
        f"{episodes} episodes; time limit {limit} steps. Only steps a person controlled are recorded: an "
        "episode the person took over from an agent starts at the physics state of the take-over "
        "(infos['sim_state'][0]); one handed back to the agent, reset or stopped early ends truncated. "
        "Observations are state observations; infos['sim_state'] (T+1, S) MuJoCo physics states and "
        "infos['channel'] (T+1, n) task channels re-render pixel observations exactly "
        "(bimgame.expert.datasets.iterate_sequences(..., obs='pixels'))."
    )
