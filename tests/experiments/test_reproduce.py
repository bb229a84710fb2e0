"""Running a reproduction: a failing piece, the command line's checks, and a tiny reproduction run
end to end through the real pieces — stopped part-way, with one A3C run left unfinished, then
continued — whose report must agree with the runs' own logs."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from bimgame.cli.main import main
from bimgame.experiments.budgets import budget_named
from bimgame.experiments.plan import load_plan, load_status
from bimgame.experiments.report import build_report
from bimgame.experiments.reproduce import reproduce
from bimgame.experiments.runners import a3c_config_for
from bimgame.expert.datasets import iterate_sequences
from bimgame.learn.a3c import train
from bimgame.learn.curves import read_table


def test_cli_rejects_bad_flags(tmp_path, capsys):
    for argv, message in ((["--tasks", "STG9"], "invalid choice: 'STG9'"),
                          (["--budget", "huge"], "invalid choice: 'huge'"),
                          (["--seeds", "0"], "expected a positive integer, got '0'"),
                          (["--algorithms", "sac"], "invalid choice: 'sac'")):
        with pytest.raises(SystemExit) as exit_info:
            main(["reproduce", "--out", str(tmp_path / "r"), *argv])
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["report", str(tmp_path), "--threshold", "1.5"])
    assert "expected a number in (0, 1], got '1.5'" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 2
    assert "not a reproduction directory" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_cli_refuses_a_ray_address_without_the_ray_backend(tmp_path, capsys):
    assert main(["reproduce", "--out", str(tmp_path / "r"), "--address", "auto"]) == 2
    assert "--ray-address is only used with --backend ray" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    with pytest.raises(ValueError, match="unknown backend 'dask'; allowed: local, ray"):
        reproduce(tmp_path / "r", budget_named("quick"), backend="dask")
    with pytest.raises(SystemExit):
        main(["reproduce", "--out", str(tmp_path / "r"), "--backend", "dask"])
    assert "invalid choice: 'dask'" in capsys.readouterr().err


def test_a_failing_piece_is_recorded_and_its_dependents_skipped(tmp_path, tiny_budget):
    budget = dataclasses.replace(tiny_budget, algorithms=("pretrain+a3c",), seeds=1)
    (tmp_path / "data").write_text("not a directory")  # the dataset cannot be generated here
    result = reproduce(tmp_path, budget, progress=False)
    assert list(result.failed) == ["data"] and "NotADirectoryError" in result.failed["data"]
    assert result.skipped == ["pretrain/STG1/policy-seed0", "runs/STG1/pretrain-a3c/seed0"]
    assert not result.complete and result.computed == []
    status = load_status(tmp_path)["pieces"]
    assert status["data"]["state"] == "failed" and "NotADirectoryError" in status["data"]["traceback"]
    assert status["runs/STG1/pretrain-a3c/seed0"]["state"] == "skipped"
    # The same directory cannot be continued with settings that change what its pieces compute.
    with pytest.raises(ValueError, match=r"other settings \(a3c\.steps: .*dagger\.episodes"):
        reproduce(tmp_path, budget.replace(a3c={"steps": {"STG1": 3_000}}, dagger={"episodes": 3}), progress=False)


# --------------------------------------------------------------------------- end to end
def _mtimes(root: Path, pieces: list[str]) -> dict[str, float]:
    """Modification times of every file of the given pieces' directories."""
    return {str(path): path.stat().st_mtime_ns for piece in pieces for path in (root / piece).rglob("*")
            if path.is_file()}


