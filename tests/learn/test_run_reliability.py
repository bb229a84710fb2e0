"""What A3C run directories survive: other people's files, foreign or cut-off logs, a missing
checkpoint, a resume at the checkpoint's step, SIGTERM during the final evaluation, a full disk, and
unreadable inputs — each refused or handled with a message that names the file and what to do."""

from __future__ import annotations

import csv
import errno
import json
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from support.disk import disk_fills_up
from support.files import snapshot

from bimgame.cli.main import main
from bimgame.learn.a3c import A3CConfig, network_for, resolve_config, train
from bimgame.learn.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from bimgame.learn.runs import KIND_A3C, run_kind

#: A run of a few seconds (one worker, tiny network, no evaluator).
TINY = dict(task="STG1", obs="state", steps=400, workers=1, envs_per_worker=2, n_steps=10, hidden=16, features=16,
            eval_every=0)
TINY_FLAGS = ["--task", "STG1", "--obs", "state", "--workers", "1", "--envs-per-worker", "2", "--n-steps", "10",
              "--hidden", "16", "--features", "16", "--eval-every", "0", "--no-progress"]


#: The finished run's settings: long enough for a few finished episodes (STG1's limit is 300 steps).
FINISHED = {**TINY, "envs_per_worker": 4, "steps": 1600}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A finished tiny run; tests work on copies of it."""
    run_dir = tmp_path_factory.mktemp("finished") / "run"
    train(A3CConfig.from_flat(**FINISHED), run_dir, progress=False)
    return run_dir


def _copy(run_dir: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run_dir, tmp_path / "copy"))


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _append(path: Path, text: str) -> None:
    with open(path, "a", newline="") as handle:
        handle.write(text)


# ----------------------------------------------------------------- other people's directories
def test_train_refuses_a_directory_that_is_not_an_a3c_run(tmp_path, capsys):
    config = A3CConfig.from_flat(**TINY)
    mine = tmp_path / "mine"
    mine.mkdir()
    for name, text in (("episodes.csv", "my,own\n1,2\n"), ("summary.json", '{"mine": true}\n'), ("notes.txt", "x")):
        (mine / name).write_text(text)
    before = snapshot(mine)
    with pytest.raises(ValueError, match=r"mine is not empty and is not an A3C run \(no config.json; found 3 entries: "
                                         r"'episodes.csv', 'notes.txt', 'summary.json'\); nothing was changed"):
        train(config, mine, progress=False)
    with pytest.raises(ValueError, match=r"--resume: .*mine has no config.json: .*mine is not an A3C run \(found 3"):
        train(config, mine, resume=True, progress=False)
    with pytest.raises(ValueError, match="is not an A3C run"):
        resolve_config({}, mine, resume=True)
    assert main(["train", "--run-dir", str(mine), *TINY_FLAGS]) == 2
    err = capsys.readouterr().err
    assert str(mine) in err and "'episodes.csv'" in err
    assert snapshot(mine) == before

    # A run of another kind (here a pre-training run of the earlier layout, with an "a3c" block).
    other = tmp_path / "pretrained"
    other.mkdir()
    (other / "config.json").write_text(json.dumps({"kind": "pretrained-policy", "a3c": config.to_dict()}))
    before = snapshot(other)
    with pytest.raises(ValueError, match="already holds a run; choose a new --run-dir .it is a pretrained-policy run"):
        train(config, other, progress=False)
    with pytest.raises(ValueError, match="holds a pretrained-policy run, not an A3C run"):
        train(config, other, resume=True, progress=False)
    with pytest.raises(ValueError, match="holds a pretrained-policy run, not an A3C run"):
        resolve_config({}, other, resume=True)
    assert snapshot(other) == before

    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="exists and is not a directory"):
        train(config, tmp_path / "file", progress=False)


# ------------------------------------------------------------------------------ resuming
def test_resume_refuses_a_log_whose_header_differs(finished_run, tmp_path):
    """episodes.csv with another header used to lose every row silently (59 -> 2 rows)."""
    run_dir = _copy(finished_run, tmp_path)
    path = run_dir / "episodes.csv"
    lines = path.read_text().splitlines(keepends=True)
    assert len(lines) > 2
    path.write_text(lines[0].replace("return", "reward") + "".join(lines[1:]))
    before = snapshot(run_dir)
    with pytest.raises(ValueError) as refused:
        train(A3CConfig.from_flat({**FINISHED, "steps": 3200}), run_dir, resume=True, progress=False)
    message = str(refused.value)
    assert str(path) in message
    assert "step,start_step,worker,reward,length,success" in message  # found
    assert "step,start_step,worker,return,length,success" in message  # expected
    assert snapshot(run_dir) == before, "a refused resume changes nothing"


def test_resume_without_a_checkpoint_is_refused(finished_run, tmp_path, capsys):
    """A missing checkpoint.pt used to restart from step 0 and drop every logged row."""
    run_dir = _copy(finished_run, tmp_path)
    (run_dir / "checkpoint.pt").unlink()
    before = snapshot(run_dir)
    with pytest.raises(ValueError, match=r"--resume: .* has no checkpoint.pt, so the A3C run in it cannot be "
                                         r"continued .*Start anew without --resume in a new --run-dir"):
        train(A3CConfig.from_flat({**FINISHED, "steps": 3200}), run_dir, resume=True, progress=False)
    assert main(["train", "--run-dir", str(run_dir), "--resume", "--steps", "3200", "--no-progress"]) == 2
    assert "has no checkpoint.pt" in capsys.readouterr().err
    assert snapshot(run_dir) == before


def _header(path: Path) -> list[str]:
    return path.read_text().splitlines()[0].split(",")


def test_resume_keeps_the_rows_before_the_checkpoint_and_counts_the_whole_run(tmp_path):
    """Rows logged at exactly the checkpoint's step S: episodes that ended there came after it (the
    segment from S on is trained again) and are dropped; the update row of step S was logged before
    the checkpoint and is kept; evaluations from S on are dropped and the resumed run evaluates the
    checkpoint's weights at S (the step-0 evaluation of the fresh run survives). A row cut off by a
    kill is dropped. Seconds count the whole run."""
    run_dir = tmp_path / "run"
    config = A3CConfig.from_flat({**TINY, "eval_every": 200, "eval_episodes": 2})
    train(config, run_dir, progress=False)
    payload = load_checkpoint(run_dir)
    step = payload["step"]
    save_checkpoint(run_dir / "checkpoint.pt", model=payload["model"], optimizer=payload["optimizer"], step=step,
                    seconds=1000.0, config=payload["config"])  # as if the run had trained 1000 s so far
    first_eval = [int(r["step"]) for r in _rows(run_dir / "eval.csv")]
    assert first_eval[0] == 0 and first_eval[-1] == step
    _append(run_dir / "episodes.csv", f"{step - 1},0,8,1,5,True,True\r\n{step},0,7,1,5,True,True\r\n")
    blanks = "," * (len(_header(run_dir / "updates.csv")) - 7)  # the update row's columns after the losses
    _append(run_dir / "updates.csv", f"{step},1,12345,0,0,0,0{blanks}\r\n{step + 20},1,54321,0,0,0,0{blanks}\r\n")
    _append(run_dir / "episodes.csv", f"{step + 1},0,9,1")  # cut off by a kill

    result = train(A3CConfig.from_flat({**config.to_dict(), "steps": 800}), run_dir, resume=True, progress=False)
    assert result.stopped == "finished" and result.steps >= 800
    workers = [r["worker"] for r in _rows(run_dir / "episodes.csv")]
    assert "8" in workers and "7" not in workers and "9" not in workers
    updates = _rows(run_dir / "updates.csv")
    assert [r["sps"] for r in updates].count("12345") == 1 and "54321" not in [r["sps"] for r in updates]
    assert all(float(r["seconds"]) >= 1000 for r in updates if int(r["step"]) > step)
    evals = [int(r["step"]) for r in _rows(run_dir / "eval.csv")]
    assert evals == sorted(set(evals)), f"an evaluation step logged twice: {evals}"
    assert evals[0] == 0 and step in evals and evals[-1] == result.steps
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["seconds"] >= 1000 and result.seconds >= 1000
    assert load_checkpoint(run_dir)["seconds"] >= 1000


_STOP_IN_FINAL_EVALUATION = '''
import os, signal, sys, time

import bimgame.learn.a3c.training as a3c_train
from bimgame.cli.main import main


def evaluate(net, config):
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(60)
    raise AssertionError("SIGTERM did not stop the final evaluation")


if __name__ == "__main__":
    a3c_train.run_evaluation = evaluate  # the parent's final evaluation (--eval-every 0: no evaluator process)
    sys.exit(main(sys.argv[1:]))
'''


def test_sigterm_during_the_final_evaluation_then_resume_does_just_the_evaluation(tmp_path, capsys):
    """SIGTERM during the final evaluation used to kill the run (exit 143) without a summary, and
    --resume then refused ("already has N steps")."""
    script = tmp_path / "stop.py"
    script.write_text(_STOP_IN_FINAL_EVALUATION)
    run_dir = tmp_path / "run"
    done = subprocess.run([sys.executable, str(script), "train", "--run-dir", str(run_dir), "--steps", "400",
                           *TINY_FLAGS], capture_output=True, text=True, timeout=300)
    assert done.returncode == 130, done.stderr
    assert "final evaluation" in done.stderr and "--resume" in done.stderr
    step = load_checkpoint(run_dir)["step"]
    assert step >= 400
    assert json.loads((run_dir / "summary.json").read_text())["stopped"] == "interrupted"
    assert _rows(run_dir / "eval.csv") == []
    episodes = (run_dir / "episodes.csv").read_bytes()

    assert main(["train", "--run-dir", str(run_dir), "--resume", "--no-progress"]) == 0
    assert f"done: {step:,} steps" in capsys.readouterr().out
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["stopped"] == "finished" and summary["steps"] == step and summary["final_eval"]["step"] == step
    assert [int(r["step"]) for r in _rows(run_dir / "eval.csv")] == [step]
    assert load_checkpoint(run_dir)["step"] == step, "no more training"
    assert (run_dir / "episodes.csv").read_bytes() == episodes
    assert main(["train", "--run-dir", str(run_dir), "--resume", "--no-progress"]) == 2
    assert "already has" in capsys.readouterr().err


# ------------------------------------------------------------------------------ full disks
def test_disk_full_while_training_names_the_file_and_how_to_resume(tmp_path, monkeypatch, capsys):
    run_dir = tmp_path / "run"
    disk_fills_up(monkeypatch, "checkpoint.pt", after=2)  # step 0 and the first interval are saved
    assert main(["train", "--run-dir", str(run_dir), "--steps", "2000", "--checkpoint-every", "400",
                 *TINY_FLAGS]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert f"cannot write {run_dir / 'checkpoint.pt'}: No space left on device" in err
    assert "continue with --resume" in err
    saved = load_checkpoint(run_dir)["step"]
    assert 400 <= saved < 2000
    assert not list(run_dir.glob(".*.tmp")), "no temporary file left behind"
    monkeypatch.undo()
    assert main(["train", "--run-dir", str(run_dir), "--resume", "--no-progress"]) == 0
    assert json.loads((run_dir / "summary.json").read_text())["steps"] >= 2000


class _FillingUp:
    """A log file's handle on a disk that fills up after ``rows`` more writes."""

    def __init__(self, handle, rows: int):
        self._handle, self._rows = handle, rows

    def write(self, text):
        self._rows -= 1
        if self._rows < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._handle.write(text)

    def __getattr__(self, name):
        return getattr(self._handle, name)


