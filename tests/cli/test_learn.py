"""``bimgame pretrain`` and ``bimgame dagger`` through the command line: bad flags are refused by
name, tiny runs write their run directories, and resuming a finished DAgger run does no work."""

from __future__ import annotations

import csv
import json
import math

import pytest
from support.disk import disk_fills_up
from support.files import snapshot

from bimgame.cli.learn import INIT_NETWORK_FLAGS, init_network_flags
from bimgame.cli.main import build_parser, main
from bimgame.expert.datasets import generate_dataset
from bimgame.expert.mpc import MPCConfig
from bimgame.learn.runs import KIND_POLICY, KIND_VALUE

#: Network sizes small enough that a run takes seconds.
SMALL_NET = ["--hidden", "16", "--features", "16"]


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Tiny networks: a second intra-op thread only slows them down on the shared 2-core machine
    (pretrain and dagger never use more threads than their caller has set)."""
    from bimgame.learn.runs import torch_threads

    with torch_threads(1):
        yield


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """Four STG1 episodes of a weak, cheap expert (K=4, H=8) cut at 40 steps, on one worker, as
    tests/expert/test_datasets.py makes them."""
    out = tmp_path_factory.mktemp("tiny-data") / "data"
    return generate_dataset(out, "STG1", 4, seed=1, config=MPCConfig(n_samples=4, horizon=8), workers=1,
                            max_steps=40, progress=False)


def _csv_rows(path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _flat(text: str) -> str:
    return " ".join(text.split())


# ----------------------------------------------------------------------------------- bad flags
@pytest.mark.parametrize("argv, flag, message", [
    (["pretrain", "--out", "OUT"], "--data", "required"),
    (["pretrain", "--data", "DATA"], "--out", "required"),
    (["pretrain", "--data", "DATA", "--out", "OUT", "--obs", "rgb"], "--obs", "invalid choice: 'rgb'"),
    (["pretrain", "--data", "DATA", "--out", "OUT", "--task", "STG9"], "--task", "invalid choice: 'STG9'"),
    (["pretrain", "--data", "DATA", "--out", "OUT", "--epochs", "0"], "--epochs", "expected a positive integer"),
    (["pretrain", "--data", "DATA", "--out", "OUT", "--lr", "-1"], "--lr", "-1"),
    (["pretrain", "--data", "DATA", "--out", "OUT", "--eval-episodes", "many"], "--eval-episodes", "many"),
    (["pretrain", "--data", "DATA", "--out", "OUT", "--bogus"], "--bogus", "unrecognized arguments"),
    (["dagger"], "--run-dir", "required"),
    (["dagger", "--run-dir", "RUN", "--iterations", "0"], "--iterations", "expected a positive integer"),
    (["dagger", "--run-dir", "RUN", "--beta0", "often"], "--beta0", "often"),
    (["dagger", "--run-dir", "RUN", "--beta-decay", "-0.5"], "--beta-decay", "-0.5"),
    (["dagger", "--run-dir", "RUN", "--obs", "rgb"], "--obs", "invalid choice: 'rgb'"),
    (["dagger", "--run-dir", "RUN", "--task", "STG9"], "--task", "invalid choice: 'STG9'"),
    (["dagger", "--run-dir", "RUN", "--episodes-per-iteration", "0"], "--episodes-per-iteration",
     "expected a positive integer"),
])
def test_bad_flags_exit_2_naming_the_flag(argv, flag, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert flag in err and message in err, err
    assert list(tmp_path.iterdir()) == []  # nothing created


def test_values_only_the_settings_can_judge_are_refused_by_name_without_a_traceback(tiny_dataset, tmp_path,
                                                                                      capsys):
    out = tmp_path / "pre"
    common = ["pretrain", "--data", str(tiny_dataset), "--out", str(out), "--task", "STG1", "--obs", "state",
              "--no-progress"]
    assert main([*common, "--val-fraction", "1.5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bimgame pretrain: error:") and "val_fraction" in err and "1.5" in err
    assert main([*common, "--gamma", "2"]) == 2
    assert "gamma" in capsys.readouterr().err
    # A directory that is not a dataset.
    assert main(["pretrain", "--data", str(tmp_path / "nothing"), "--out", str(out), "--task", "STG1", "--obs",
                 "state", "--no-progress"]) == 2
    assert "bimgame pretrain: error:" in capsys.readouterr().err
    assert not out.exists()

    assert main(["dagger", "--run-dir", str(tmp_path / "run"), "--beta0", "1.5", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bimgame dagger: error:") and "beta0" in err
    # --resume needs a run to continue.
    assert main(["dagger", "--run-dir", str(tmp_path / "run"), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and "config.json" in err
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------------------------ pretrain
def test_tiny_pretrain_writes_its_summary_and_checkpoint(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "pi"
    assert main(["pretrain", "--data", str(tiny_dataset), "--out", str(out), "--task", "STG1", "--obs", "state",
                 "--epochs", "2", "--patience", "1", "--eval-episodes", "2", "--seed", "3", *SMALL_NET,
                 "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert f"--init {out}" in _flat(captured.out)  # how to use it
    # The hint is a train command whose network fits π^s: it repeats the sizes given.
    hint = _flat(captured.out).split("use it with: bimgame ")[1].split()
    train = build_parser().parse_args(hint)
    assert (train.verb, train.task, train.obs, train.hidden, train.features) == ("train", "STG1", "state", 16, 16)
    for name in ("config.json", "checkpoint.pt", "summary.json", "pretrain.csv"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name

    summary = json.loads((out / "summary.json").read_text())
    config = json.loads((out / "config.json").read_text())
    assert summary["kind"] == config["kind"] == KIND_POLICY
    # The flags reached the settings.
    assert (config["pretrain"]["task"], config["pretrain"]["obs"], config["pretrain"]["target"]) == (
        "STG1", "state", "policy")
    assert (config["pretrain"]["epochs"], config["pretrain"]["patience"], config["pretrain"]["seed"]) == (2, 1, 3)
    assert (config["pretrain"]["hidden"], config["pretrain"]["features"]) == (16, 16)
    # Four episodes: at least one held out, the others trained on.
    assert summary["episodes"]["train"] + summary["episodes"]["held_out"] == 4
    assert summary["episodes"]["held_out"] >= 1 and summary["episodes"]["train"] >= 1
    assert 1 <= summary["epochs_run"] <= 2 and 0 <= summary["best_epoch"] <= summary["epochs_run"]
    rows = _csv_rows(out / "pretrain.csv")
    assert len(rows) == summary["epochs_run"] + 1  # the initial held-out measurement, then each epoch
    assert 0.0 <= summary["val_accuracy"] <= 1.0 and math.isfinite(summary["val_value_rmse"])
    assert f"{summary['val_value_rmse']:.3f}" in captured.out

    # The checkpoint is the network the summary evaluated as a policy: π^s alone on STG1, two
    # episodes from pre-training's evaluation seed (12345, also bimgame evaluate's default).
    from bimgame.learn.actor import evaluate_network
    from bimgame.learn.common import load_run_network

    net, run, _ = load_run_network(out)
    assert (net.config.hidden, net.config.features, run.task) == (16, 16, "STG1")
    assert summary["policy_eval"]["episodes"] == 2
    for mode, greedy in (("greedy", True), ("sampled", False)):
        result = evaluate_network(net, task="STG1", obs_mode="state", episodes=2, seed=12345, greedy=greedy)
        for key, value in result.summary().items():
            if key != "episodes":
                assert summary["policy_eval"][f"{mode}_{key}"] == pytest.approx(value), (mode, key)

    # The run is never overwritten.
    before = snapshot(out, without_tensorboard=True)
    assert main(["pretrain", "--data", str(tiny_dataset), "--out", str(out), "--task", "STG1", "--obs", "state",
                 "--epochs", "1", "--eval-episodes", "0", "--no-progress"]) == 2
    assert "already holds a run" in capsys.readouterr().err
    assert snapshot(out, without_tensorboard=True) == before


@pytest.mark.parametrize("given", [
    ["--keypoints", "--subtract-background", "--motion"],
    ["--no-tilt-input", "--hidden", "64", "--no-aux-heads"],
    ["--surroundings", "--features", "32", "--aux-heads", "--gate-bearings"],
])
def test_the_pretrain_hint_repeats_every_network_flag_given_so_bimgame_train_builds_the_same_network(given):
    parser = build_parser()
    pretrain = parser.parse_args(["pretrain", "--data", "d", "--out", "o", *given])
    hint = init_network_flags(pretrain).split()
    assert sorted(hint) == sorted(given)
    train = parser.parse_args(["train", "--run-dir", "r", *hint])
    for name in INIT_NETWORK_FLAGS:
        assert getattr(train, name) == getattr(pretrain, name), name


def test_tiny_value_only_pretrain(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "v"
    assert main(["pretrain", "--data", str(tiny_dataset), "--out", str(out), "--task", "STG1", "--obs", "state",
                 "--value-only", "--epochs", "1", "--eval-episodes", "2", *SMALL_NET, "--no-progress"]) == 0
    assert f"--value-reward {out}" in _flat(capsys.readouterr().out)
    summary = json.loads((out / "summary.json").read_text())
    config = json.loads((out / "config.json").read_text())
    assert config["pretrain"]["target"] == "value"
    assert summary["kind"] == config["kind"] == KIND_VALUE
    assert summary["policy_eval"] is None  # a value function is not evaluated as a policy
    assert summary["epochs_run"] == 1 and (out / "checkpoint.pt").is_file()


# -------------------------------------------------------------------------------------- dagger
DAGGER_RUN = ["--task", "STG1", "--obs", "state", "--iterations", "1", "--episodes-per-iteration", "2",
              "--epochs-per-iteration", "1", "--beta-decay", "1", "--seed", "2", *SMALL_NET, "--no-progress"]


@pytest.fixture(scope="module")
def tiny_dagger(tmp_path_factory):
    """One iteration of two expert-executed episodes (β0 = 1: the expert acts, so rollouts are
    short even with the CLI's default expert), two evaluation episodes."""
    run_dir = tmp_path_factory.mktemp("dagger") / "run"
    assert main(["dagger", "--run-dir", str(run_dir), *DAGGER_RUN, "--eval-episodes", "2"]) == 0
    return run_dir


def test_tiny_dagger_writes_its_run_directory(tiny_dagger):
    import numpy as np

    from bimgame.learn.common import load_run_network

    run_dir = tiny_dagger
    for name in ("config.json", "checkpoint.pt", "dagger.csv", "dagger_state.json", "data/iteration_000.npz"):
        assert (run_dir / name).is_file(), name
    assert not (run_dir / "data" / "iteration_001.npz").exists()
    stored = json.loads((run_dir / "config.json").read_text())
    settings = stored["dagger"]
    assert (settings["iterations"], settings["episodes_per_iteration"], settings["epochs_per_iteration"],
            settings["beta0"], settings["beta_decay"], settings["eval_episodes"]) == (1, 2, 1, 1.0, 1.0, 2)
    assert (settings["learner"]["task"], settings["learner"]["obs"], settings["learner"]["seed"],
            settings["learner"]["hidden"], settings["learner"]["features"]) == ("STG1", "state", 2, 16, 16)

    rows = _csv_rows(run_dir / "dagger.csv")
    assert len(rows) == 1 and int(rows[0]["iteration"]) == 0 and int(rows[0]["episodes"]) == 2
    state = json.loads((run_dir / "dagger_state.json").read_text())
    with np.load(run_dir / "data" / "iteration_000.npz") as data:
        lengths = data["lengths"]
        executed, labels = data["executed"], data["actions"]
    assert len(lengths) == 2 and state["iteration"] == 1
    assert state["env_steps"] == int(rows[0]["step"]) == int(lengths.sum())
    np.testing.assert_array_equal(executed, labels)  # β = 1: the expert's actions were executed
    for key in ("greedy_success_rate", "sampled_success_rate"):
        assert 0.0 <= float(rows[0][key]) <= 1.0, key
    net, run, step = load_run_network(run_dir)
    assert step == state["env_steps"] and net.config.hidden == 16 and run.task == "STG1"


def test_resuming_a_finished_dagger_run_does_no_work(tiny_dagger, tmp_path, capsys):
    import shutil

    run_dir = shutil.copytree(tiny_dagger, tmp_path / "run")
    before = snapshot(run_dir, without_tensorboard=True)
    capsys.readouterr()
    # The run's own settings are used; the same number of iterations means nothing is left.
    assert main(["dagger", "--run-dir", str(run_dir), "--resume", "--no-progress"]) == 0
    out = _flat(capsys.readouterr().out)
    assert "nothing to do" in out and "1 iterations" in out and "--iterations" in out
    after = snapshot(run_dir, without_tensorboard=True)
    assert after == before  # no new data, weights, state or log rows
    assert not (run_dir / "data" / "iteration_001.npz").exists()


def test_a_run_without_evaluations_is_not_reported_as_nothing_to_do(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["dagger", "--run-dir", str(run_dir), *DAGGER_RUN, "--eval-episodes", "0"]) == 0
    assert (run_dir / "data" / "iteration_000.npz").is_file()  # the iteration ran
    assert "nothing to do" not in capsys.readouterr().out


# ------------------------------------------------------------------------------ reliability
PRETRAIN_TINY = ["--task", "STG1", "--obs", "state", "--epochs", "1", "--eval-episodes", "0", *SMALL_NET,
                 "--no-progress"]


def test_pretrain_refuses_a_directory_holding_other_files(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "pretrain.csv").write_text("my,own\n")
    (out / "summary.json").write_text("{}\n")
    before = snapshot(out, without_tensorboard=True)
    assert main(["pretrain", "--data", str(tiny_dataset), "--out", str(out), *PRETRAIN_TINY]) == 2
    err = _flat(capsys.readouterr().err)
    assert (f"{out} is not empty and is not a pre-training run (no config.json; found 2 entries: 'pretrain.csv', "
            f"'summary.json'); nothing was changed") in err
    assert snapshot(out, without_tensorboard=True) == before


@pytest.mark.parametrize("stop, code", [(ValueError("a bad setting found late"), 2), (KeyboardInterrupt(), 130)])
def test_pretraining_that_stops_early_leaves_nothing_that_blocks_a_rerun(tiny_dataset, tmp_path, monkeypatch, capsys,
                                                                          stop, code):
    def stopped(*args, **kwargs):
        raise stop
    monkeypatch.setattr("bimgame.learn.pretrain.policy_epoch", stopped)
    out = tmp_path / "pi"
    argv = ["pretrain", "--data", str(tiny_dataset), "--out", str(out), *PRETRAIN_TINY]
    assert main(argv) == code
    assert not out.exists()
    monkeypatch.undo()
    assert main(argv) == 0
    assert (out / "summary.json").is_file()


def test_disk_full_during_pretraining_names_the_file(tiny_dataset, tmp_path, monkeypatch, capsys):
    disk_fills_up(monkeypatch, "checkpoint.pt")
    out = tmp_path / "pi"
    assert main(["pretrain", "--data", str(tiny_dataset), "--out", str(out), *PRETRAIN_TINY]) == 2
    err = _flat(capsys.readouterr().err)
    assert f"cannot write {out / 'checkpoint.pt'}: No space left on device" in err and "run the same command" in err
    assert not out.exists()


def test_dagger_gate_bearings_flag_reaches_the_learner_and_is_refused_without_mazes(tmp_path, capsys):
    base = ["dagger", "--task", "STG1", "--obs", "state", *SMALL_NET, "--no-progress"]
    assert main([*base, "--gate-bearings", "--run-dir", str(tmp_path / "refused")]) == 2
    assert "gate_bearings without num_mazes" in _flat(capsys.readouterr().err)
    run = tmp_path / "run"
    argv = [*base, "--gate-bearings", "--num-mazes", "0", "--iterations", "1", "--episodes-per-iteration", "1",
            "--max-episode-steps", "20", "--eval-episodes", "1", "--run-dir", str(run)]
    assert main(argv) == 0
    stored = json.loads((run / "config.json").read_text())
    assert stored["dagger"]["learner"]["gate_bearings"] is True


# ------------------------------------------------------------------------------ the expert
def _dagger_args(*flags: str):
    from bimgame.cli.main import build_parser

    return build_parser().parse_args(["dagger", "--run-dir", "RUN", *flags])


def test_dagger_mpc_flags_set_the_labelling_expert_over_the_tasks_own():
    from bimgame.cli.flags import given_settings
    from bimgame.cli.learn import DAGGER_FLAGS, dagger_expert_from, dagger_learner_from
    from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
    from bimgame.learn.dagger import DAggerConfig

    def expert(*flags):
        args = _dagger_args(*flags)
        given = given_settings(args, DAggerConfig, DAGGER_FLAGS)
        return dagger_expert_from(args, dagger_learner_from(args), given)

    assert expert("--task", "STG1") is None  # DAgger picks the task's own expert
    assert expert("--task", "STG1", "-K", "4", "-H", "8") == MPCConfig(n_samples=4, horizon=8)
    # On random mazes the geodesic reward DAgger picks stays unless the flag says otherwise.
    assert expert("--task", "STG1", "--num-mazes", "0", "-K", "4") == MPCConfig(n_samples=4, reward="geodesic")
    board = expert("--task", "LABYRINTH-HARD", "--action-type", "continuous", "-K", "64")
    assert board == LabyrinthMPCConfig(n_samples=64)
    board = expert("--task", "LABYRINTH-HARD", "--action-type", "continuous", "--plans", "4")
    assert board == LabyrinthMPCConfig(n_plans=4)
    with pytest.raises(ValueError, match="--plans: the labyrinth's expert setting, not the circular maze's"):
        expert("--task", "STG1", "-P", "4")
    board = expert("--task", "LABYRINTH-HARD", "--action-type", "continuous", "--sampling", "mppi")
    assert board == LabyrinthMPCConfig(sampling="mppi")
    with pytest.raises(ValueError, match=r"--sampling mppi: the labyrinth's expert setting.*uniform or hold"):
        expert("--task", "STG1", "--sampling", "mppi")
    with pytest.raises(ValueError, match="--planning-reward: the circular maze's expert setting"):
        expert("--task", "LABYRINTH-HARD", "--action-type", "continuous", "--planning-reward", "geodesic")
    with pytest.raises(ValueError, match=r"--resume keeps the run's expert; drop the MPC expert's settings given "
                                         r"\(--horizon, --n-samples\)"):
        expert("--resume", "-K", "4", "-H", "8")


def test_dagger_stores_the_expert_the_flags_set(tmp_path):
    run = tmp_path / "run"
    assert main(["dagger", "--run-dir", str(run), *DAGGER_RUN, "--eval-episodes", "0", "-K", "4", "-H", "8"]) == 0
    stored = json.loads((run / "config.json").read_text())["dagger"]["expert"]
    assert (stored["n_samples"], stored["horizon"]) == (4, 8)