def test_tiny_reproduction_stops_resumes_and_reports_what_the_runs_logged(tmp_path, capsys, tiny_budget):
    out = tmp_path / "repro"
    first = reproduce(out, tiny_budget, progress=False, stop_after=3)
    assert first.computed == ["data", "pretrain/STG1/policy-seed0", "pretrain/STG1/value-seed0"]
    assert len(first.remaining) == 8 and not first.complete
    status = load_status(out)["pieces"]
    assert status["runs/STG1/a3c/seed0"]["state"] == "pending" and status["data"]["state"] == "done"
    finished_before = _mtimes(out, first.computed)

    # An A3C run interrupted after a checkpoint: a run of the piece's settings with fewer steps.
    partial = out / "runs/STG1/a3c/seed1"
    train(a3c_config_for(tiny_budget, "STG1", 1).with_flat(steps=400), partial, progress=False,
          extra_config={"reward": {"value_reward": None, "geodesic_coef": None}})
    partial_config = (partial / "config.json").stat().st_mtime_ns
    partial_rows = read_table(partial / "episodes.csv")

    second = reproduce(out, tiny_budget, progress=False)
    assert second.complete and second.reused == first.computed
    assert len(second.computed) == 8 and "runs/STG1/a3c/seed1" in second.computed
    assert _mtimes(out, first.computed) == finished_before  # nothing finished was computed again
    status = load_status(out)["pieces"]
    assert all(entry["state"] == "done" and entry["computed"] == 1 for entry in status.values())
    assert status["runs/STG1/a3c/seed1"]["note"] == "resumed from its checkpoint"
    assert (partial / "config.json").stat().st_mtime_ns == partial_config
    resumed_rows = read_table(partial / "episodes.csv")
    assert len(resumed_rows["start_step"]) > len(partial_rows.get("start_step", ()))
    assert resumed_rows["start_step"].max() >= 400  # episodes of the continued run
    assert json.loads((partial / "summary.json").read_text())["steps"] >= 2_000
    shaped = json.loads((out / "runs/STG1/pretrain-a3c-value/seed0/config.json").read_text())
    assert shaped["init"].endswith("pretrain/STG1/policy-seed0")
    assert shaped["reward"]["value_reward"].endswith("pretrain/STG1/value-seed0")

    paths = build_report(out, resamples=300)
    for name in ("fig_curves_STG1.png", "fig_expert_lengths.png", "table_speedup.md", "table_speedup.json",
                 "report.md"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    _check_table_against_logs(out, json.loads(paths.table_json.read_text()))
    report = paths.report.read_text()
    assert "| Pre-training speeds learning up 2–3× |" in report and "not measured in this budget" in report
    assert "| **total** |" in report and "Budget **tiny**" in report

    # The command line continues the directory with its own budget: nothing left, report rebuilt.
    before = _mtimes(out, [p.path for p in load_plan(out)[1]])
    capsys.readouterr()
    assert main(["reproduce", "--out", str(out), "--no-progress"]) == 0
    assert "0 pieces computed, 11 reused" in " ".join(capsys.readouterr().err.split())
    assert _mtimes(out, [p.path for p in load_plan(out)[1]]) == before
    (out / "report.md").unlink()
    assert main(["report", str(out), "--resamples", "200"]) == 0
    assert (out / "report.md").is_file()
    capsys.readouterr()
    assert main(["reproduce", "--out", str(out), "--dry-run"]) == 0
    assert "the 0 not finished yet" in " ".join(capsys.readouterr().err.split())  # rich wraps lines
    assert main(["reproduce", "--out", str(out), "--budget", "quick", "--dry-run"]) == 2
    assert "holds a reproduction with other settings" in capsys.readouterr().err


def _check_table_against_logs(out: Path, numbers: dict) -> None:
    """Recompute, from each run's CSV logs with plain numpy, what the table says about it."""
    entry = numbers["tasks"]["STG1"]
    threshold, width = entry["threshold"], entry["curve_bin_steps"]
    assert entry["expert_success"] == pytest.approx(np.mean(_expert_successes(out)))
    assert threshold == pytest.approx(0.8 * entry["expert_success"])
    for algorithm in ("a3c", "pretrain+a3c+value"):
        runs = entry["algorithms"][algorithm]["runs"]
        assert [r["seed"] for r in runs] == [0, 1]
        for run in runs:
            episodes = read_table(out / run["dir"] / "episodes.csv")
            summary = json.loads((out / run["dir"] / "summary.json").read_text())
            # Only episodes known to have ended count: those that started at least one episode
            # span (time limit 300 + one segment of 20, times 4 envs) before the run's last step.
            span = max((300 + 20) * 4, (episodes["step"] - episodes["start_step"]).max())
            until = max(summary["steps"], episodes["step"].max()) - span + 1
            bins = np.minimum((episodes["start_step"] // width).astype(int), round(2_000 / width) - 1)
            crossed = [b for b in sorted(set(bins))
                       if (b + 1) * width <= until and (bins == b).sum() >= entry["min_episodes_per_bin"]
                       and episodes["success"][bins == b].mean() >= threshold]
            if crossed:
                assert run["steps_to_threshold"] == pytest.approx((crossed[0] + 1) * width)
            else:
                assert run["steps_to_threshold"] is None
                assert run["censored_at"] == pytest.approx(min(2_000, max(0.0, until // width * width)))
            end = min(until, 2_000)
            late = (episodes["start_step"] >= end - 0.1 * 2_000) & (episodes["start_step"] < end)
            if late.any():
                assert run["final_success_training"] == pytest.approx(episodes["success"][late].mean())
            else:
                assert run["final_success_training"] is None
            assert run["final_greedy_success"] == pytest.approx(summary["final_eval"]["greedy_success_rate"])
    for run in entry["algorithms"]["dagger"]["runs"]:
        table = read_table(out / run["dir"] / "dagger.csv")
        assert run["final_greedy_success"] == pytest.approx(table["greedy_success_rate"][-1])
        assert run["env_steps"] == table["step"][-1]
        reached = table["greedy_success_rate"] >= threshold
        assert (run["steps_to_threshold"] is not None) == bool(reached.any())
    pretraining = numbers["pretraining"]["STG1"]
    for seed in (0, 1):
        summary = json.loads((out / f"pretrain/STG1/policy-seed{seed}/summary.json").read_text())
        assert pretraining["val_accuracy"][seed] == pytest.approx(summary["val_accuracy"])


def _expert_successes(out: Path) -> list[bool]:
    return [s.terminated and len(s) <= 300 for s in iterate_sequences(out / "data", obs="state")]


def test_tiny_reproduction_beyond_the_paper_gives_the_runs_their_settings_and_the_dataset(tmp_path, tiny_budget):
    """Real runs of the two methods that read the expert's dataset: their pieces need it, they record
    the reproduction's DIR/data and the paper preset, and the report gets its section and figure."""
    budget = tiny_budget.replace(algorithms=("pretrain+a3c+bc", "pretrain+a3c+demo"), seeds=1,
                                 a3c={"eval_every": 1_000})
    result = reproduce(tmp_path, budget, progress=False)
    assert result.complete and result.computed == [
        "data", "pretrain/STG1/policy-seed0", "runs/STG1/pretrain-a3c-bc/seed0", "runs/STG1/pretrain-a3c-demo/seed0"]
    for algorithm, changed in (("pretrain-a3c-bc", {"bc_coef": 0.1, "bc_decay_steps": 2_000}),
                               ("pretrain-a3c-demo", {"start_curriculum": "demo"})):
        stored = json.loads((tmp_path / "runs/STG1" / algorithm / "seed0/config.json").read_text())
        settings = stored["a3c"]
        assert settings["expert_data"] == str(tmp_path.resolve() / "data") and settings["finetune"] == "paper"
        assert {k: settings[k] for k in changed} == changed
        assert stored["init"].endswith("pretrain/STG1/policy-seed0")
        assert read_table(tmp_path / "runs/STG1" / algorithm / "seed0/eval.csv")["step"][0] == 0
    paths = build_report(tmp_path, resamples=100)
    assert (tmp_path / "fig_eval_STG1.png").is_file()
    numbers = json.loads(paths.table_json.read_text())["beyond"]["tasks"]["STG1"]["algorithms"]
    assert all(numbers[a]["seeds_finished"] == 1 for a in budget.algorithms)
    assert "## Beyond the paper" in paths.report.read_text()
