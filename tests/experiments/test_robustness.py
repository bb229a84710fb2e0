"""Robustness measurements: the same boards for every policy, randomised conditions that change
what happens, and the table."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.envs.randomization import Randomization, randomization_preset
from bimgame.experiments.robustness import EXPERT, Measurement, measure, summary_rows, write_robustness
from bimgame.learn.a3c import A3CConfig, train


def test_the_expert_plans_with_the_nominal_model_and_meets_the_same_boards():
    nominal = measure(EXPERT, "STG1", "nominal", None, episodes=3, seed=0, group="expert")
    again = measure(EXPERT, "STG1", "nominal", None, episodes=3, seed=0, group="expert")
    assert nominal == again and nominal.success == 1.0
    # A board whose servos respond two steps late and a third weaker changes the expert's episodes.
    late = Randomization(latency=(2, 2), tilt_step=(0.67, 0.67))
    slowed = measure(EXPERT, "STG1", "late", late, episodes=3, seed=0, group="expert")
    assert slowed.mean_length != nominal.mean_length
    # On two worker processes the randomised board reaches every episode: the same numbers.
    assert measure(EXPERT, "STG1", "late", late, episodes=3, seed=0, group="expert", workers=2) == slowed


def test_a_run_is_measured_on_every_condition(tmp_path):
    config = A3CConfig.from_flat(task="STG1", obs="state", workers=1, envs_per_worker=2, n_steps=5, eval_every=0,
                                 hidden=8, features=8, steps=100, randomize="physics")
    train(config, tmp_path / "run", progress=False)
    nominal = measure(str(tmp_path / "run"), "STG1", "nominal", None, episodes=4, seed=1, group="A3C")
    physics = measure(str(tmp_path / "run"), "STG1", "physics", randomization_preset("physics"), episodes=4, seed=1,
                      group="A3C")
    assert nominal.episodes == physics.episodes == 4
    assert 0 <= nominal.success <= 1 and nominal.mean_length > 0


def test_summary_and_table_per_seed_with_an_interval(tmp_path):
    rows = [Measurement("A3C", f"r{k}", k, c, 10, s, 40.0 + k) for k, s in enumerate((0.5, 0.7, 0.9))
            for c in ("nominal", "physics")]
    summary = summary_rows(rows)
    entry = next(s for s in summary if s["condition"] == "physics")
    assert entry["success_per_source"] == [0.5, 0.7, 0.9] and entry["mean_success"] == pytest.approx(0.7)
    assert entry["ci_low"] <= 0.7 <= entry["ci_high"] and entry["ci_low"] >= 0.5
    _, md = write_robustness(rows, tmp_path)
    text = md.read_text()
    assert "| A3C | 50, 70, 90; **70%**" in text and "physics: mean length" in text


def test_training_randomisation_is_checked():
    with pytest.raises(ValueError, match="randomize must be None or one of"):
        A3CConfig.from_flat(obs="state", randomize="heavy")
    with pytest.raises(ValueError, match="camera, which needs obs='pixels'"):
        A3CConfig.from_flat(obs="state", randomize="camera")
    assert A3CConfig.from_flat(obs="pixels", randomize="all").randomize == "all"
    assert np.isfinite(randomization_preset("physics").marble_radius[1])
    with pytest.raises(ValueError, match="unknown randomisation 'x'; allowed: physics, camera, all"):
        randomization_preset("x")
