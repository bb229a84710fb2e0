"""A3C: the loss, determinism, checkpoints and resume, failure handling, and that it learns."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from bimgame.learn.a3c import A3CConfig, TrainingError, a3c_segment_loss, network_for, train
from bimgame.learn.actor import evaluate_network
from bimgame.learn.checkpoints import load_checkpoint, load_weights
from bimgame.learn.nets import LSTMState
from bimgame.learn.rollout import Segment

# Small, fast settings for state observations.
FAST = dict(task="STG1", obs="state", workers=1, envs_per_worker=4, n_steps=10, eval_every=0, hidden=32,
            features=32, log_every=500)


def _segment(config: A3CConfig, steps: int, batch: int, seed: int = 0) -> Segment:
    g = torch.Generator().manual_seed(seed)
    return Segment(**{"obs": torch.randn(steps + 1, batch, 7, generator=g) * 0.05,
            "prev_action": torch.randint(-1, 5, (steps + 1, batch), generator=g),
            "prev_reward": torch.zeros(steps + 1, batch), "tilt": torch.zeros(steps + 1, batch, 2),
            "starts": torch.zeros(steps + 1, batch, dtype=torch.bool),
            "actions": torch.randint(0, 5, (steps, batch), generator=g),
            "rewards": (torch.rand(steps, batch, generator=g) < 0.2).float(),
            "ends": torch.rand(steps, batch, generator=g) < 0.15,
            "initial_state": LSTMState(torch.zeros(batch, config.network.hidden),
                                       torch.zeros(batch, config.network.hidden))})


@pytest.mark.parametrize("gae_lambda", [1.0, 0.9])
def test_segment_loss_matches_n_step_returns(gae_lambda):
    """With λ=1 the value target is the n-step return r_t + γ r_t+1 + … + γ^k V(s_T), cut at episode
    ends; with λ<1 it is the GAE target. Checked against a plain re-implementation."""
    config = A3CConfig.from_flat(obs="state", hidden=8, features=8, gamma=0.9, gae_lambda=gae_lambda)
    net = network_for(config)
    seg = _segment(config, 6, 3)
    loss, parts = a3c_segment_loss(net, seg, config)
    with torch.no_grad():
        _, values, _ = net.unroll(seg.obs, seg.prev_action, seg.prev_reward, seg.tilt, seg.initial_state,
                                  seg.starts)
    v = values.numpy().astype(np.float64)
    r, ends = seg.rewards.numpy(), seg.ends.numpy()
    targets = np.zeros((6, 3))
    for b in range(3):
        adv = 0.0
        for t in reversed(range(6)):
            nonterminal = 0.0 if ends[t, b] else 1.0
            delta = r[t, b] + 0.9 * v[t + 1, b] * nonterminal - v[t, b]
            adv = delta + 0.9 * gae_lambda * nonterminal * adv
            targets[t, b] = adv + v[t, b]
    if gae_lambda == 1.0:  # the same as discounted n-step returns
        for b in range(3):
            ret = v[6, b]
            for t in reversed(range(6)):
                ret = r[t, b] + 0.9 * ret * (0.0 if ends[t, b] else 1.0)
                assert targets[t, b] == pytest.approx(ret, abs=1e-6)
    expected_value_loss = 0.5 * np.mean((targets - v[:6]) ** 2)
    assert parts["value_loss"] == pytest.approx(expected_value_loss, rel=1e-5)
    assert parts["entropy"] == pytest.approx(np.log(5), abs=0.01)  # a fresh policy is near uniform
    loss.backward()
    assert all(p.grad is not None for p in net.parameters())


def test_config_errors_name_the_setting():
    with pytest.raises(ValueError, match="NetworkSettings.obs must be one of"):
        A3CConfig.from_flat(obs="rgb")
    with pytest.raises(ValueError, match="ScheduleSettings.workers must be an integer >= 1, got 0"):
        A3CConfig.from_flat(workers=0)
    with pytest.raises(ValueError, match=r"OptimizationSettings.gamma must be in \[0.0, 1.0\]"):
        A3CConfig.from_flat(gamma=1.5)
    with pytest.raises(ValueError, match="OptimizationSettings.lr must be a finite number > 0"):
        A3CConfig.from_flat(lr=float("nan"))
    with pytest.raises(ValueError, match="A3CConfig.task"):
        A3CConfig.from_flat(task="STG9")
    with pytest.raises(ValueError, match="OptimizationSettings.optimizer must be one of"):
        A3CConfig.from_flat(optimizer="sgd")
    assert A3CConfig.from_flat(obs="state").network.hidden == 128
    assert A3CConfig.from_flat(obs="pixels").network.hidden == 256


def test_single_worker_run_is_deterministic(tmp_path):
    config = A3CConfig.from_flat(steps=2_000, seed=5, **FAST)
    train(config, tmp_path / "a", progress=False)
    train(config, tmp_path / "b", progress=False)
    a, b = load_checkpoint(tmp_path / "a"), load_checkpoint(tmp_path / "b")
    assert a["step"] == b["step"] >= 2_000
    for key in a["model"]:
        assert torch.equal(a["model"][key], b["model"][key]), key
    fresh = network_for(config).state_dict()
    assert any(not torch.equal(a["model"][k], fresh[k]) for k in fresh), "training changed the weights"
    other = A3CConfig.from_flat(steps=2_000, seed=6, **FAST)
    train(other, tmp_path / "c", progress=False)
    c = load_checkpoint(tmp_path / "c")
    assert any(not torch.equal(a["model"][k], c["model"][k]) for k in a["model"]), "the seed matters"


def test_run_directory_guards(tmp_path):
    config = A3CConfig.from_flat(steps=400, **FAST)
    train(config, tmp_path / "run", progress=False)
    with pytest.raises(ValueError, match="already holds a run; pass --resume"):
        train(config, tmp_path / "run", progress=False)
    with pytest.raises(ValueError, match=r"--resume must keep the run's settings; changed: lr"):
        train(A3CConfig.from_flat(steps=800, lr=1e-3, **FAST), tmp_path / "run", resume=True, progress=False)
    with pytest.raises(ValueError, match="already has .* steps >= steps=400"):
        train(config, tmp_path / "run", resume=True, progress=False)
    with pytest.raises(ValueError, match="has no config.json"):
        train(config, tmp_path / "none", resume=True, progress=False)


class ScaledRewards:
    """An env wrapper gone wrong: rewards multiplied by ``factor`` (NaN, or so large that the loss
    overflows), from the ``after``-th step of each env on."""

    def __init__(self, factor: float, after: int = 0):
        self.factor, self.after = factor, after

    def __call__(self, env):
        import gymnasium as gym

        factor, after = self.factor, self.after

        class Wrapped(gym.vector.VectorWrapper):
            steps = 0

            def step(self, actions):
                obs, reward, terminated, truncated, info = self.env.step(actions)
                Wrapped.steps += 1
                if Wrapped.steps <= after:
                    return obs, reward, terminated, truncated, info
                return obs, reward * factor + (factor if factor > 1 else 0), terminated, truncated, info
        return Wrapped(env)


@pytest.mark.parametrize("factor, what", [(float("nan"), "reward from the env"), (1e38, "loss")])
def test_non_finite_values_stop_the_run_and_keep_the_weights(tmp_path, factor, what):
    """After some training, the weights from before the bad update are kept (and can be resumed)."""
    config = A3CConfig.from_flat(steps=5_000, checkpoint_every=100, **FAST)
    with pytest.raises(TrainingError, match=f"non-finite {what} .* the update was not applied.* saved in"):
        train(config, tmp_path / "run", env_wrapper=ScaledRewards(factor, after=100), progress=False)
    net = network_for(config)
    assert 0 < load_weights(net, tmp_path / "run") < 5_000  # raises on non-finite weights
    assert all(torch.isfinite(p).all() for p in net.parameters())


def test_a_new_run_that_fails_before_training_leaves_nothing_that_blocks_a_rerun(tmp_path):
    """A setting found bad only once the directory exists — a wrapper that cannot be sent to the
    workers, rewards that are NaN from the first step — leaves no directory behind: the same
    command runs again once the cause is fixed (an existing empty directory stays, empty)."""
    config = A3CConfig.from_flat(steps=400, **FAST)
    with pytest.raises(Exception, match="pickle|Can't get local object"):
        train(config, tmp_path / "run", env_wrapper=lambda env: env, progress=False)  # not picklable
    assert not (tmp_path / "run").exists()
    (tmp_path / "empty").mkdir()
    with pytest.raises(TrainingError, match="non-finite reward .* files are removed .* run the same command again"):
        train(config, tmp_path / "empty", env_wrapper=ScaledRewards(float("nan")), progress=False)
    assert list((tmp_path / "empty").iterdir()) == []
    assert train(config, tmp_path / "empty", progress=False).stopped == "finished"


def _train_command(run_dir: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "bimgame.cli.main", "train", "--run-dir", str(run_dir), "--task", "STG1", "--obs",
            "state", "--workers", "1", "--envs-per-worker", "4", "--n-steps", "10", "--hidden", "32", "--features",
            "32", "--eval-every", "0", "--no-progress", *extra]


def _wait_for_checkpoint(run_dir: Path, process: subprocess.Popen, min_step: int, timeout: float = 120) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert process.poll() is None, process.communicate()
        try:
            step = load_checkpoint(run_dir)["step"]
            if step >= min_step:
                return step
        except Exception:
            pass
        time.sleep(0.2)
    raise AssertionError("no checkpoint in time")


def test_kill_9_then_resume(tmp_path):
    run_dir = tmp_path / "run"
    process = subprocess.Popen(_train_command(run_dir, "--steps", "40k", "--checkpoint-every", "2k"),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    _wait_for_checkpoint(run_dir, process, 6_000)
    workers = _children(process.pid)
    assert workers, "the run has worker processes"
    os.kill(process.pid, signal.SIGKILL)  # only the parent: its workers must notice and exit
    process.communicate()
    killed_at = load_checkpoint(run_dir)["step"]
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and any(_running(pid) for pid in workers):
        time.sleep(0.2)
    assert not any(_running(pid) for pid in workers), "workers outlived a killed parent"
    resumed = subprocess.run(_train_command(run_dir, "--resume", "--steps", "12k"), capture_output=True,
                             text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    final = load_checkpoint(run_dir)["step"]
    assert final >= 12_000 > killed_at
    updates = np.genfromtxt(run_dir / "updates.csv", delimiter=",", names=True)
    assert np.all(np.diff(updates["step"]) > 0), "no step logged twice after the resume"
    episodes = np.genfromtxt(run_dir / "episodes.csv", delimiter=",", names=True)
    assert episodes["step"].max() <= final + 40
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["stopped"] == "finished" and summary["steps"] == final


def _children(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-eo", "ppid=,pid="], capture_output=True, text=True).stdout
    return [int(child) for parent, child in (line.split() for line in out.splitlines()) if int(parent) == pid]


def _running(pid: int) -> bool:
    """Alive and not a zombie."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


