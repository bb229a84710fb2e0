"""DAgger with the MPC expert: the mixed rollouts and their labels, the aggregated dataset and its
cost accounting, improvement over behaviour cloning, resuming, errors, and the CLI verbs."""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from support.disk import disk_fills_up
from support.files import snapshot

from bimgame.cli.main import main
from bimgame.envs.env import NO_ACTION
from bimgame.expert.episode import Episode
from bimgame.expert.mpc import MPCConfig
from bimgame.learn import checkpoints, runs
from bimgame.learn.actor import evaluate_network
from bimgame.learn.common import load_run_network
from bimgame.learn.dagger import BEST, KIND_DAGGER, DAggerConfig, collect_episodes, dagger, resolve_dagger_config
from bimgame.learn.evaluations import evaluate_greedy_and_sampled, evaluation_seed
from bimgame.learn.supervised import PretrainConfig
from bimgame.util.files import FileWriteError


# ----------------------------------------------------------------------------------- helpers
@pytest.fixture(scope="module", autouse=True)
def _dagger_on_one_thread():
    """One torch thread for this file: on the busy 2-core test machine two made these tiny networks
    ~10x slower (40 evaluation episodes: 44 s against 4 s); dagger() never uses more threads than
    its caller has set."""
    with runs.torch_threads(1):
        yield


def _csv_rows(path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _discounted(rewards, gamma) -> np.ndarray:
    rewards = np.asarray(rewards, dtype=np.float64)
    return np.array([sum(gamma ** k * r for k, r in enumerate(rewards[t:])) for t in range(len(rewards))])


def _npz(run_dir, iteration: int) -> dict[str, np.ndarray]:
    with np.load(run_dir / "data" / f"iteration_{iteration:03d}.npz", allow_pickle=False) as data:
        return {key: data[key] for key in data.files}


def _episodes_of(arrays: dict[str, np.ndarray]) -> list[SimpleNamespace]:
    """The episodes of a stored iteration, read independently of the library's own reader."""
    bounds = np.concatenate([[0], np.cumsum(arrays["lengths"])])
    return [SimpleNamespace(**{k: v[a:b] for k, v in arrays.items() if k != "lengths"})
            for a, b in itertools.pairwise(bounds)]


def _weights(run_dir) -> dict[str, torch.Tensor]:
    return checkpoints.load_checkpoint(run_dir / "checkpoint.pt")["model"]


def _without_seconds(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k != "seconds"} for row in rows]


# ------------------------------------------------------------------------- collect_episodes
#: A cheap expert (K=5, H=10) — collect_episodes' bookkeeping does not need a good one.
ROLLOUT = DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", seed=0), episodes_per_iteration=4,
                       expert=MPCConfig(n_samples=5, horizon=10), max_episode_steps=40)
FORCED_ACTION = 2  # tilt -x


def _forced_learner(config: DAggerConfig):
    """A learner whose policy puts all its mass on FORCED_ACTION, whatever its inputs."""
    net = config.learner.build_policy(config.learner.seed)
    with torch.no_grad():
        net.policy.weight.zero_()
        net.policy.bias.fill_(-50.0)
        net.policy.bias[FORCED_ACTION] = 50.0
    return net


def _check_episode_layout(episode: Episode | SimpleNamespace, config: DAggerConfig) -> None:
    steps = len(episode.actions)
    assert 1 <= steps <= config.time_limit
    for key in ("obs", "executed", "prev_actions", "prev_rewards", "tilt", "rewards", "returns"):
        assert len(getattr(episode, key)) == steps, key
    assert episode.tilt.shape == (steps, 2)
    assert set(np.unique(episode.actions)) <= set(range(5))
    assert set(np.unique(episode.executed)) <= set(range(5))
    # The recurrent inputs are what was executed and received one step earlier.
    assert episode.prev_actions[0] == NO_ACTION
    np.testing.assert_array_equal(episode.prev_actions[1:], episode.executed[:-1])
    assert episode.prev_rewards[0] == 0.0
    np.testing.assert_array_equal(episode.prev_rewards[1:], episode.rewards[:-1])
    np.testing.assert_allclose(episode.returns, _discounted(episode.rewards, config.learner.gamma), rtol=1e-6)
    # STG1: reward 1 when the marble passes the first wall, which ends the episode; otherwise the
    # rollout runs to the time limit.
    np.testing.assert_array_equal(episode.rewards[:-1], 0.0)
    assert episode.rewards[-1] == 1.0 or (episode.rewards[-1] == 0.0 and steps == config.time_limit)