def test_disk_full_while_logging_names_the_log_and_the_run_resumes(tmp_path, monkeypatch, capsys):
    real_open = Path.open

    def open_(path, mode="r", *args, **kwargs):
        handle = real_open(path, mode, *args, **kwargs)
        return _FillingUp(handle, rows=30) if path.name == "updates.csv" and "a" in mode else handle
    monkeypatch.setattr(Path, "open", open_)
    run_dir = tmp_path / "run"
    assert main(["train", "--run-dir", str(run_dir), "--steps", "3000", "--checkpoint-every", "200",
                 "--log-every", "20", *TINY_FLAGS]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert f"cannot write {run_dir / 'updates.csv'}: No space left on device" in err and "--resume" in err
    saved = load_checkpoint(run_dir)["step"]
    assert 0 < saved < 3000
    monkeypatch.undo()
    assert main(["train", "--run-dir", str(run_dir), "--resume", "--no-progress"]) == 0
    steps = [int(r["step"]) for r in _rows(run_dir / "updates.csv")]
    assert steps == sorted(set(steps)) and steps[-1] >= 3000


def test_disk_full_before_anything_was_trained_leaves_nothing(tmp_path, monkeypatch, capsys):
    disk_fills_up(monkeypatch, "checkpoint.pt", after=0)
    assert main(["train", "--run-dir", str(tmp_path / "run"), "--steps", "400", *TINY_FLAGS]) == 2
    assert f"cannot write {tmp_path / 'run' / 'checkpoint.pt'}: No space left on device" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


# --------------------------------------------------------------------------- old run directories
#: The config.json of an A3C run stored before A3C recorded its kind, byte for byte as ``train`` wrote
#: it then for TINY's settings: it has no "kind".
OLD_A3C_CONFIG = """{
  "a3c": {
    "actor_ramp_steps": 0,
    "advantage_norm": false,
    "asymmetric_critic": false,
    "augment_shift": 0,
    "aux_coef": 1.0,
    "aux_heads": false,
    "bc_coef": 0.0,
    "bc_decay_steps": 0,
    "checkpoint_every": 100000,
    "critic_warmup_steps": 0,
    "curriculum_threshold": 0.8,
    "entropy_coef": 0.01,
    "entropy_target": null,
    "entropy_target_steps": 0,
    "envs_per_worker": 2,
    "eval_episodes": 10,
    "eval_every": 0,
    "expert_data": null,
    "features": 16,
    "finetune": null,
    "gae_lambda": 1.0,
    "gamma": 0.99,
    "hidden": 16,
    "keypoints": false,
    "kl_coef": 0.0,
    "kl_decay_steps": 0,
    "kl_temperature": 1.0,
    "log_every": 2000,
    "lr": 0.0007,
    "max_episode_steps": null,
    "max_grad_norm": 0.5,
    "n_steps": 10,
    "obs": "state",
    "optimizer": "rmsprop",
    "optimizer_eps": 1e-05,
    "precision": "fp32",
    "randomize": null,
    "rmsprop_alpha": 0.99,
    "seed": 0,
    "start_curriculum": "none",
    "steps": 400,
    "subtract_background": false,
    "task": "STG1",
    "tilt_input": true,
    "value_coef": 0.5,
    "workers": 1
  },
  "init": null,
  "net": {
    "asymmetric_critic": false,
    "aux_heads": false,
    "conv_channels": [
      16,
      32
    ],
    "encoder": "mlp",
    "features": 16,
    "hidden": 16,
    "keypoints": false,
    "n_actions": 5,
    "obs_shape": [
      7
    ],
    "precision": "fp32",
    "privileged_size": 0,
    "subtract_background": false,
    "tilt_input": true
  }
}
"""


def test_an_a3c_run_stored_before_its_kind_was_recorded_still_resumes_and_evaluates(tmp_path, capsys):
    run_dir = tmp_path / "old"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(OLD_A3C_CONFIG)
    stored = json.loads(OLD_A3C_CONFIG)
    config = A3CConfig.from_dict(stored["a3c"])
    assert "kind" not in stored and config == A3CConfig.from_flat(**TINY)
    save_checkpoint(run_dir / "checkpoint.pt", model=network_for(config).state_dict(), step=0, seconds=0.0,
                    config=json.dumps(config.to_dict()))
    assert run_kind(run_dir) == KIND_A3C
    assert resolve_config({}, run_dir, resume=True) == config
    result = train(config, run_dir, resume=True, progress=False)
    assert (result.steps, result.stopped) == (400, "finished")
    assert (run_dir / "config.json").read_text() == OLD_A3C_CONFIG  # a resume keeps the record as it is
    assert main(["evaluate", str(run_dir), "--episodes", "1"]) == 0
    assert "error" not in capsys.readouterr().err


# ------------------------------------------------------------------------------ bad input
class _Code:
    def __reduce__(self):
        return (print, ("ran",))


def test_unreadable_init_checkpoints_say_why_and_never_advise_weights_only_false(tmp_path, capsys):
    config = A3CConfig.from_flat(**TINY)
    (tmp_path / "empty.pt").write_bytes(b"")
    with pytest.raises(CheckpointError, match=r"--init: cannot read checkpoint .*empty.pt: the file is empty"):
        train(config, tmp_path / "run", init=tmp_path / "empty.pt", progress=False)
    assert not (tmp_path / "run").exists()
    (tmp_path / "random.pt").write_bytes(np.random.default_rng(0).integers(0, 256, 200, dtype=np.uint8).tobytes())
    (tmp_path / "pickle.pt").write_bytes(pickle.dumps(_Code()))
    torch.save({"weights": _Code()}, tmp_path / "code.pt")
    full = tmp_path / "full.pt"
    save_checkpoint(full, model=network_for(config).state_dict(), step=0)
    (tmp_path / "truncated.pt").write_bytes(full.read_bytes()[:500])
    for name, says in (("empty.pt", "empty"), ("random.pt", "not a PyTorch checkpoint, or it is damaged"),
                       ("pickle.pt", "not a PyTorch checkpoint, or it is damaged"), ("code.pt", "could run code"),
                       ("truncated.pt", "truncated")):
        assert main(["train", "--run-dir", str(tmp_path / "run"), "--init", str(tmp_path / name),
                     *TINY_FLAGS]) == 2, name
        err = " ".join(capsys.readouterr().err.split())
        assert name in err and says in err, err
        for advice in ("weights_only", "trusted source", "safe_globals", "file an issue"):
            assert advice not in err, (name, err)
        if name != "code.pt":
            assert "could run code" not in err, err
    assert not (tmp_path / "run").exists()


def _hand_made_run(run_dir: Path) -> Path:
    """A run directory as train() writes it, without training: config.json and a checkpoint."""
    config = A3CConfig.from_flat(**TINY)
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps({"a3c": config.to_dict()}))
    save_checkpoint(run_dir / "checkpoint.pt", model=network_for(config).state_dict(), step=0)
    return run_dir


