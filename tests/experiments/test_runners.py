"""Running pieces: the torch threads of the library calls; an unfinished run resumes wherever its
reproduction directory is now."""

from __future__ import annotations

import dataclasses
import json
import shutil

import torch

from bimgame.experiments.plan import load_status
from bimgame.experiments.reproduce import reproduce
from bimgame.experiments.runners import a3c_config_for
from bimgame.learn.a3c import train
from bimgame.learn.runs import torch_threads


def test_the_pieces_thread_count_is_set_and_restored():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with torch_threads(1):  # what the reproduction does around a piece
            with torch_threads() as count:  # what pretrain() and dagger() do inside
                assert count == 1 and torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_a_run_that_reads_the_dataset_resumes_after_its_reproduction_moved(tmp_path, tiny_budget):
    """A retried Ray task continues a shipped-back run in another node's directory; a person may move
    a reproduction. The run recorded its dataset's old absolute path and must still resume."""
    budget = dataclasses.replace(tiny_budget, algorithms=("pretrain+a3c+bc",), seeds=1)
    before, after = tmp_path / "before", tmp_path / "after"
    assert reproduce(before, budget, progress=False, stop_after=2).computed == ["data", "pretrain/STG1/policy-seed0"]
    partial = before / "runs/STG1/pretrain-a3c-bc/seed0"
    config = a3c_config_for(budget, "STG1", 0, "pretrain+a3c+bc", (before / "data").resolve())
    train(config.with_flat(steps=400), partial, progress=False,
          extra_config={"reward": {"value_reward": None, "geodesic_coef": None}})
    shutil.move(before, after)
    result = reproduce(after, budget, progress=False)
    assert result.complete and result.computed == ["runs/STG1/pretrain-a3c-bc/seed0"]
    entry = load_status(after)["pieces"]["runs/STG1/pretrain-a3c-bc/seed0"]
    assert entry["note"] == "resumed from its checkpoint", entry
    stored = json.loads((after / "runs/STG1/pretrain-a3c-bc/seed0/config.json").read_text())["a3c"]
    assert stored["expert_data"] == str((after / "data").resolve())
    assert json.loads((after / "runs/STG1/pretrain-a3c-bc/seed0/summary.json").read_text())["steps"] >= 2_000