def _check_costs(episodes, costs, config: DAggerConfig) -> None:
    steps = sum(len(e.actions) for e in episodes)
    assert costs["env_steps"] == costs["labels"] == steps
    assert costs["expert_sim_steps"] == steps * config.expert.n_samples * config.expert.horizon
    assert costs["successes"] == sum(int(e.rewards[-1] == 1.0) for e in episodes)


def test_collect_episodes_mixes_expert_and_learner_by_beta_and_labels_every_state_with_the_expert(
        one_torch_thread):
    config = ROLLOUT
    net = config.learner.build_policy(config.learner.seed)
    expert_run, expert_costs = collect_episodes(net, config, beta=1.0, seed=11)
    assert len(expert_run) == config.episodes_per_iteration
    for episode in expert_run:
        _check_episode_layout(episode, config)
        # β = 1: every executed action is the expert's label.
        np.testing.assert_array_equal(episode.executed, episode.actions)
    _check_costs(expert_run, expert_costs, config)
    # Even this cheap expert passes the first wall within the limit in some episodes, not all.
    assert 0 < expert_costs["successes"] < config.episodes_per_iteration, expert_costs

    # The same seed gives the same episodes; another seed other starts.
    again, again_costs = collect_episodes(net, config, beta=1.0, seed=11)
    assert again_costs == expert_costs
    for a, b in zip(expert_run, again):
        for key, value in a.step_arrays().items():
            np.testing.assert_array_equal(value, getattr(b, key), err_msg=key)
    other, _ = collect_episodes(net, config, beta=1.0, seed=12)
    assert not any(np.array_equal(a.obs[0], b.obs[0]) for a, b in zip(expert_run, other))

    # β = 0: the learner (here one that always tilts -x) acts; the expert still labels every state.
    forced = _forced_learner(config)
    learner_run, learner_costs = collect_episodes(forced, config, beta=0.0, seed=11)
    for episode in learner_run:
        _check_episode_layout(episode, config)
        np.testing.assert_array_equal(episode.executed, FORCED_ACTION)
    _check_costs(learner_run, learner_costs, config)
    labels = np.concatenate([e.actions for e in learner_run])
    assert (labels != FORCED_ACTION).any() and len(np.unique(labels)) >= 3, np.bincount(labels)
    # Up to the first step where the learner departs from the expert, both runs visit the same
    # states (same starts) and the expert gives the same labels there: the labels are the
    # expert's, in the state the learner reached.
    for expert_episode, learner_episode in zip(expert_run, learner_run):
        departs = np.flatnonzero(learner_episode.actions != FORCED_ACTION)
        assert len(departs), "the expert never disagrees with always tilting -x"
        upto = int(departs[0]) + 1
        assert upto <= len(expert_episode.actions)
        np.testing.assert_array_equal(learner_episode.obs[:upto], expert_episode.obs[:upto])
        np.testing.assert_array_equal(learner_episode.actions[:upto], expert_episode.actions[:upto])

    # β = 0.5: each step executes either the label or the learner's action, and both happen; up
    # to the first executed action that is not the label, the run is the expert's run.
    mixed_run, mixed_costs = collect_episodes(forced, config, beta=0.5, seed=11)
    _check_costs(mixed_run, mixed_costs, config)
    shared = 0
    for expert_episode, mixed_episode in zip(expert_run, mixed_run):
        _check_episode_layout(mixed_episode, config)
        departs = np.flatnonzero(mixed_episode.executed != mixed_episode.actions)
        upto = int(departs[0]) + 1 if len(departs) else len(mixed_episode.actions)
        shared += upto
        for key in ("obs", "actions", "tilt"):
            np.testing.assert_array_equal(getattr(mixed_episode, key)[:upto], getattr(expert_episode, key)[:upto],
                                          err_msg=key)
    assert shared > len(mixed_run), shared
    executed = np.concatenate([e.executed for e in mixed_run])
    labels = np.concatenate([e.actions for e in mixed_run])
    assert ((executed == labels) | (executed == FORCED_ACTION)).all()
    disagree = labels != FORCED_ACTION
    expert_share = float(np.mean(executed[disagree] == labels[disagree]))
    assert disagree.sum() >= 20 and 0.25 <= expert_share <= 0.75, (disagree.sum(), expert_share)


