"""Shared, session-scoped fixtures: an expert dataset and the networks pre-trained on it.

They are expensive (the dataset takes about a minute of MPC planning), so they are built once per
test session, lazily, by the first test that asks for them."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Callable

# The suite runs as two xdist workers on two cores: one intra-op thread per process, subprocesses
# included (set before torch starts its thread pool). A second thread spins against the other
# worker: the 100k-step PPO test took 12 minutes with two threads on a loaded machine.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest  # noqa: E402
import torch  # noqa: E402
from filelock import FileLock  # noqa: E402

from bimgame.cli.main import main  # noqa: E402
from bimgame.expert.datasets import generate_dataset  # noqa: E402
from bimgame.expert.labyrinth_datasets import generate_labyrinth_dataset  # noqa: E402
from bimgame.learn.pretrain import PretrainResult, pretrain  # noqa: E402
from bimgame.learn.runs import torch_threads  # noqa: E402
from bimgame.learn.supervised import PretrainConfig  # noqa: E402
from support.labyrinth_runs import SMALL_STATE_FLAGS  # noqa: E402

torch.set_num_threads(1)

#: Episodes of :func:`stg1_dataset` (≈0.6 s of MPC planning each on one core).
STG1_DATASET_EPISODES = 60
STG1_DATASET_SEED = 0


@pytest.fixture
def one_torch_thread():
    """The test runs with one torch thread (restored afterwards): on a busy 2-core machine a second
    intra-op thread makes these small networks several times slower, and the library calls
    (pretrain, dagger) never use more threads than their caller has set."""
    with torch_threads(1):
        yield


def _once_per_session(tmp_path_factory, name: str, build: Callable[[Path], str]) -> str:
    """``build(directory)``'s JSON text, computed by the first xdist worker that asks and read from
    disk by the others: each session fixture below took a minute or more per worker, and every
    worker built its own copy. The lock and the result live in the session's common temporary
    directory (the parent of each worker's own)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    done = root / f"{name}.json"
    with FileLock(str(root / f"{name}.lock")):
        if not done.is_file():
            text = build(root / name)
            done.write_text(text)
        return done.read_text()


def _result_json(result: PretrainResult) -> str:
    return json.dumps({**dataclasses.asdict(result), "run_dir": str(result.run_dir)})


def _result_from_json(text: str) -> PretrainResult:
    fields = json.loads(text)
    return PretrainResult(**{**fields, "run_dir": Path(fields["run_dir"])})


@pytest.fixture(scope="session")
def stg1_dataset(tmp_path_factory) -> Path:
    """A finished MPC-expert dataset directory of STG1 episodes (state and pixels readable with
    :func:`bimgame.expert.datasets.iterate_sequences`); seeded, so the same in every session."""
    def build(directory: Path) -> str:
        data = generate_dataset(directory / "data", "STG1", STG1_DATASET_EPISODES, seed=STG1_DATASET_SEED,
                                workers=2, progress=False)
        return json.dumps(str(data))

    return Path(json.loads(_once_per_session(tmp_path_factory, "stg1-expert", build)))


@pytest.fixture(scope="session")
def pretrained_stg1(stg1_dataset, tmp_path_factory) -> PretrainResult:
    """π^s pre-trained on :func:`stg1_dataset` with state observations (early stopping after 3
    epochs without a better held-out loss), measured over 40 greedy and sampled episodes."""
    config = PretrainConfig(task="STG1", obs="state", target="policy", epochs=30, patience=3, eval_episodes=40,
                            seed=0)

    def build(directory: Path) -> str:
        with torch_threads(1):
            return _result_json(pretrain(config, stg1_dataset, directory / "policy", progress=False))

    return _result_from_json(_once_per_session(tmp_path_factory, "pretrained-policy", build))


@pytest.fixture(scope="session")
def value_stg1(stg1_dataset, tmp_path_factory) -> PretrainResult:
    """The value-only network V̂ trained on :func:`stg1_dataset` (state observations). Small
    batches and a patient early stop: with the defaults (256 frames per batch, patience 5) V̂
    stops while still underfitting on a dataset this small."""
    config = PretrainConfig(task="STG1", obs="state", target="value", epochs=100, patience=10, batch_frames=64,
                            seed=0)

    def build(directory: Path) -> str:
        with torch_threads(1):
            return _result_json(pretrain(config, stg1_dataset, directory / "value", progress=False))

    return _result_from_json(_once_per_session(tmp_path_factory, "pretrained-value", build))


@pytest.fixture(scope="session")
def easy_expert_episode(tmp_path_factory) -> Path:
    """A finished labyrinth dataset of one successful expert episode on the easy layout (the default
    expert: ≈ 460 steps, 10-20 s of planning): the expert's states along the whole path."""
    def build(directory: Path) -> str:
        data = generate_labyrinth_dataset(directory / "data", "LABYRINTH-EASY", 1, seed=0, workers=1, progress=False)
        return json.dumps(str(data))

    return Path(json.loads(_once_per_session(tmp_path_factory, "labyrinth-easy-expert", build)))


@pytest.fixture(scope="session")
def surroundings_teacher_run(tmp_path_factory) -> Path:
    """A tiny PPO policy on the easy layout from state with surroundings (33 values), continuous: the
    trained teacher of DAgger's and PPO's learners that observe something else (a few seconds)."""
    def build(directory: Path) -> str:
        run_dir = directory / "run"
        with torch_threads(1):
            assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--steps", "128", "--surroundings",
                         *SMALL_STATE_FLAGS]) == 0
        return json.dumps(str(run_dir))

    return Path(json.loads(_once_per_session(tmp_path_factory, "surroundings-teacher", build)))
