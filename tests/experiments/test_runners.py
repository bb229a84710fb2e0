"""Running pieces: the torch threads of the library calls."""

from __future__ import annotations

import torch

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