# ---------------------------------------------------------------------------- a small run
#: A cheap run for the bookkeeping and resume tests: a weak expert (K=4, H=6), short rollouts,
#: and a β schedule other than the default.
SMALL = DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", seed=3, batch_episodes=2), iterations=3,
                     episodes_per_iteration=3, beta0=0.9, beta_decay=0.6, epochs_per_iteration=2,
                     expert=MPCConfig(n_samples=4, horizon=6), max_episode_steps=25, eval_episodes=3)


@pytest.fixture(scope="module")
def small_runs(tmp_path_factory):
    """SMALL run twice: uninterrupted, and stopped after iteration 1, resumed to 2, resumed to 3."""
    root = tmp_path_factory.mktemp("dagger-small")
    whole = dagger(SMALL, root / "whole", progress=False)
    stages = [dagger(dataclasses.replace(SMALL, iterations=1), root / "resumed", progress=False)]
    stages.append(dagger(dataclasses.replace(SMALL, iterations=2), root / "resumed", resume=True, progress=False))
    stages.append(dagger(SMALL, root / "resumed", resume=True, progress=False))
    return whole, stages


def _check_aggregation(run_dir, config: DAggerConfig, result) -> list[dict[str, str]]:
    """The dataset grows by each iteration's episodes; the csv's counters add them up."""
    rows = _csv_rows(run_dir / "dagger.csv")
    assert [int(r["iteration"]) for r in rows] == list(range(config.iterations))
    k, h = config.expert.n_samples, config.expert.horizon
    steps = 0
    for i, row in enumerate(rows):
        data = _npz(run_dir, i)
        assert set(data) == {"obs", "actions", "executed", "prev_actions", "prev_rewards", "tilt", "rewards",
                             "returns", "lengths"}
        episodes = _episodes_of(data)
        assert len(episodes) == config.episodes_per_iteration
        for episode in episodes:
            _check_episode_layout(episode, config)
        collected = int(data["lengths"].sum())
        assert collected == len(data["actions"]) == len(data["obs"]) > 0
        steps += collected
        # β_i = β0 · decay^i.
        assert float(row["beta"]) == pytest.approx(config.beta0 * config.beta_decay ** i, rel=1e-5)
        assert int(row["episodes"]) == config.episodes_per_iteration * (i + 1)
        # step counts environment steps, cumulatively; each visited state got one label, and the
        # expert's planning is counted apart, K·H simulator steps per label.
        assert int(row["step"]) == int(row["labels"]) == int(row["dataset_steps"]) == steps
        assert int(row["expert_sim_steps"]) == steps * k * h
        successes = sum(int(e.rewards[-1] == 1.0) for e in episodes)
        assert float(row["rollout_success_rate"]) == pytest.approx(successes / config.episodes_per_iteration)
        if i > 0:
            assert int(row["dataset_steps"]) > int(rows[i - 1]["dataset_steps"])
    assert (result.iterations, result.env_steps, result.dataset_steps, result.expert_sim_steps) == (
        config.iterations, steps, steps, steps * k * h)
    state = json.loads((run_dir / "dagger_state.json").read_text())
    assert (state["iteration"], state["env_steps"], state["labels"], state["expert_sim_steps"]) == (
        config.iterations, steps, steps, steps * k * h)
    return rows


