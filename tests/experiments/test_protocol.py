"""The benchmark protocol: fixed starts, deterministic scores, the normalisation's references, and any
policy (built-in, network run, module:callable, Stable-Baselines3 model)."""

from __future__ import annotations

import json

import pytest

from bimgame.experiments.policy_sources import builtin_policy, load_policy
from bimgame.experiments.protocol import PROTOCOL_SEED, Protocol, measure_references, run_protocol, score
from bimgame.expert import references
from bimgame.expert.evaluation import evaluate_expert
from bimgame.learn.checkpoints import save_checkpoint
from bimgame.learn.common import NetworkSettings
from bimgame.learn.runs import CHECKPOINT
from bimgame.util.seeding import episode_seed


def test_the_protocol_starts_from_the_expert_datasets_seeds():
    protocol = Protocol(task="STG1", episodes=3)
    assert protocol.start_seeds() == [episode_seed(PROTOCOL_SEED, i) for i in range(3)]
    assert protocol.time_limit == 300
    with pytest.raises(ValueError, match="Protocol.episodes"):
        Protocol(episodes=0)
    with pytest.raises(ValueError, match="Protocol.obs"):
        Protocol(obs="rgb")


def test_same_policy_same_score_and_another_policy_differs():
    protocol = Protocol(task="STG1", episodes=6)
    first = run_protocol(builtin_policy("random"), protocol).summary()
    again = run_protocol(builtin_policy("random"), protocol).summary()
    first.pop("seconds"), again.pop("seconds")
    assert first == again
    again.pop("normalised_score"), again.pop("normalised_score_ci")
    assert {k: v for k, v in score("random", "stg1", episodes=6).items() if k in again} == again
    geodesic = run_protocol(builtin_policy("geodesic"), protocol)
    assert geodesic.returns != run_protocol(builtin_policy("noop"), protocol).returns


def test_the_expert_in_the_protocol_is_the_expert_of_the_references():
    """The built-in expert scored in process and the parallel expert runs behind the references see
    the same starts and act the same, episode by episode."""
    protocol = Protocol(task="STG1", episodes=3)
    in_process = run_protocol(builtin_policy("expert"), protocol)
    parallel = evaluate_expert("STG1", 3, seed=PROTOCOL_SEED, workers=1, progress=False)
    assert in_process.returns == [r.episode_return for r in parallel]
    assert in_process.lengths == [r.length for r in parallel]


def test_normalisation_maps_random_to_0_and_the_expert_to_100(monkeypatch):
    measured = measure_references(["STG1"], episodes=4, workers=1, progress=False)["tasks"]
    monkeypatch.setattr(references, "reference_scores", lambda: measured)
    protocol = Protocol(task="STG1", episodes=4)
    random = run_protocol(builtin_policy("random"), protocol).summary()
    expert = run_protocol(builtin_policy("expert"), protocol).summary()
    assert random["normalised_score"] == pytest.approx(0.0)
    assert expert["normalised_score"] == pytest.approx(100.0)
    assert expert["success_rate"] > random["success_rate"]


def test_the_stored_references_separate_random_from_expert_on_every_task():
    stored = references.reference_scores()
    assert set(stored) == {"FULL", "STG1", "STG2", "STG3", "STG4"}
    for task, entry in stored.items():
        assert entry["expert"] > entry["random"], task
        assert entry["expert_success_rate"] >= 0.9, task


def test_a_network_run_a_callable_and_intervals(tmp_path):
    network = NetworkSettings(obs="state", hidden=8, features=8)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps({"kind": "pretrained-policy", "task": "STG1", "seed": 0,
                                                     "network": network.to_dict()}))
    save_checkpoint(run_dir / CHECKPOINT, model=network.build_policy(0).state_dict(), step=0)
    protocol = Protocol(task="STG1", episodes=3)
    score = run_protocol(load_policy(str(run_dir), obs="state"), protocol)
    assert score.returns == run_protocol(load_policy(str(run_dir), obs="state"), protocol).returns
    with pytest.raises(ValueError, match="--obs state"):
        load_policy(str(run_dir), obs="pixels")
    noop = run_protocol(load_policy("support.policies:always_noop", obs="state"), protocol).summary()
    assert noop["success_rate"] == 0.0 and noop["mean_length_solved"] is None
    low, high = noop["mean_return_ci"]
    assert low <= noop["mean_return"] <= high
    from support import policies

    before = policies.counting.episodes
    run_protocol(load_policy("support.policies:counting", obs="state"), protocol)
    assert policies.counting.episodes - before == 3


def test_a_stable_baselines3_model_scores(tmp_path):
    stable_baselines3 = pytest.importorskip("stable_baselines3")
    import gymnasium as gym

    import bimgame  # noqa: F401  (registers the env ids)

    env = gym.make("BiMGame/STG1-v0", obs_mode="state")
    model = stable_baselines3.PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=128)
    model.save(tmp_path / "ppo")
    summary = run_protocol(load_policy(str(tmp_path / "ppo.zip"), obs="state"), Protocol(episodes=2)).summary()
    assert summary["episodes"] == 2 and 0.0 <= summary["success_rate"] <= 1.0
    (tmp_path / "fake.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a zip file"):
        load_policy(str(tmp_path / "fake.zip"), obs="state")


@pytest.mark.parametrize("spec, says", [("nonsense", "is none of"), ("nomodule_xyz:f", "cannot import module"),
                                        ("support.policies:missing", "has no 'missing'")])
def test_a_bad_policy_is_refused_with_what_is_allowed(spec, says):
    with pytest.raises(ValueError, match=says):
        load_policy(spec, obs="state")

