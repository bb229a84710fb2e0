"""The labyrinth's scoring protocol (bimgame.experiments.labyrinth_protocol): fixed starts and
deterministic numbers, the built-in policies (noop, random, the MPC expert), progress reached read
from the return, a tiny trained PPO run scored through ``bimgame score``, and refusals that name the
problem."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from bimgame.cli.main import main
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.experiments.labyrinth_protocol import (
    CYBERRUNNER_RECORD_S,
    ENDINGS,
    HUMAN_RECORD_S,
    LABYRINTH_PROTOCOL_SEED,
    SCORE_THREADS,
    protocol_starts,
    score_labyrinth,
    start_progress,
    summarise_labyrinth,
)
from bimgame.experiments import labyrinth_protocol
from bimgame.learn.actor import EvalResult, evaluate_network
from bimgame.learn.runs import torch_threads

#: A tiny PPO run on the easy layout (as tests/learn/test_labyrinth_training.py trains them).
TINY_PPO = ["--obs", "state", "--action-type", "continuous", "--steps", "256", "--hidden", "16", "--features", "16",
            "--envs-per-worker", "4", "--n-steps", "32", "--eval-every", "0", "--eval-episodes", "2",
            "--max-episode-steps", "100", "--no-progress"]


@pytest.fixture(scope="module")
def easy_run(tmp_path_factory):
    """A PPO run trained for 256 steps on LABYRINTH-EASY from state, continuous actions."""
    run = tmp_path_factory.mktemp("labyrinth") / "ppo-easy"
    assert main(["train", "--algo", "ppo", "--task", "LABYRINTH-EASY", "--run-dir", str(run), *TINY_PPO]) == 0
    return run


def _without_seconds(summary):
    return {k: v for k, v in summary.items() if k != "seconds"}


def test_the_same_seed_gives_the_same_result_and_noop_and_random_do_not_solve_the_hard_layout():
    first = score_labyrinth("random", "labyrinth-hard", episodes=6, progress=False)
    again = score_labyrinth("random", "LABYRINTH-HARD", episodes=6, progress=False)
    assert _without_seconds(first) == _without_seconds(again)
    assert first["protocol_seed"] == LABYRINTH_PROTOCOL_SEED and first["task"] == "LABYRINTH-HARD"
    assert first["time_limit_steps"] == 3000 and first["control_hz"] == 55 and first["mode"] is None
    assert first["success_rate"] <= 1 / 6  # random tilting rarely reaches the goal (0 of 6 here)
    ended_by = first["ended_by"]
    assert ended_by["fall"] == ended_by["hole"] + ended_by["off_path"] >= 1
    assert sum(ended_by[how] for how in ENDINGS) == 6 and ended_by == {how: first["ended"].count(how)
                                                                        for how in ENDINGS} | {"fall": ended_by["fall"]}
    other = score_labyrinth("random", "LABYRINTH-HARD", episodes=6, seed=7, progress=False)
    assert other["returns"] != first["returns"]  # other starts, other draws
    # noop: the board stays flat and the marble at its start until the time limit.
    noop = score_labyrinth("noop", "LABYRINTH-HARD", episodes=3, progress=False)
    assert noop["success_rate"] == 0.0 and noop["success_rate_ci"] == [0.0, 0.0]
    assert noop["lengths"] == [3000] * 3 and noop["ended_by"] == {"goal": 0, "hole": 0, "off_path": 0, "time": 3, "fall": 0}
    assert noop["ended"] == ["time"] * 3
    starts = start_progress("LABYRINTH-HARD", [LABYRINTH_PROTOCOL_SEED + i for i in range(3)])
    length = LabyrinthEnv("hard").path.length
    np.testing.assert_allclose(np.multiply(noop["progress_fractions"], length), starts, atol=1e-4)
    assert noop["completion_time_s"] == {"best": None, "q25": None, "median": None, "q75": None}
    assert noop["best_over_cyberrunner"] is None
    assert noop["references"]["cyberrunner_s"] == CYBERRUNNER_RECORD_S == 14.48 and HUMAN_RECORD_S == 15.41


def test_progress_reached_is_the_envs_progress_after_the_last_step_that_did_not_fail():
    """Random episodes played here (random tilt rates held for 20 steps), their info's progress kept:
    the summary's progress, read from the return, is the same, for falls (the progress before the
    failing step) and for time-outs; a fall is a hole or the path left as the env's info says."""
    env = LabyrinthEnv("hard")
    seeds, limit = [3, 4, 5, 6, 7, 8], 400
    result, expected, endings = EvalResult([], [], []), [], []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        _, info = env.reset(seed=seed)
        total, length, kept = 0.0, limit, info["progress_fraction"]
        for step in range(1, limit + 1):
            if step % 20 == 1:
                action = rng.uniform(-1, 1, 2).astype(np.float32)
            _, reward, terminated, _, info = env.step(action)
            total += reward
            if terminated:
                length = step
                break
            kept = info["progress_fraction"]
        result.successes.append(False)
        result.lengths.append(length)
        result.returns.append(total)
        result.holes.append(bool(info["over_hole"]))
        expected.append(kept)
        endings.append("time" if length == limit else "hole" if info["over_hole"] else "off_path")
        assert length == limit or info["over_hole"] or info["off_path"]  # a fall is one or the other
    summary = summarise_labyrinth(result, "LABYRINTH-HARD", seeds, time_limit=limit)
    assert summary["ended"] == endings and set(endings) == {"time", "hole", "off_path"}  # every kind of end
    assert summary["ended_by"] == {"goal": 0, "hole": 3, "off_path": 1, "time": 2, "fall": 4}
    # A result that does not tell holes from the path (a hand-made one) says "fall".
    unknown = summarise_labyrinth(dataclasses.replace(result, holes=[]), "LABYRINTH-HARD", seeds, time_limit=limit)
    assert unknown["ended"] == ["fall" if e in ("hole", "off_path") else e for e in endings]
    np.testing.assert_allclose(summary["progress_fractions"], expected, atol=1e-9)
    assert summary["mean_progress_fraction"] == pytest.approx(np.mean(expected))
    # An episode that ends where it started, its rewards' rounding summed below zero, reached 0 exactly.
    start = summarise_labyrinth(EvalResult([False], [limit], [0.0]), "LABYRINTH-HARD", seeds[:1], time_limit=limit)
    still = -start["progress_fractions"][0] * env.path.length * env.progress_scale - 1e-18
    assert summarise_labyrinth(EvalResult([False], [limit], [still]), "LABYRINTH-HARD", seeds[:1], time_limit=limit)[
        "progress_fractions"
    ] == [0.0]