def test_dataset_aggregates_every_iteration_and_costs_are_counted_apart(small_runs, one_torch_thread):
    (whole, _), config = small_runs, SMALL
    run_dir = whole.run_dir
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["kind"] == KIND_DAGGER
    assert DAggerConfig.from_dict(stored["dagger"]) == config
    rows = _check_aggregation(run_dir, config, whole)
    # The learner acts from iteration 0 on (β0 = 0.9): executed actions are not all the labels.
    executed = np.concatenate([_npz(run_dir, i)["executed"] for i in range(config.iterations)])
    labels = np.concatenate([_npz(run_dir, i)["actions"] for i in range(config.iterations)])
    assert (executed != labels).any()

    # The checkpoint holds the last iteration's weights: it reproduces the last evaluation.
    net, run, step = load_run_network(run_dir)
    assert (run.task, run.network.obs, step) == ("STG1", "state", whole.env_steps)
    again = evaluate_greedy_and_sampled(net, task=run.task, obs=run.network.obs, episodes=config.eval_episodes,
                                        seed=evaluation_seed(run.seed), time_limit=run.time_limit)
    assert whole.final_eval == pytest.approx(again)
    for key in ("greedy_success_rate", "sampled_success_rate", "greedy_mean_length"):
        assert float(rows[-1][key]) == pytest.approx(again[key], rel=1e-5)


def test_resumed_run_ends_identical_to_an_uninterrupted_one(small_runs, tmp_path):
    whole, stages = small_runs
    resumed = stages[-1].run_dir
    assert [s.iterations for s in stages] == [1, 2, 3]
    assert stages[0].env_steps < stages[1].env_steps < stages[2].env_steps
    last = stages[-1]
    assert (last.iterations, last.env_steps, last.expert_sim_steps, last.dataset_steps) == (
        whole.iterations, whole.env_steps, whole.expert_sim_steps, whole.dataset_steps)
    assert last.final_eval == whole.final_eval
    rows = _csv_rows(whole.run_dir / "dagger.csv")
    assert _without_seconds(_csv_rows(resumed / "dagger.csv")) == _without_seconds(rows)
    weights, resumed_weights = _weights(whole.run_dir), _weights(resumed)
    assert weights.keys() == resumed_weights.keys()
    for key in weights:
        assert torch.equal(weights[key], resumed_weights[key]), key
    for i in range(SMALL.iterations):
        a, b = _npz(whole.run_dir, i), _npz(resumed, i)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"iteration {i}: {key}")
    state = json.loads((whole.run_dir / "dagger_state.json").read_text())
    resumed_state = json.loads((resumed / "dagger_state.json").read_text())
    state.pop("seconds"), resumed_state.pop("seconds")
    assert state == resumed_state

    # Resuming a finished run does nothing and keeps its log.
    copy = tmp_path / "finished"
    shutil.copytree(resumed, copy)
    again = dagger(SMALL, copy, resume=True, progress=False)
    assert (again.iterations, again.env_steps, again.dataset_steps) == (3, whole.env_steps, whole.dataset_steps)
    assert _csv_rows(copy / "dagger.csv") == _csv_rows(resumed / "dagger.csv")


def _rank(row: dict[str, str]) -> list[float]:
    """An iteration's rank as the run keeps its best (success, then return, over both modes)."""
    return [float(row["greedy_success_rate"]) + float(row["sampled_success_rate"]),
            float(row["greedy_mean_return"]) + float(row["sampled_mean_return"])]


def test_the_best_iterate_by_the_in_run_evaluation_is_kept_with_its_weights(small_runs):
    whole, stages = small_runs
    rows = _csv_rows(whole.run_dir / "dagger.csv")
    ranks = [_rank(row) for row in rows]
    expected = ranks.index(max(ranks))  # the first of equals: a later one must rank strictly higher
    assert whole.best is not None and whole.best["iteration"] == expected
    payload = checkpoints.load_checkpoint(whole.run_dir / BEST)
    assert payload["iteration"] == expected and payload["step"] == int(rows[expected]["step"])
    # Its weights reproduce that iteration's in-run evaluation.
    net, run, _ = load_run_network(whole.run_dir / BEST)
    again = evaluate_greedy_and_sampled(net, task=run.task, obs=run.network.obs, episodes=SMALL.eval_episodes,
                                        seed=evaluation_seed(run.seed), time_limit=run.time_limit)
    for key in ("greedy_success_rate", "sampled_success_rate", "greedy_mean_return", "sampled_mean_return"):
        assert again[key] == pytest.approx(float(rows[expected][key]), rel=1e-5, abs=1e-6), key
    # The resumed run kept the same best iterate with the same weights.
    assert stages[-1].best == whole.best
    resumed = checkpoints.load_checkpoint(stages[-1].run_dir / BEST)["model"]
    for key, value in payload["model"].items():
        assert torch.equal(value, resumed[key]), key


