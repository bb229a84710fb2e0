from __future__ import annotations

import json

import numpy as np
import pytest
from support.logs import running_log

from bimgame.cli.main import main
from bimgame.learn import curves
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.curves import binned_by_start, plot_run, read_table
from bimgame.learn.metric_logs import CsvLog


def test_binned_by_start_groups_by_the_start_step():
    episodes = {"start_step": np.array([0.0, 0, 10, 10, 10]), "success": np.array([1.0, 0, 1, 1, 0])}
    steps, means = binned_by_start(episodes, "success", bins=2)
    np.testing.assert_allclose(means, [0.5, 2 / 3])
    assert steps[0] < steps[1]


def test_plot_run_from_logs(tmp_path, capsys):
    with pytest.raises(ValueError, match="no finished training episodes"):
        plot_run(tmp_path)
    log = CsvLog(tmp_path / "episodes.csv", ["step", "start_step", "worker", "return", "length", "success"])
    rng = np.random.default_rng(0)
    for i in range(200):
        log.write({"step": 100 * i + 50, "start_step": 100 * i, "worker": 0, "return": 1.0, "length": 50,
                   "success": int(rng.random() < i / 200)})
    log.close()
    assert read_table(tmp_path / "episodes.csv")["start_step"][-1] == 19_900
    path = plot_run(tmp_path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["curves", str(tmp_path), "--out", str(tmp_path / "c.png")]) == 0
    assert (tmp_path / "c.png").is_file()


def test_booleans_as_the_a3c_logs_write_them_and_a_comparison_figure(tmp_path):
    runs = []
    for index, rate in enumerate((0.2, 0.8)):
        run = tmp_path / f"run{index}"
        run.mkdir()
        log = CsvLog(run / "episodes.csv", ["step", "start_step", "worker", "return", "length", "success"])
        for i in range(100):
            log.write({"step": 10 * i + 5, "start_step": 10 * i, "worker": 0, "return": 0.0, "length": 5,
                       "success": bool(i % 10 < 10 * rate)})
        log.close()
        runs.append(run)
    table = read_table(runs[1] / "episodes.csv")
    assert table["success"].mean() == pytest.approx(0.8)  # "True"/"False" cells read as 1/0
    out = tmp_path / "compare.png"
    assert main(["compare", f"low={runs[0]}", f"high={runs[1]}", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(SystemExit):
        main(["compare", "nolabel", "--out", str(out)])


# ------------------------------------------------------------- episodes still running at the end
def test_bins_whose_episodes_may_still_be_running_are_left_out():
    # Success does not depend on the start step: every bin should show ≈ 50%. The episodes that
    # started in the last 200 × 64 steps and fail (run to the time limit) had not ended when the
    # log stopped, so the last bins held only short successes: 100% (the old, biased curve).
    episodes = running_log(400_000)
    span = 200 * 64
    assert np.max(episodes["step"] - episodes["start_step"]) == span
    edges = np.linspace(0, 400_000, 41)
    start = episodes["start_step"]
    old_last = episodes["success"][start >= edges[-2]].mean()
    assert old_last > 0.95  # what the last bin held
    steps, means = binned_by_start(episodes, "success", edges=edges)
    assert np.all(np.abs(means - 0.5) < 0.15), means
    assert steps.max() + 5_000 <= episodes["step"].max() - span + 1  # only bins whose episodes all ended
    assert len(steps) == 38  # the two bins after 387k are left out, no more
    # What is kept is what the whole log shows: the same run logged until every episode had ended.
    whole = running_log(400_000 + span)
    np.testing.assert_allclose(means, binned_by_start(whole, "success", edges=edges)[1][:38])
    # Bins chosen by the function span the complete part of the run only.
    steps, means = binned_by_start(episodes, "success", bins=40)
    assert len(steps) == 40 and np.all(np.abs(means - 0.5) < 0.2), means
    assert steps.max() < episodes["step"].max() - span


def test_binned_means_drops_bins_past_the_complete_part():
    edges = np.array([0.0, 100.0, 200.0, 300.0])
    means, counts = curves.binned_means(np.array([0, 50, 150, 250]), np.array([0, 1, 1, 1]), edges, until=200.0)
    np.testing.assert_allclose(means[:2], [0.5, 1.0])
    assert np.isnan(means[2]) and counts.tolist() == [2, 1, 0]


def test_episode_span_from_the_run_settings_and_the_log():
    episodes = {"step": np.array([500.0, 900.0]), "start_step": np.array([0.0, 100.0])}
    assert curves.episode_span(episodes) == 800  # the longest logged
    a3c = {"task": "STG1", "max_episode_steps": None, "workers": 2, "envs_per_worker": 16, "n_steps": 20}
    assert curves.episode_span(episodes, {"a3c": a3c}) == (300 + 20) * 2 * 16  # STG1's time limit 300
    short = {**a3c, "max_episode_steps": 5, "n_steps": 5}
    assert curves.episode_span(episodes, {"a3c": short}) == 800  # the log's is longer than (5 + 5) × 32
    assert curves.complete_until(episodes, 800) == 101
    # A finished run ran on after its last logged end step; an unfinished one may be resumed earlier.
    assert curves.finished_at({"stopped": "finished", "steps": 1_000}) == 1_000
    assert curves.finished_at({"stopped": "interrupted", "steps": 1_000}) is None
    assert curves.complete_until(episodes, 800, finished_at=1_000) == 201
    assert curves.complete_until({"start_step": np.array([0.0])}, 800) == np.inf  # no end steps: nothing to cut


def test_plot_run_and_compare_draw_runs_with_an_unfinished_tail(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    episodes = running_log(200_000)
    with (run / "episodes.csv").open("w") as handle:
        handle.write("step,start_step,worker,return,length,success\n")
        for row in zip(*(episodes[k] for k in ("step", "start_step", "worker", "return", "length", "success"))):
            handle.write(",".join(str(int(v)) for v in row) + "\n")
    assert plot_run(run).is_file()
    out = tmp_path / "compare.png"
    assert main(["compare", f"a={run}", f"b={run}", "--out", str(out), "--max-step", "100k"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_curves_and_compare_of_a_real_tiny_run(tmp_path):
    # Four envs, a 50-step time limit: an episode spans at most (50 + 10) × 4 steps of the x-axis.
    config = A3CConfig.from_flat(task="STG1", obs="state", workers=1, envs_per_worker=4, n_steps=10, eval_every=0,
                                 hidden=16, features=16, log_every=500, max_episode_steps=50, steps=2_000)
    train(config, tmp_path / "run", progress=False)
    episodes = read_table(tmp_path / "run" / "episodes.csv")
    span = curves.episode_span(episodes, json.loads((tmp_path / "run" / "config.json").read_text()))
    assert span >= (50 + 10) * 4
    until = curves.run_until(tmp_path / "run", episodes)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["steps"] >= 2_000 and until == summary["steps"] - span + 1  # the run's last step − the span
    steps, _ = binned_by_start(episodes, "success", until=until)
    assert len(steps) and steps.max() < until
    assert main(["curves", str(tmp_path / "run"), "--out", str(tmp_path / "c.png")]) == 0
    assert main(["compare", f"tiny={tmp_path / 'run'}", "--out", str(tmp_path / "d.png")]) == 0
    assert (tmp_path / "c.png").is_file() and (tmp_path / "d.png").is_file()
