from __future__ import annotations

import numpy as np
import pytest

from bimgame.cli.main import main
from bimgame.learn.curves import binned_by_start, plot_run, read_table
from bimgame.learn.runs import CsvLog


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