def test_a_kill_before_best_pt_was_written_is_repaired_on_resume(small_runs, tmp_path):
    """The checkpoint records the last iteration as the best, but best.pt was not written yet: the
    resumed run writes it from the checkpoint's weights (the last iteration's)."""
    whole, _ = small_runs
    run_dir = shutil.copytree(whole.run_dir, tmp_path / "run")
    payload = checkpoints.load_checkpoint(run_dir / "checkpoint.pt")
    last = SMALL.iterations - 1
    payload["best"] = {"iteration": last, "step": payload["step"], "rank": [9.0, 9.0]}
    checkpoints.save_checkpoint(run_dir / "checkpoint.pt", **{k: v for k, v in payload.items() if k != "format"})
    (run_dir / BEST).unlink()
    again = dagger(SMALL, run_dir, resume=True, progress=False)
    assert again.iterations_run == 0 and again.best["iteration"] == last
    repaired = checkpoints.load_checkpoint(run_dir / BEST)
    assert repaired["iteration"] == last
    for key, value in _weights(whole.run_dir).items():
        assert torch.equal(value, repaired["model"][key]), key


def test_a_run_without_in_run_evaluation_keeps_no_best(tmp_path):
    config = dataclasses.replace(SMALL, iterations=1, eval_episodes=0)
    result = dagger(config, tmp_path / "run", progress=False)
    assert result.best is None and not (tmp_path / "run" / BEST).exists()


# ------------------------------------------------------------------- against behaviour cloning
#: Measured with this seed (the default expert, K=10, H=20): greedy success over the run's 40
#: evaluation starts after iterations 0, 1, 2 = 15%, 50%, 55%; sampled 50%, 45%, 97.5%; 1074
#: labels in all, 30-50 s on the 2-core machine busy with a training run. Seeds 1-4 with the same
#: settings, iteration 0 -> 2: greedy 37.5 -> 82.5, 37.5 -> 92.5, 5 -> 67.5, 2.5 -> 62.5 %;
#: sampled 17.5 -> 87.5, 32.5 -> 77.5, 25 -> 57.5, 30 -> 57.5 %. Small batches (2 episodes) and
#: lr 2e-3 so that 8 episodes give the network more than a handful of updates per iteration (with
#: 16-episode batches the margins were small and inconsistent across seeds).
IMPROVE = DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", seed=0, batch_episodes=2, lr=2e-3),
                       iterations=3, episodes_per_iteration=8, epochs_per_iteration=10, max_episode_steps=60,
                       eval_episodes=40)


@pytest.fixture(scope="module")
def improve_run(tmp_path_factory):
    return dagger(IMPROVE, tmp_path_factory.mktemp("dagger-improve") / "run", progress=False)


def test_dagger_improves_on_behaviour_cloning(improve_run):
    config, run_dir = IMPROVE, improve_run.run_dir
    rows = _check_aggregation(run_dir, config, improve_run)
    # Iteration 0 executes the expert only (β0 = 1): behaviour cloning data. With the default
    # expert (K=10, H=20) most of those episodes pass the wall within the 60-step limit.
    first = _npz(run_dir, 0)
    np.testing.assert_array_equal(first["executed"], first["actions"])
    assert float(rows[0]["rollout_success_rate"]) >= 0.5
    for i in range(1, config.iterations):
        data = _npz(run_dir, i)
        assert (data["executed"] != data["actions"]).any()

    # Every iteration is evaluated on the same 40 starts (the run's evaluation seed); iteration
    # 0's row is the behaviour-cloning policy.
    bc, last = rows[0], rows[-1]
    for mode, margin in (("greedy", 0.25), ("sampled", 0.15)):
        before, after = float(bc[f"{mode}_success_rate"]), float(last[f"{mode}_success_rate"])
        assert after >= before + margin, (mode, [r[f"{mode}_success_rate"] for r in rows])
    assert improve_run.final_eval["greedy_success_rate"] == pytest.approx(float(last["greedy_success_rate"]))


