"""PPO's best iterate (``best.pt``): the weights of the best-ranked in-run evaluation, kept across a
resume, and re-evaluating them gives the numbers they were chosen on."""

from __future__ import annotations

import csv

import torch

from bimgame.learn.best_iterate import evaluation_rank, read_best
from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.common import run_evaluation
from bimgame.learn.ppo import PPOConfig, train_ppo

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=64, eval_episodes=2, log_every=64, max_episode_steps=40, lr=3e-3)


def _evaluations(run) -> list[dict[str, float]]:
    with open(run / "eval.csv", newline="") as handle:
        return [{key: float(value) for key, value in row.items()} for row in csv.DictReader(handle)]


def _best_row(rows: list[dict[str, float]]) -> dict[str, float]:
    """The first row of the highest rank (a later one replaces the best only when strictly better)."""
    best = rows[0]
    for row in rows[1:]:
        if evaluation_rank(row) > evaluation_rank(best):
            best = row
    return best


def test_best_pt_holds_the_weights_of_the_best_ranked_evaluation(tmp_path):
    config = PPOConfig.from_flat(TINY, steps=384)
    train_ppo(config, tmp_path / "run", progress=False)
    rows = _evaluations(tmp_path / "run")
    assert [int(row["step"]) for row in rows] == [64, 128, 192, 256, 320, 384, 384]  # the last: the final one
    best = _best_row(rows)
    record = read_best(tmp_path / "run" / "best.pt")
    assert record == {"step": int(best["step"]), "rank": evaluation_rank(best)}
    net = config.network.build_policy(config.seed)
    net.load_state_dict(load_checkpoint(tmp_path / "run" / "best.pt")["model"])
    again = run_evaluation(net, config)
    assert evaluation_rank(again) == evaluation_rank(best)  # the same episodes, the same numbers


def test_best_pt_differs_from_the_last_weights_when_an_earlier_evaluation_ranked_higher(tmp_path):
    """Whatever the run's course, best.pt is never ranked below the final evaluation, and when it is
    an earlier step its weights are not the last ones."""
    train_ppo(PPOConfig.from_flat(TINY, steps=384, seed=3), tmp_path / "run", progress=False)
    rows = _evaluations(tmp_path / "run")
    record = read_best(tmp_path / "run" / "best.pt")
    assert record is not None and record["rank"] >= evaluation_rank(rows[-1])
    best = load_checkpoint(tmp_path / "run" / "best.pt")["model"]
    last = load_checkpoint(tmp_path / "run" / "checkpoint.pt")["model"]
    same = all(torch.equal(best[key], last[key]) for key in last)
    assert same == (record["step"] == 384)


def test_a_resumed_run_keeps_the_best_and_ranks_new_evaluations_against_it(tmp_path):
    train_ppo(PPOConfig.from_flat(TINY, steps=192), tmp_path / "run", progress=False)
    first = read_best(tmp_path / "run" / "best.pt")
    train_ppo(PPOConfig.from_flat(TINY, steps=384), tmp_path / "run", resume=True, progress=False)
    rows = _evaluations(tmp_path / "run")
    record = read_best(tmp_path / "run" / "best.pt")
    assert record is not None and first is not None and record["rank"] >= first["rank"]
    assert record == {"step": int(_best_row(rows)["step"]), "rank": evaluation_rank(_best_row(rows))}


def test_a_run_without_in_run_evaluations_keeps_its_final_evaluation_as_the_best(tmp_path):
    train_ppo(PPOConfig.from_flat(TINY, steps=128, eval_every=0), tmp_path / "run", progress=False)
    rows = _evaluations(tmp_path / "run")
    assert len(rows) == 1 and read_best(tmp_path / "run" / "best.pt")["step"] == 128
