"""Rebuilding a whole report from saved results without training: hand-made runs with known
crossings, and the report's refusals of bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from support.logs import write_csv

from bimgame.experiments.budgets import A3CBudget, Budget, DaggerBudget, DatasetBudget
from bimgame.experiments.plan import write_plan
from bimgame.experiments.report import build_report
from bimgame.experiments.statistics import CURVE_BINS
from bimgame.expert.datasets import generate_dataset


@pytest.fixture
def fake_run(training_episodes):
    """``fake_run(path, steps, curve)`` writes the logs of a finished A3C run of ``steps`` whose
    training episodes succeed at the rates of ``curve`` ((start, end, rate) ranges)."""

    def write(path: Path, steps: int, curve: list[tuple[int, int, float]]) -> None:
        episodes = training_episodes(curve, steps // CURVE_BINS)
        _write_run(path, steps, {**episodes, "step": episodes["start_step"] + 50, "length": episodes["length"]})

    return write


def _write_run(path: Path, steps: int, episodes: dict, config: dict | None = None) -> None:
    """The logs of a finished A3C run of ``steps`` with the given episodes.csv columns (and config.json)."""
    rows = [{"step": int(e), "start_step": int(s), "worker": 0, "return": float(r), "length": int(n),
             "success": bool(r)} for e, s, r, n in zip(episodes["step"], episodes["start_step"],
                                                        episodes["success"], episodes["length"])]
    write_csv(path / "episodes.csv", rows)
    write_csv(path / "eval.csv", [{"step": steps, "greedy_success_rate": 0.9, "greedy_mean_length": 40,
                                    "greedy_mean_return": 0.9, "sampled_success_rate": 0.8,
                                    "sampled_mean_length": 45, "sampled_mean_return": 0.8}])
    (path / "summary.json").write_text(json.dumps({"steps": steps, "stopped": "finished",
                                                   "final_eval": {"greedy_success_rate": 0.9}}))
    if config is not None:
        (path / "config.json").write_text(json.dumps(config))


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory) -> Path:
    """Four STG1 expert episodes (a few seconds of planning)."""
    return generate_dataset(tmp_path_factory.mktemp("report") / "data", "STG1", 4, seed=0, workers=1, progress=False)


def test_report_is_rebuilt_from_saved_results(tmp_path, tiny_dataset, fake_run):
    steps = 100_000
    budget = Budget(name="hand-made", tasks=("STG1",), seeds=2, a3c=A3CBudget(steps={"STG1": steps}),
                    dataset=DatasetBudget(task="STG1", episodes=4, workers=1), dagger=DaggerBudget(iterations=3))
    pieces = write_plan(tmp_path, budget)
    shutil.copytree(tiny_dataset, tmp_path / "data")
    # Known crossings (bins of 2.5k steps): A3C at 60k and 70k, pre-trained at 20k and 35k, value
    # reward never (censored at 100k), pre-trained + value at 30k and 35k.
    plain = {0: 60_000, 1: 70_000}
    pre = {0: 20_000, 1: 35_000}
    prevalue = {0: 30_000, 1: 35_000}
    for seed in range(2):
        root = tmp_path / "runs" / "STG1"
        fake_run(root / "a3c" / f"seed{seed}", steps, [(0, plain[seed] - 2_500, 0.3),
                                                       (plain[seed] - 2_500, steps, 0.9)])
        fake_run(root / "pretrain-a3c" / f"seed{seed}", steps, [(0, pre[seed] - 2_500, 0.5),
                                                                (pre[seed] - 2_500, steps, 0.95)])
        fake_run(root / "a3c-value" / f"seed{seed}", steps, [(0, steps, 0.4)])
        fake_run(root / "pretrain-a3c-value" / f"seed{seed}", steps,
                 [(0, prevalue[seed] - 2_500, 0.5), (prevalue[seed] - 2_500, steps, 0.95)])
        dagger = root / "dagger" / f"seed{seed}"
        write_csv(dagger / "dagger.csv", [{"step": s, "iteration": i, "greedy_success_rate": g,
                                            "greedy_mean_length": 100, "sampled_success_rate": g}
                                           for i, (s, g) in enumerate([(200, 0.1), (900, 0.5), (1800, 0.6)])])
        (dagger / "dagger_state.json").write_text(json.dumps({"iteration": 3, "env_steps": 1800}))
        for kind, summary in (("policy", {"val_accuracy": 0.25 + 0.02 * seed, "val_value_rmse": 0.3,
                                          "policy_eval": {"greedy_success_rate": 0.4, "sampled_success_rate": 0.3}}),
                              ("value", {"val_accuracy": float("nan"), "val_value_rmse": 0.2 + seed / 10})):
            out = tmp_path / "pretrain" / "STG1" / f"{kind}-seed{seed}"
            out.mkdir(parents=True)
            (out / "summary.json").write_text(json.dumps(summary))
            (out / "checkpoint.pt").write_bytes(b"weights")
    assert len(pieces) == 1 + 2 * 2 + 2 * 5

    paths = build_report(tmp_path, resamples=500, seed=3)
    for name in ("fig_curves_STG1.png", "fig_expert_lengths.png", "table_speedup.md", "table_speedup.json",
                 "report.md"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert (tmp_path / "fig_curves_STG1.png").read_bytes()[:4] == b"\x89PNG"
    numbers = json.loads(paths.table_json.read_text())
    stg1 = numbers["tasks"]["STG1"]
    assert stg1["curve_bin_steps"] == steps / CURVE_BINS
    assert stg1["expert_success"] == 1.0  # the seeded expert solves all four episodes
    assert stg1["threshold"] == pytest.approx(0.8)
    algorithms = stg1["algorithms"]
    assert [r["steps_to_threshold"] for r in algorithms["a3c"]["runs"]] == [60_000, 70_000]
    assert [r["steps_to_threshold"] for r in algorithms["pretrain+a3c"]["runs"]] == [20_000, 35_000]
    assert [r["censored_at"] for r in algorithms["a3c+value"]["runs"]] == [steps, steps]
    assert algorithms["a3c+value"]["reached"] == 0
    assert algorithms["pretrain+a3c"]["speedup_vs_a3c"]["estimate"] == pytest.approx(65_000 / 27_500)
    assert algorithms["pretrain+a3c"]["speedup_vs_a3c"]["bound"] == "exact"
    assert algorithms["a3c+value"]["speedup_vs_a3c"]["bound"] == "not reached"
    assert algorithms["pretrain+a3c+value"]["speedup_vs_pretrain+a3c"]["estimate"] == pytest.approx(27_500 / 32_500)
    assert algorithms["dagger"]["final_greedy_success"] == pytest.approx(0.6)
    assert numbers["pretraining"]["STG1"]["val_accuracy_mean"] == pytest.approx(0.26)

    table = paths.table_md.read_text()
    assert "| pre-train + A3C | 2/2 | 2/2 | 20k, 35k | 27.5k | 2.36× [" in table
    assert "| A3C + value reward | 2/2 | 0/2 | > 100k, > 100k | not reached | not reached |" in table
    report = paths.report.read_text()
    assert "Pre-training speeds learning up 2–3×" in report and "STG1: 2.36×" in report
    assert "26.0% (seeds: 25.0%, 27.0%" in report
    assert "STG3 and STG4 are not learned by any method | not measured in this budget" in report
    assert "STG2 and FULL not measured in this budget" in report
    assert "![STG1 learning curves](fig_curves_STG1.png)" in report
    assert "![expert trajectory lengths](fig_expert_lengths.png)" in report
    # The paper's grid gets no section beyond it, nor its figures or numbers.
    assert "Beyond the paper" not in report and numbers["beyond"] is None
    assert not list(tmp_path.glob("fig_eval_*.png"))

    # The same results and seed give the same numbers; another threshold gives other crossings.
    again = build_report(tmp_path, resamples=500, seed=3)
    assert json.loads(again.table_json.read_text()) == numbers
    lower = json.loads(build_report(tmp_path, threshold_fraction=0.5, resamples=500).table_json.read_text())
    assert lower["tasks"]["STG1"]["algorithms"]["a3c+value"]["reached"] == 0  # 0.4 < 0.5 still
    assert lower["tasks"]["STG1"]["algorithms"]["pretrain+a3c"]["runs"][0]["steps_to_threshold"] == 2_500

    # A piece whose outputs vanish drops out of the report, which says it is incomplete.
    (tmp_path / "runs" / "STG1" / "a3c" / "seed1" / "summary.json").unlink()
    numbers = json.loads(build_report(tmp_path, resamples=200).table_json.read_text())
    assert numbers["tasks"]["STG1"]["algorithms"]["a3c"]["seeds_finished"] == 1
    assert "**Incomplete:** 1 pieces are not finished" in (tmp_path / "report.md").read_text()


def test_report_counts_only_training_episodes_known_to_have_ended(tmp_path, tiny_dataset, running_log):
    # One A3C run of 400k steps on 64 envs, 50% success throughout; when its log stopped, the
    # failing (time-limited) episodes of its last 12.8k steps were still running. Before, the last
    # bin showed 100% and "reached" the 80% threshold at 400k, and the final training success
    # (episodes started after 360k) read 57%.
    steps = 400_000
    budget = Budget(name="hand-made", tasks=("STG1",), algorithms=("a3c",), seeds=1,
                    a3c=A3CBudget(steps={"STG1": steps}, workers=1, envs_per_worker=64),
                    dataset=DatasetBudget(task="STG1", episodes=4, workers=1))
    write_plan(tmp_path, budget)
    shutil.copytree(tiny_dataset, tmp_path / "data")
    a3c = {"task": "STG1", "max_episode_steps": 200, "workers": 1, "envs_per_worker": 64, "n_steps": 20}
    _write_run(tmp_path / "runs" / "STG1" / "a3c" / "seed0", steps, running_log(steps), {"a3c": a3c})
    paths = build_report(tmp_path, resamples=100)
    entry = json.loads(paths.table_json.read_text())["tasks"]["STG1"]
    assert entry["threshold"] == pytest.approx(0.8)
    run = entry["algorithms"]["a3c"]["runs"][0]
    # Complete up to 400k − (200 + 20) × 64 steps: censored at the last whole 10k bin before it.
    assert run["steps_to_threshold"] is None and run["censored_at"] == 380_000
    # The episodes that started in the 40k steps before that, all of them (the same run logged
    # for longer holds no more).
    until = steps - (200 + 20) * 64 + 1
    whole = running_log(steps + 200 * 64)
    late = (whole["start_step"] >= until - 40_000) & (whole["start_step"] < until)
    assert run["final_success_training"] == pytest.approx(whole["success"][late].mean())
    assert "| A3C | 1/1 | 0/1 | > 380k | not reached |" in paths.table_md.read_text()


def test_report_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="not a reproduction directory .no readable plan.json"):
        build_report(tmp_path)
    write_plan(tmp_path, Budget().replace(a3c={"steps": {"STG1": 1000}}))
    with pytest.raises(ValueError, match=r"threshold_fraction must be in \(0, 1\], got 1.5"):
        build_report(tmp_path, threshold_fraction=1.5)
    with pytest.raises(ValueError, match="resamples must be an integer >= 1, got 0"):
        build_report(tmp_path, resamples=0)