def test_the_expert_solves_the_easy_layout():
    """One episode (≈ 470 decisions of ≈ 70 ms: ≈ 30 s on a loaded 2-core machine)."""
    summary = score_labyrinth("expert", "LABYRINTH-EASY", episodes=1, progress=False)
    assert summary["successes"] == [True] and summary["ended_by"] == {"goal": 1, "hole": 0, "off_path": 0, "time": 0, "fall": 0}
    times = summary["completion_time_s"]
    assert 5.0 < times["best"] == times["median"] < 15.0 and times["best"] == summary["lengths"][0] / 55
    assert summary["mean_progress_fraction"] > 0.98
    assert summary["best_over_cyberrunner"] is None  # the references are the hard layout's


def test_a_model_based_law_scores_through_the_command_line_as_its_agent_plays(tmp_path, capsys):
    from bimgame.learn.model_based import MarbleLaw, Transitions
    from bimgame.learn.model_based.agent import ModelBasedAgent, play_episode
    from bimgame.learn.model_based.transitions import explore

    env = LabyrinthEnv("easy")
    transitions = Transitions()
    explore(env, 2000, np.random.default_rng(0), transitions)
    law = MarbleLaw.fit(transitions, env.board)
    path = law.save(tmp_path / "law.json")
    out = tmp_path / "score.json"
    assert main(["score", str(path), "--task", "labyrinth-easy", "--episodes", "1", "--out", str(out), "--no-progress"]) == 0
    result = json.loads(out.read_text())
    assert (result["obs"], result["action_type"], result["mode"]) == ("state", "continuous", None)
    assert result["successes"] == [True]  # 2,000 random steps are enough on easy
    start = protocol_starts(1)[0]
    agent = ModelBasedAgent.for_env(env, law, rng=np.random.default_rng([start, 1]))
    played = play_episode(env, agent, seed=start, max_steps=3000)
    assert (played["steps"], played["return"]) == (result["lengths"][0], pytest.approx(result["returns"][0]))
    env.close()
    (tmp_path / "other.json").write_text("{}")
    assert main(["score", str(tmp_path / "other.json"), "--task", "labyrinth-easy", "--no-progress"]) != 0
    assert "not a marble law" in capsys.readouterr().err


