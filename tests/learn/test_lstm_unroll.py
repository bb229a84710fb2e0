"""The fused LSTM unroll equals the loop of LSTM cell steps it replaces, forward and backward."""

from __future__ import annotations

import pytest
import torch

from bimgame.learn.lstm_unroll import lstm_unroll
from bimgame.learn.nets import LSTMState


@pytest.mark.parametrize("pattern", ["none", "first", "random", "all"])
def test_lstm_unroll_equals_the_cell_loop_forward_and_backward(pattern):
    """The fused unroll (one LSTM call per piece between episode starts) gives the loop's outputs,
    final state and gradients, wherever the starts fall."""
    g = torch.Generator().manual_seed(3)
    steps, batch = 9, 4
    starts = {
        "none": torch.zeros(steps, batch, dtype=torch.bool),
        "first": torch.zeros(steps, batch, dtype=torch.bool).index_fill_(0, torch.tensor([0]), True),
        "random": torch.rand(steps, batch, generator=g) < 0.25,
        "all": torch.ones(steps, batch, dtype=torch.bool),
    }[pattern]
    results = []
    for fused in (True, False):
        cell = torch.nn.LSTMCell(6, 5)
        cell.load_state_dict(
            {k: torch.randn(v.shape, generator=torch.Generator().manual_seed(7)) for k, v in cell.state_dict().items()}
        )
        x = torch.randn(steps, batch, 6, generator=torch.Generator().manual_seed(1)).requires_grad_()
        state = LSTMState(
            torch.randn(batch, 5, generator=torch.Generator().manual_seed(2)),
            torch.randn(batch, 5, generator=torch.Generator().manual_seed(4)),
        )
        if fused:
            hidden, (h, c) = lstm_unroll(cell, x, state, starts)
            final = LSTMState(h, c)
        else:
            h, c, outputs = state.h, state.c, []
            for t in range(steps):
                keep = (~starts[t]).float().unsqueeze(-1)
                h, c = cell(x[t], (h * keep, c * keep))
                outputs.append(h)
            hidden, final = torch.stack(outputs), LSTMState(h, c)
        (hidden.square().sum() + final.c.sum()).backward()
        results.append((hidden, final, x.grad, cell.weight_hh.grad))
    (hidden_f, final_f, dx_f, dw_f), (hidden_l, final_l, dx_l, dw_l) = results
    torch.testing.assert_close(hidden_f, hidden_l, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(final_f.c, final_l.c, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(dx_f, dx_l, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(dw_f, dw_l, rtol=1e-5, atol=1e-5)
