"""A person's episodes as a dataset directory in the format of ``bimgame generate``, appended to as
they are played, resumable, and marked as human.

The directory has the layout of an expert dataset (:mod:`bimgame.expert.datasets`), so that
``load_dataset``, ``iterate_sequences``, ``bimgame pretrain --data`` and ``--expert-data`` read it
as they read the expert's::

    generation.json        format, task, episode count, "source": "human", versions
    episodes/episode_000000.npz …   one file per episode, written atomically when the episode ends
    minari/bimgame/<task>-human-v0/data/{metadata.json, main_data.hdf5}
    COMPLETE               counts, content hash, every file's size and SHA-256

**When an episode is written.** :class:`EpisodeBuilder` collects the steps a person controlled.
Its episode is saved when the game episode ends (the goal: terminated; the time limit: truncated),
and, truncated, when the person resets (R) after at least one step, hands control to the agent, or
the server stops. Steps the agent played are never recorded: an episode the person took over
mid-way starts at the physics state of the take-over (``infos["sim_state"][0]``; the episode file's
``start_step`` says after how many agent steps).

**Crash safety.** The episode files are the record; everything else is rebuilt from them. An
episode file is written atomically (temporary file, then rename) before anything else changes.
Then, in a background thread, the Minari file is built in a temporary directory by a child
process, the ``COMPLETE`` marker is removed, the new Minari directory swapped in, the manifest's
episode count raised and a new marker written — last. A crash (``kill -9``, power loss) at any
point leaves every earlier episode file intact and the directory either complete with the earlier
episodes or without a marker (``load_dataset`` refuses it as incomplete); the next
``bimgame play --record DIR`` finds the episode files and rebuilds. A process lock keeps two
servers from recording into one directory at once.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import shutil
import tempfile
import threading
from pathlib import Path
from typing import Any

import minari
import numpy as np

import bimgame
from bimgame.expert.dataset_files import (
    BUILD_PREFIX,
    FORMAT_NAME,
    FORMAT_VERSION,
    LOCK_NAME,
    MANIFEST_NAME,
    MARKER_NAME,
    MINARI_DIR,
    episode_totals,
    remove_stale_temporaries,
)
from bimgame.expert.datasets import DatasetError, dataset_id_for
from bimgame.expert.generation import write_marker
from bimgame.expert.minari_build import episode_path
from bimgame.play.minari_human import read_human_episode, run_build_process
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.files import atomic_write_bytes, exclusive_lock, read_json, write_json

__all__ = ["SOURCE", "EpisodeBuilder", "HumanRecording"]

log = logging.getLogger("bimgame.play")

#: ``generation.json``'s ``source`` for recordings (expert datasets have none, or ``"expert"``).
SOURCE = "human"
_OLD_PREFIX = ".minari-old-"


class EpisodeBuilder:
    """The steps of one episode a person controlled, from the state they started in."""

    def __init__(self, *, seed: int, start_step: int, obs: np.ndarray, sim_state: np.ndarray, channel: np.ndarray):
        self.seed, self.start_step = int(seed), int(start_step)
        self.observations, self.sim_states, self.channels = [obs], [sim_state], [channel]
        self.actions: list[int] = []
        self.rewards: list[float] = []

    @property
    def steps(self) -> int:
        return len(self.actions)

    def add(self, action: int, reward: float, obs: np.ndarray, sim_state: np.ndarray, channel: np.ndarray) -> None:
        self.actions.append(int(action))
        self.rewards.append(float(reward))
        self.observations.append(obs)
        self.sim_states.append(sim_state)
        self.channels.append(channel)

    def finish(self, *, terminated: bool, reason: str) -> dict[str, Any]:
        """The episode's arrays (those of :func:`bimgame.expert.mpc.run_expert_episode`, plus
        ``start_step`` and ``end_reason``): terminated at the goal, else truncated."""
        steps = self.steps
        if steps < 1:
            raise ValueError("an episode needs at least one step")
        terminations = np.zeros(steps, dtype=bool)
        truncations = np.zeros(steps, dtype=bool)
        (terminations if terminated else truncations)[-1] = True
        return {
            "actions": np.array(self.actions, dtype=np.int64),
            "rewards": np.array(self.rewards, dtype=np.float64),
            "terminations": terminations,
            "truncations": truncations,
            "observations": np.array(self.observations, dtype=np.float32),
            "sim_states": np.array(self.sim_states, dtype=np.float64),
            "channels": np.array(self.channels, dtype=np.int64),
            "seed": np.int64(self.seed),
            "success": np.bool_(terminated),
            "start_step": np.int64(self.start_step),
            "end_reason": np.str_(reason),
        }


class HumanRecording:
    """The recording directory ``out_dir`` of ``task`` episodes with time limit ``max_steps`` (None:
    the task's): :meth:`open` it (creating it, or resuming one of the same task and limit), :meth:`add`
    episodes, :meth:`close` it (waits for the last Minari build)."""

    def __init__(self, out_dir: str | Path, task: str | Task, *, max_steps: int | None = None, seed: int = 0):
        self.out_dir = Path(out_dir).absolute()
        self.shown_dir = str(out_dir)  # as the person gave it, for the page
        self.task = parse_task(task)
        self.max_steps = max_steps
        self.seed = int(seed)
        self.episodes = 0  # episode files saved
        self.built = 0  # episodes in the Minari dataset and the COMPLETE marker
        self.last_error: str | None = None
        self._lock_context: contextlib.AbstractContextManager[None] | None = None
        self._wake = threading.Condition()
        self._closing = False
        self._thread: threading.Thread | None = None

    # ----------------------------------------------------------------- life cycle
    def open(self) -> int:
        """Create or resume the directory and lock it; returns the number of episodes already there."""
        out = self.out_dir
        if out.exists() and not out.is_dir():
            raise NotADirectoryError(f"--record {out} exists and is not a directory")
        manifest_path = out / MANIFEST_NAME
        if manifest_path.exists():
            self._check_existing(read_json(manifest_path))
        elif out.exists() and any(not p.name.startswith(".") for p in out.iterdir()):
            raise FileExistsError(
                f"--record {out} is not empty and is not a recording (no {MANIFEST_NAME}); "
                "nothing was changed. Use a new or empty directory, or an earlier recording"
            )
        out.mkdir(parents=True, exist_ok=True)
        self._lock_context = exclusive_lock(out / LOCK_NAME, f"another process is recording into {out}")
        self._lock_context.__enter__()
        try:
            remove_stale_temporaries(self.out_dir, (BUILD_PREFIX, _OLD_PREFIX))
            while episode_path(out, self.episodes).exists():
                read_human_episode(out, self.episodes)  # refuses an unreadable file, naming it
                self.episodes += 1
            manifest = read_json(manifest_path)
            if manifest is None:
                write_json(manifest_path, self._manifest(0))
            marker = read_json(out / MARKER_NAME)
            self.built = self.episodes if (self.episodes and self._marker_matches(marker)) else 0
        except BaseException:
            self._release_lock()
            raise
        self._thread = threading.Thread(target=self._build_loop, name="bimgame-play-recording", daemon=True)
        self._thread.start()
        if self.built != self.episodes:
            log.info(
                "recording %s: %d episode files, %d in the Minari dataset; rebuilding", out, self.episodes, self.built
            )
            self._kick()
        return self.episodes

    def add(self, episode: dict[str, Any]) -> int:
        """Save an episode (atomically, at once) and queue the Minari rebuild; returns its index."""
        if self._thread is None:
            raise RuntimeError("open() the recording first")
        index = self.episodes
        buffer = io.BytesIO()
        np.savez(buffer, index=np.int64(index), **episode)
        atomic_write_bytes(episode_path(self.out_dir, index), buffer.getvalue())
        self.episodes += 1
        self._kick()
        return index

    def close(self, timeout: float | None = None) -> bool:
        """Finish the pending Minari build and release the directory; returns whether the dataset is
        complete (every saved episode built)."""
        if self._thread is not None:
            with self._wake:
                self._closing = True
                self._wake.notify_all()
            self._thread.join(timeout)
            if self._thread.is_alive():
                return False
            self._thread = None
        self._release_lock()
        return self.built == self.episodes

    def wait_built(self, timeout: float) -> bool:
        """Wait until every saved episode is in the Minari dataset (for tests); returns whether it is."""
        with self._wake:
            return self._wake.wait_for(lambda: self.built == self.episodes, timeout)

    @property
    def status(self) -> dict:
        return {"dir": self.shown_dir, "episodes": self.episodes, "built": self.built, "error": self.last_error}

    # ----------------------------------------------------------------- building
    def _kick(self) -> None:
        with self._wake:
            self._wake.notify_all()

    def _build_loop(self) -> None:
        while True:
            with self._wake:
                self._wake.wait_for(lambda: self.built != self.episodes or self._closing)
                target = self.episodes
                if target == self.built:
                    return  # closing with nothing left to build
            try:
                self._build(target)
                self.last_error = None
            except Exception as error:  # noqa: BLE001 - reported on the page and in the log; the episode files stay
                self.last_error = f"{type(error).__name__}: {error}"
                log.error(
                    "recording %s: building the Minari dataset failed (the episode files are kept; the "
                    "next start rebuilds it): %s",
                    self.out_dir,
                    self.last_error,
                )
                with self._wake:
                    if self._closing:
                        return
                    self._wake.wait(5.0)  # retry later, or when the next episode comes
                continue
            with self._wake:
                self.built = target
                self._wake.notify_all()

    def _build(self, episodes: int) -> None:
        out = self.out_dir
        totals = episode_totals(episodes, lambda index: read_human_episode(out, index))
        manifest = self._manifest(episodes)
        build_root = Path(tempfile.mkdtemp(prefix=BUILD_PREFIX, dir=out))
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(build_root, 0o777 & ~umask)  # mkdtemp's 0700 would hide the dataset from other users
        try:
            run_build_process(out, manifest, episodes, build_root)
            (out / MARKER_NAME).unlink(missing_ok=True)  # from here until the new marker: incomplete
            final = out / MINARI_DIR
            if final.exists():
                old = Path(tempfile.mkdtemp(prefix=_OLD_PREFIX, dir=out))
                os.replace(final, old / MINARI_DIR)
                os.replace(build_root, final)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(build_root, final)
        finally:
            shutil.rmtree(build_root, ignore_errors=True)
        write_json(out / MANIFEST_NAME, manifest)
        write_marker(out, manifest["dataset_id"], episodes, totals)

    # ----------------------------------------------------------------- files
    def _manifest(self, episodes: int) -> dict:
        existing = read_json(self.out_dir / MANIFEST_NAME) or {}
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "source": SOURCE,
            "task": self.task.value,
            "episodes": episodes,
            "seed": existing.get("seed", self.seed),
            "max_steps": self.max_steps,
            "mpc_config": None,
            "recorded_with": "bimgame play",
            "bimgame_version": bimgame.__version__,
            "dataset_id": dataset_id_for(self.task, SOURCE),
            "env_id": f"BiMGame/{self.task.value}-v0",
            "minari_version": minari.__version__,
        }

    def _check_existing(self, manifest: dict | None) -> None:
        where = f"--record {self.out_dir}"
        if manifest is None or manifest.get("format") != FORMAT_NAME:
            raise DatasetError(f"{where}: {MANIFEST_NAME} is not a bimgame dataset manifest; nothing was changed")
        if manifest.get("source") != SOURCE:
            raise ValueError(
                f"{where} holds an expert dataset (bimgame generate), not a human recording; "
                "record into another directory"
            )
        if manifest.get("format_version") != FORMAT_VERSION:
            raise DatasetError(
                f"{where} has format version {manifest.get('format_version')!r}; this bimgame "
                f"writes version {FORMAT_VERSION}"
            )
        if manifest.get("task") != self.task.value or manifest.get("max_steps") != self.max_steps:
            raise ValueError(
                f"{where} holds {manifest.get('task')} episodes with time limit "
                f"{manifest.get('max_steps') or 'the task default'}; this session plays {self.task.value} "
                f"with {self.max_steps or 'the task default'}: give the same --task and --max-steps "
                "to add to it, or record into another directory"
            )

    def _marker_matches(self, marker: dict | None) -> bool:
        """Whether the COMPLETE marker covers exactly the saved episodes, file sizes unchanged."""
        manifest = read_json(self.out_dir / MANIFEST_NAME) or {}
        if not marker or marker.get("episodes") != self.episodes or manifest.get("episodes") != self.episodes:
            return False
        try:
            return all((self.out_dir / name).stat().st_size == entry["size"] for name, entry in marker["files"].items())
        except (OSError, KeyError, TypeError, AttributeError):
            return False

    def _release_lock(self) -> None:
        if self._lock_context is not None:
            self._lock_context.__exit__(None, None, None)
            self._lock_context = None