@pytest.mark.parametrize("text, says", [
    ('{"a3c": ', "Expecting value"), ("[1]", "is not a JSON object"), ('{"x": 1}', "has no 'a3c' settings"),
    ('{"a3c": {"foo": 1}}', "unknown A3C settings ['foo']"), ('{"a3c": {"seed": -1}}', "seed must be"),
])
def test_a_broken_config_json_is_named_by_every_reader(tmp_path, capsys, text, says):
    run_dir = _hand_made_run(tmp_path / "run")
    path = run_dir / "config.json"
    path.write_text(text)
    with pytest.raises(ValueError) as refused:
        resolve_config({}, run_dir, resume=True)
    assert str(path) in str(refused.value) and says in str(refused.value)
    with pytest.raises(ValueError, match=str(path)):
        train(A3CConfig.from_flat(**TINY), run_dir, resume=True, progress=False)
    for argv in (["evaluate", str(run_dir)], ["train", "--run-dir", str(run_dir), "--resume"],
                 ["train", "--run-dir", str(tmp_path / "new"), "--init", str(run_dir)]):
        assert main(argv) == 2, argv
        assert str(path) in capsys.readouterr().err, argv
    assert not (tmp_path / "new").exists()


def test_evaluate_names_a_file_that_is_not_in_a_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("rand.pt").write_bytes(np.random.default_rng(1).integers(0, 256, 100, dtype=np.uint8).tobytes())
    assert main(["evaluate", "rand.pt"]) == 2
    err = capsys.readouterr().err
    assert "rand.pt is a file outside a training run" in err and "expected a run directory" in err
    assert main(["evaluate", "missing"]) == 2
    assert "missing does not exist" in capsys.readouterr().err