def test_a_tiny_ppo_run_scores_through_the_command_line(easy_run, tmp_path, capsys):
    out = tmp_path / "score.json"
    figure = tmp_path / "ends.png"
    argv = ["score", str(easy_run / "checkpoint.pt"), "--task", "labyrinth-easy", "--episodes", "2", "--out",
            str(out), "--figure", str(figure), "--no-progress"]
    assert main(argv) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "CyberRunner" in printed and "mean progress reached" in printed  # the table, its line below
    result = json.loads(out.read_text())
    assert result["policy"] == str(easy_run / "checkpoint.pt") and result["task"] == "LABYRINTH-EASY"
    assert (result["mode"], result["obs"], result["action_type"], result["step"]) == ("greedy", "state", "continuous",
                                                                                     256)
    assert result["episodes"] == 2 and len(result["lengths"]) == 2 and 0.0 <= result["success_rate"] <= 1.0
    assert all(0 < n <= 3000 for n in result["lengths"])  # the protocol's limit, not the run's 100 steps
    assert 0.0 <= result["mean_progress_fraction"] <= 1.0 and result["median_over_human"] is None
    assert set(result["ended"]) <= set(ENDINGS) and "in a hole" in printed and "off the path" in printed


def test_refusals_name_the_problem(easy_run, tmp_path, capsys):
    # A run is scored on the task it was trained on.
    assert main(["score", str(easy_run), "--task", "LABYRINTH-HARD", "--episodes", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "is a run trained on LABYRINTH-EASY, not LABYRINTH-HARD" in err and "--task LABYRINTH-EASY" in err
    assert main(["score", str(easy_run), "--task", "STG1", "--episodes", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "is a run on LABYRINTH-EASY (the labyrinth), but --task STG1 is the circular maze's" in err
    assert main(["score", str(easy_run), "--task", "LABYRINTH-EASY", "--obs", "pixels", "--no-progress"]) == 2
    assert "trained on state observations, not pixels; score it with --obs state" in capsys.readouterr().err
    # --figure is the labyrinth's; a bad path is refused before any episode is played.
    assert main(["score", "random", "--task", "STG1", "--figure", str(tmp_path / "f.png"), "--no-progress"]) == 2
    assert "--figure draws where the labyrinth's episodes ended; --task STG1 is the circular maze's" in (
        capsys.readouterr().err)
    assert main(["score", "random", "--task", "LABYRINTH-EASY", "--figure", str(tmp_path), "--no-progress"]) == 2
    assert f"--figure {tmp_path} is a directory" in capsys.readouterr().err
    # What the labyrinth's protocol does not play, each with the allowed policies.
    (tmp_path / "model.zip").write_bytes(b"")
    for policy, why in (
        ("geodesic", "follows the circular maze's channels"),
        (str(tmp_path / "model.zip"), "Stable-Baselines3 models are scored on the circular maze only"),
        ("os:getcwd", "module:callable policies are scored on the circular maze only"),
        (str(tmp_path / "missing"), "no such built-in policy, file or directory"),
    ):
        with pytest.raises(ValueError, match=f"{why}.*; allowed: random, noop, expert, a bimgame run directory.*, or a marble law"):
            score_labyrinth(policy, "LABYRINTH-EASY", episodes=1, progress=False)
    with pytest.raises(ValueError, match=r"task STG1 is the circular maze's; .* LABYRINTH-EASY, LABYRINTH-MEDIUM"):
        score_labyrinth("random", "stg1", episodes=1)
    with pytest.raises(ValueError, match="unknown task 'LABYRINTH_EASY'; allowed: FULL, STG1"):
        score_labyrinth("random", "LABYRINTH_EASY", episodes=1)
    with pytest.raises(ValueError, match=r"score_labyrinth\.episodes must be an integer >= 1, got 0"):
        score_labyrinth("random", "LABYRINTH-EASY", episodes=0)
    with pytest.raises(ValueError, match=r"score_labyrinth\.seed must be an integer from 0"):
        score_labyrinth("random", "LABYRINTH-EASY", episodes=1, seed=-1)


def test_a_network_is_scored_on_one_torch_thread_whatever_the_callers_setting(easy_run, monkeypatch):
    """Scores do not depend on the machine: the batched forward pass runs on SCORE_THREADS threads
    (its float sums, and so a chaotic marble's episodes, depend on the count), and the caller's
    setting is restored afterwards."""
    seen = []

    def recording(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return evaluate_network(*args, **kwargs)

    monkeypatch.setattr(labyrinth_protocol, "evaluate_network", recording)
    with torch_threads(2):
        score_labyrinth(easy_run, "LABYRINTH-EASY", episodes=1, progress=False)
        assert torch.get_num_threads() == 2
    assert seen == [SCORE_THREADS] == [1]



def test_the_off_path_rule_is_the_protocols_unless_asked_and_changes_how_episodes_end(easy_run, capsys, monkeypatch):
    """The same random tilting on the easy layout: the tolerance rule ends the first protocol episode off
    the path at step 929; CyberRunner's free box lets the marble roll on over open floor to the time
    limit. The rule is in the summary; a network's envs get it; the maze's protocol refuses the flag."""
    tolerance = score_labyrinth("random", "LABYRINTH-EASY", episodes=1, progress=False)
    box = score_labyrinth("random", "LABYRINTH-EASY", episodes=1, progress=False, off_path_rule="cyberrunner")
    assert (tolerance["off_path_rule"], tolerance["ended"], tolerance["lengths"]) == ("tolerance", ["off_path"], [929])
    assert (box["off_path_rule"], box["ended"], box["lengths"]) == ("cyberrunner", ["time"], [3000])
    seen = []

    def recording(*args, **kwargs):
        seen.append(kwargs["mazes"])
        return evaluate_network(*args, **kwargs)

    monkeypatch.setattr(labyrinth_protocol, "evaluate_network", recording)
    assert main(["score", str(easy_run), "--task", "LABYRINTH-EASY", "--episodes", "1", "--off-path-rule",
                 "cyberrunner", "--no-progress"]) == 0
    assert seen == [{"off_path_rule": "cyberrunner"}] and "off-path rule cyberrunner" in capsys.readouterr().out
    with pytest.raises(ValueError, match=r"off_path_rule must be one of tolerance, cyberrunner, got 'box'"):
        score_labyrinth("random", "LABYRINTH-EASY", episodes=1, off_path_rule="box")
    assert main(["score", "random", "--task", "STG1", "--off-path-rule", "cyberrunner", "--no-progress"]) == 2
    assert "--off-path-rule cyberrunner: when the labyrinth's episodes end off its printed path; --task STG1" in (
        capsys.readouterr().err)