# ----------------------------------------------------------------------------------- errors
def test_invalid_settings_and_misused_run_directories_are_refused(small_runs, tmp_path):
    for changes, field in (({"beta0": 1.5}, "beta0"), ({"beta_decay": -0.1}, "beta_decay"),
                           ({"iterations": 0}, "iterations"), ({"episodes_per_iteration": 0}, "episodes_per_iteration"),
                           ({"epochs_per_iteration": 2.5}, "epochs_per_iteration"),
                           ({"eval_episodes": -1}, "eval_episodes"), ({"max_episode_steps": 0}, "max_episode_steps")):
        with pytest.raises(ValueError, match=rf"DAggerConfig\.{field} "):
            DAggerConfig(**changes)
    with pytest.raises(ValueError, match="target='policy'"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", target="value"))
    with pytest.raises(ValueError, match=r"unknown DAgger settings \['beta'\]"):
        DAggerConfig.from_dict({**SMALL.to_dict(), "beta": 0.5})
    assert DAggerConfig.from_dict(json.loads(json.dumps(SMALL.to_dict()))) == SMALL

    whole, _ = small_runs
    run_dir = whole.run_dir
    before = {p.name: p.read_bytes() for p in (run_dir / "dagger.csv", run_dir / "checkpoint.pt",
                                                run_dir / "dagger_state.json", run_dir / "config.json")}
    # Resuming must keep every setting but the number of iterations and evaluation episodes.
    for changes, field in (({"episodes_per_iteration": 4}, "episodes_per_iteration"),
                           ({"beta_decay": 0.5}, "beta_decay"),
                           ({"expert": MPCConfig(n_samples=5, horizon=6)}, "expert"),
                           ({"learner": dataclasses.replace(SMALL.learner, lr=1e-2)}, "learner"),
                           ({"max_episode_steps": 30}, "max_episode_steps")):
        with pytest.raises(ValueError, match=rf"changed: {field}\b"):
            dagger(dataclasses.replace(SMALL, iterations=4, **changes), run_dir, resume=True, progress=False)
    with pytest.raises(ValueError, match="already holds a run"):
        dagger(SMALL, run_dir, progress=False)
    assert {p: (run_dir / p).read_bytes() for p in before} == before
    assert len(list((run_dir / "data").iterdir())) == SMALL.iterations

    with pytest.raises(ValueError, match="no config.json"):
        dagger(SMALL, tmp_path / "nothing", resume=True, progress=False)
    assert not (tmp_path / "nothing").exists()


# -------------------------------------------------------------------------------------- CLI
def test_cli_dagger_resume_and_evaluate(tmp_path, capsys, one_torch_thread):
    run_dir = tmp_path / "run"
    # β0 = 1 and no decay: the expert executes every step, so the rollouts are short even with
    # the CLI's default expert and time limit.
    common = ["--run-dir", str(run_dir), "--epochs-per-iteration", "2", "--eval-episodes", "2", "--no-progress"]
    assert main(["dagger", *common, "--obs", "state", "--iterations", "1", "--episodes-per-iteration", "2",
                 "--beta-decay", "1", "--seed", "5"]) == 0
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["kind"] == KIND_DAGGER
    config = DAggerConfig.from_dict(stored["dagger"])
    assert (config.learner.task, config.learner.obs, config.learner.seed) == ("STG1", "state", 5)
    assert (config.iterations, config.episodes_per_iteration, config.epochs_per_iteration, config.beta0,
            config.beta_decay, config.eval_episodes, config.expert) == (1, 2, 2, 1.0, 1.0, 2, MPCConfig())

    # --resume refuses a setting that would change the run (the learner's too), naming it, and
    # leaves the run as it was; the run's own values given again are accepted.
    before = snapshot(run_dir, without_tensorboard=True)
    for changed, named in ((["--episodes-per-iteration", "5"], "episodes_per_iteration"),
                           (["--seed", "6"], "learner.seed"), (["--beta0", "0.5"], "beta0")):
        assert main(["dagger", *common, "--resume", "--iterations", "2", *changed]) == 2
        err = " ".join(capsys.readouterr().err.split())  # the message as one line
        assert f"changed: {named}" in err and "Allowed to change: iterations, eval_episodes" in err, err
    assert snapshot(run_dir, without_tensorboard=True) == before
    # It continues with the run's settings and may raise --iterations.
    assert main(["dagger", *common, "--resume", "--iterations", "2", "--episodes-per-iteration", "2",
                 "--seed", "5", "--obs", "state"]) == 0
    rows = _csv_rows(run_dir / "dagger.csv")
    assert [(int(r["iteration"]), int(r["episodes"]), float(r["beta"])) for r in rows] == [(0, 2, 1.0), (1, 4, 1.0)]
    assert DAggerConfig.from_dict(json.loads((run_dir / "config.json").read_text())["dagger"]) == config
    for i in range(2):
        data = _npz(run_dir, i)
        np.testing.assert_array_equal(data["executed"], data["actions"])
    env_steps = int(rows[-1]["step"])

    # bimgame evaluate reads the DAgger run's weights.
    out = tmp_path / "eval.json"
    assert main(["evaluate", str(run_dir), "--episodes", "3", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert (result["step"], result["episodes"], result["mode"]) == (env_steps, 3, "greedy")
    net, _, _ = load_run_network(run_dir)
    direct = evaluate_network(net, task="STG1", obs_mode="state", episodes=3, seed=result["seed"], greedy=True)
    assert (result["successes"], result["lengths"]) == (direct.successes, direct.lengths)

    # Invalid values are refused by name, as an error exit rather than a traceback.
    capsys.readouterr()
    assert main(["dagger", "--run-dir", str(tmp_path / "bad"), "--obs", "state", "--beta0", "1.5",
                 "--no-progress"]) == 2
    assert "beta0" in capsys.readouterr().err
    assert main(["dagger", *common, "--iterations", "3"]) == 2
    assert "already holds a run" in capsys.readouterr().err


# ------------------------------------------------------------------------------ reliability
def test_dagger_refuses_directories_that_are_not_dagger_runs(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "dagger.csv").write_text("my,own\n")
    before = snapshot(mine, without_tensorboard=True)
    with pytest.raises(ValueError, match=r"is not empty and is not a DAgger run \(no config.json; found 1 entry: "
                                         r"'dagger.csv'\); nothing was changed"):
        dagger(SMALL, mine, progress=False)
    with pytest.raises(ValueError, match=r"--resume: .* has no config.json: .* is not a DAgger run"):
        dagger(SMALL, mine, resume=True, progress=False)
    assert snapshot(mine, without_tensorboard=True) == before
    a3c = tmp_path / "a3c"
    a3c.mkdir()
    (a3c / "config.json").write_text(json.dumps({"a3c": {"task": "STG1", "obs": "state"}}))
    for resume in (False, True):
        with pytest.raises(ValueError, match="(holds a a3c run, not a DAgger run|it is a a3c run, not a DAgger run)"):
            dagger(SMALL, a3c, resume=resume, progress=False)
    with pytest.raises(ValueError, match="holds a a3c run, not a DAgger run"):
        resolve_dagger_config(SMALL.learner, {}, a3c, resume=True)


def test_dagger_resume_refuses_to_start_over_without_its_checkpoint_or_data(small_runs, tmp_path):
    """A missing dagger_state.json used to restart from iteration 0, dropping every logged row; a
    missing checkpoint or data file failed with a bare FileNotFoundError or 'no checkpoint at'."""
    whole, _ = small_runs
    run_dir = shutil.copytree(whole.run_dir, tmp_path / "no-checkpoint")
    (run_dir / "checkpoint.pt").unlink()
    before = snapshot(run_dir, without_tensorboard=True)
    with pytest.raises(ValueError, match=r"has no checkpoint.pt, so the DAgger run in it cannot be continued .*Start "
                                         r"anew without --resume in a new --run-dir"):
        dagger(dataclasses.replace(SMALL, iterations=4), run_dir, resume=True, progress=False)
    assert snapshot(run_dir, without_tensorboard=True) == before

    run_dir = shutil.copytree(whole.run_dir, tmp_path / "no-data")
    (run_dir / "data" / "iteration_001.npz").unlink()
    before = snapshot(run_dir, without_tensorboard=True)
    with pytest.raises(ValueError, match=r"aggregated data of finished iterations is missing \(.*iteration_001.npz\)"):
        dagger(dataclasses.replace(SMALL, iterations=4), run_dir, resume=True, progress=False)
    assert snapshot(run_dir, without_tensorboard=True) == before

    # The checkpoint holds the counts: a lost (or damaged) state file is rewritten, nothing redone.
    run_dir = shutil.copytree(whole.run_dir, tmp_path / "no-state")
    state = (run_dir / "dagger_state.json").read_text()
    (run_dir / "dagger_state.json").unlink()
    again = dagger(SMALL, run_dir, resume=True, progress=False)
    assert again.iterations_run == 0 and again.env_steps == whole.env_steps
    assert json.loads((run_dir / "dagger_state.json").read_text()) == json.loads(state)
    assert _csv_rows(run_dir / "dagger.csv") == _csv_rows(whole.run_dir / "dagger.csv")


def test_a_kill_between_the_commit_and_the_state_copy_neither_redoes_nor_loses_an_iteration(small_runs, tmp_path):
    """The checkpoint commits an iteration. Killed after it but before dagger_state.json was
    rewritten, the state file is one iteration behind: the resumed run used to redo that iteration
    on top of the weights already trained by it. Killed after the log row but before the commit, the
    row is dropped and the iteration redone."""
    whole, _ = small_runs
    run_dir = shutil.copytree(whole.run_dir, tmp_path / "run")
    rows = _csv_rows(run_dir / "dagger.csv")
    behind = {"iteration": 2, "env_steps": int(rows[1]["step"]), "labels": int(rows[1]["labels"]),
              "expert_sim_steps": int(rows[1]["expert_sim_steps"]), "seconds": float(rows[1]["seconds"])}
    (run_dir / "dagger_state.json").write_text(json.dumps(behind))
    with open(run_dir / "dagger.csv", "a", newline="") as handle:  # the row of an iteration never committed
        handle.write(f"{whole.env_steps + 7},3,0.1,{','.join(['1'] * (len(rows[0]) - 3))}\r\n")
    again = dagger(SMALL, run_dir, resume=True, progress=False)
    assert again.iterations_run == 0 and again.iterations == 3
    assert _csv_rows(run_dir / "dagger.csv") == rows
    assert json.loads((run_dir / "dagger_state.json").read_text())["iteration"] == 3
    for key, value in _weights(whole.run_dir).items():
        assert torch.equal(value, _weights(run_dir)[key]), key


def test_a_new_dagger_run_that_fails_in_its_first_iteration_leaves_nothing(tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise ValueError("a setting only the rollouts find bad")
    monkeypatch.setattr("bimgame.learn.dagger.training.collect_episodes", broken)
    with pytest.raises(ValueError, match="only the rollouts find bad"):
        dagger(SMALL, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_disk_full_during_dagger_names_the_file_and_keeps_the_finished_iterations(tmp_path, monkeypatch, capsys):
    disk_fills_up(monkeypatch, "iteration_001.npz")
    run_dir = tmp_path / "run"
    config = dataclasses.replace(SMALL, iterations=2, eval_episodes=0)
    with pytest.raises(FileWriteError, match=r"cannot write .*iteration_001.npz: No space left on device. The "
                                                 r"iterations finished before \(1\) are saved .* --resume"):
        dagger(config, run_dir, progress=False)
    assert [r["iteration"] for r in _csv_rows(run_dir / "dagger.csv")] == ["0"]
    monkeypatch.undo()
    assert dagger(config, run_dir, resume=True, progress=False).iterations_run == 1


def test_ctrl_c_stops_dagger_with_a_resumable_run(tmp_path, monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr("bimgame.learn.dagger.training.collect_episodes", interrupted)
    run_dir = tmp_path / "run"
    assert main(["dagger", "--run-dir", str(run_dir), "--obs", "state", "--no-progress"]) == 130
    assert "--resume" in capsys.readouterr().err
    assert {p.name for p in run_dir.iterdir()} >= {"config.json", "checkpoint.pt", "dagger_state.json"}
    runs.check_resumable(run_dir, kind=KIND_DAGGER, what="DAgger", needs=("checkpoint.pt",))
