"""Shared, session-scoped fixtures: an expert dataset and the networks pre-trained on it.

They are expensive (the dataset takes about a minute of MPC planning), so they are built once per
test session, lazily, by the first test that asks for them."""

from __future__ import annotations

import os

# The suite runs as two xdist workers on two cores: one intra-op thread per process, subprocesses
# included (set before torch starts its thread pool). A second thread spins against the other
# worker: the 100k-step PPO test took 12 minutes with two threads on a loaded machine.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest  # noqa: E402
import torch  # noqa: E402

from bimgame.expert.datasets import generate_dataset  # noqa: E402
from bimgame.learn.pretrain import PretrainResult, pretrain  # noqa: E402
from bimgame.learn.runs import torch_threads  # noqa: E402
from bimgame.learn.supervised import PretrainConfig  # noqa: E402

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


@pytest.fixture(scope="session")
def stg1_dataset(tmp_path_factory):
    """A finished MPC-expert dataset directory of STG1 episodes (state and pixels readable with
    :func:`bimgame.expert.datasets.iterate_sequences`); seeded, so the same in every session."""
    out = tmp_path_factory.mktemp("stg1-expert") / "data"
    return generate_dataset(out, "STG1", STG1_DATASET_EPISODES, seed=STG1_DATASET_SEED, workers=2, progress=False)


@pytest.fixture(scope="session")
def pretrained_stg1(stg1_dataset, tmp_path_factory) -> PretrainResult:
    """π^s pre-trained on :func:`stg1_dataset` with state observations (early stopping after 3
    epochs without a better held-out loss), measured over 40 greedy and sampled episodes."""
    config = PretrainConfig(task="STG1", obs="state", target="policy", epochs=30, patience=3, eval_episodes=40,
                            seed=0)
    with torch_threads(1):
        return pretrain(config, stg1_dataset, tmp_path_factory.mktemp("pretrained") / "policy", progress=False)


@pytest.fixture(scope="session")
def value_stg1(stg1_dataset, tmp_path_factory) -> PretrainResult:
    """The value-only network V̂ trained on :func:`stg1_dataset` (state observations). Small
    batches and a patient early stop: with the defaults (256 frames per batch, patience 5) V̂
    stops while still underfitting on a dataset this small."""
    config = PretrainConfig(task="STG1", obs="state", target="value", epochs=100, patience=10, batch_frames=64,
                            seed=0)
    with torch_threads(1):
        return pretrain(config, stg1_dataset, tmp_path_factory.mktemp("pretrained") / "value", progress=False)