def _as_from_a_terminal() -> None:
    """In the child before it runs: SIGINT delivered and handled by default, as from a terminal. A
    process inherits an ignored or blocked signal from its parent (a test runner's worker may have
    one), and Python then never raises KeyboardInterrupt."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def test_ctrl_c_stops_cleanly_with_a_final_checkpoint(tmp_path):
    run_dir = tmp_path / "run"
    process = subprocess.Popen(_train_command(run_dir, "--steps", "1M", "--checkpoint-every", "500k"),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=_as_from_a_terminal)
    deadline = time.monotonic() + 120
    while not (run_dir / "updates.csv").is_file() or len((run_dir / "updates.csv").read_text().splitlines()) < 3:
        assert time.monotonic() < deadline and process.poll() is None, process.communicate()
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    try:
        _, stderr = process.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        process.kill()
        _, stderr = process.communicate()
        raise AssertionError(f"no exit within 90 s of Ctrl-C: {stderr}") from None
    assert process.returncode == 130, stderr
    assert "interrupted" in stderr and "--resume" in stderr
    assert 0 < load_checkpoint(run_dir)["step"] < 1_000_000


def test_a3c_learns_stg1_from_state_observations(tmp_path):
    """Well beyond a random policy on STG1 in about 300k steps (one deterministic worker)."""
    config = A3CConfig.from_flat(task="STG1", obs="state", workers=1, envs_per_worker=32, steps=300_000, seed=1,
                                 eval_every=0)
    result = train(config, tmp_path / "run", progress=False)
    net = network_for(config)
    load_weights(net, tmp_path / "run")
    trained = evaluate_network(net, task="STG1", obs_mode="state", episodes=40, seed=777, greedy=False)
    untrained = evaluate_network(network_for(config), task="STG1", obs_mode="state", episodes=40, seed=777,
                                 greedy=False)
    assert untrained.success_rate <= 0.35  # an untrained network acts about uniformly at random (~15%)
    assert trained.success_rate >= untrained.success_rate + 0.4, (trained.summary(), untrained.summary())
    assert trained.mean_length < 0.7 * untrained.mean_length
    assert result.final_eval is None or result.final_eval["sampled_success_rate"] >= 0


def test_workers_that_die_silently_fail_the_run_instead_of_finishing_it(tmp_path):
    """A script without a ``__main__`` guard makes every spawned worker fail while starting, before its
    own error handling: the run must fail with advice, not be recorded as finished at step 0."""
    script = tmp_path / "unguarded.py"
    script.write_text("import sys\nfrom bimgame.learn.a3c import A3CConfig, train\n"
                      "train(A3CConfig.from_flat(task='STG1', obs='state', workers=1, envs_per_worker=2, "
                      "steps=2000, eval_every=0, hidden=16, features=16), sys.argv[1], progress=False)\n")
    done = subprocess.run([sys.executable, str(script), str(tmp_path / "run")], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert done.returncode != 0
    assert "exited at step 0 of 2,000 without reporting an error" in done.stderr
    assert "__main__" in done.stderr
    assert not (tmp_path / "run" / "summary.json").exists()
