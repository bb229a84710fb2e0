from __future__ import annotations

import numpy as np
import pytest

from bimgame.cli import main
from bimgame.curves import binned_by_start, plot_run, read_table
from bimgame.runs import CsvLog


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
