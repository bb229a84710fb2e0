"""The best iterate: how in-run evaluations are ranked and when one replaces the best (the runs'
bookkeeping of ``best.pt`` is tested with the DAgger and PPO runs)."""

from __future__ import annotations

from bimgame.learn.best_iterate import evaluation_rank, is_better


def _evaluation(greedy: float, sampled: float, greedy_return: float = 0.0, sampled_return: float = 0.0):
    return {"greedy_success_rate": greedy, "sampled_success_rate": sampled, "greedy_mean_return": greedy_return,
            "sampled_mean_return": sampled_return, "greedy_mean_length": 10.0, "sampled_mean_length": 10.0}


def test_success_over_both_modes_ranks_first_and_return_breaks_ties():
    assert evaluation_rank(_evaluation(0.5, 0.25, 1.0, 2.0)) == [0.75, 3.0]
    assert evaluation_rank(_evaluation(0.5, 0.5)) > evaluation_rank(_evaluation(0.25, 0.5, 9.0, 9.0))
    assert evaluation_rank(_evaluation(0.5, 0.5, 1.0, 1.0)) > evaluation_rank(_evaluation(0.5, 0.5, 1.0, 0.5))


def test_only_a_strictly_better_iteration_replaces_the_best():
    best = {"iteration": 2, "step": 100, "rank": evaluation_rank(_evaluation(0.5, 0.5, 1.0, 1.0))}
    assert is_better(_evaluation(0.0, 0.0), None)  # the first evaluated iteration is the best so far
    assert not is_better(_evaluation(0.5, 0.5, 1.0, 1.0), best)  # equal: the earlier one stays
    assert not is_better(_evaluation(0.25, 0.5, 5.0, 5.0), best)
    assert is_better(_evaluation(0.5, 0.5, 1.0, 1.5), best)
    assert is_better(_evaluation(0.75, 0.5), best)