def test_evaluate_checks_its_output_paths_before_evaluating(tmp_path, monkeypatch, capsys):
    run_dir = _hand_made_run(tmp_path / "run")

    def evaluated(*args, **kwargs):
        raise AssertionError("evaluated before checking the output path")
    monkeypatch.setattr("bimgame.cli.train.evaluate_network", evaluated)
    (tmp_path / "dir").mkdir()
    (tmp_path / "file").write_text("x")
    for argv, says in ((["--out", str(tmp_path / "dir")], "--out"), (["--gif", str(tmp_path / "dir")], "--gif"),
                       (["--out", str(tmp_path / "file" / "eval.json")], "is a file, not a directory"),
                       (["--task", "STG9"], "STG9")):
        assert main(["evaluate", str(run_dir), *argv]) == 2, argv
        assert says in capsys.readouterr().err, argv


# ---------------------------------------------------------------------------- integer options
def _exit_code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as stop:  # argparse
        return int(stop.code)


@pytest.mark.parametrize("argv, says", [
    (["train", "--run-dir", "R", "--obs", "state", "--seed", str(2**64)], "--seed"),
    (["train", "--run-dir", "R", "--obs", "state", "--steps", "1e30"], "at most 1e12"),
    (["train", "--run-dir", "R", "--obs", "state", "--steps", "1e400"], "at most 1e12"),
    (["train", "--run-dir", "R", "--obs", "state", "--checkpoint-every", "1e13"], "at most 1e12"),
    (["train", "--run-dir", "R", "--obs", "state", "--hidden", "100000"],
     "NetworkSettings.hidden must be at most 4096"),
    (["train", "--run-dir", "R", "--obs", "state", "--workers", "100000"], "ScheduleSettings.workers must be at most"),
    (["train", "--run-dir", "R", "--obs", "state", "--eval-episodes", "1000000"], "--eval-episodes"),
    (["evaluate", "R", "--seed", "-1"], "--seed"),
    (["evaluate", "R", "--seed", str(2**64)], "--seed"),
    (["evaluate", "R", "--episodes", "1000000"], "--episodes"),
    (["pretrain", "--data", "D", "--out", "R", "--seed", str(2**64)], "--seed"),
    (["pretrain", "--data", "D", "--out", "R", "--eval-episodes", "1000000"], "--eval-episodes"),
    (["dagger", "--run-dir", "R", "--seed", str(2**64)], "--seed"),
    (["dagger", "--run-dir", "R", "--episodes-per-iteration", "100000"], "--episodes-per-iteration"),
    (["dagger", "--run-dir", "R", "--hidden", "100000"], "hidden must be at most 4096"),
])
def test_integer_options_that_would_fail_later_are_refused_by_name_up_front(argv, says, tmp_path, monkeypatch,
                                                                             capsys):
    monkeypatch.chdir(tmp_path)

    def started(*args, **kwargs):
        raise AssertionError(f"{argv[0]} started instead of refusing the value")
    for name in ("bimgame.cli.train.train", "bimgame.cli.train.evaluate_network", "bimgame.cli.learn.pretrain",
                 "bimgame.cli.learn.dagger"):
        monkeypatch.setattr(name, started)
    assert _exit_code(argv) == 2
    assert says in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_settings_classes_bound_steps_and_seeds():
    with pytest.raises(ValueError, match=r"ScheduleSettings.steps must be at most 1,000,000,000,000"):
        A3CConfig.from_flat(steps=10**30)
    with pytest.raises(ValueError, match=r"A3CConfig.seed must be an integer from 0 to 4294967295"):
        A3CConfig.from_flat(seed=2**64)
    assert A3CConfig.from_flat(steps=10**12, seed=2**32 - 1).schedule.steps == 10**12
