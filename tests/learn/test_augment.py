from __future__ import annotations

import numpy as np
import pytest
import torch

from bimgame.learn.augment import MAX_SHIFT, random_shift
from bimgame.sim.maze import MazeSpec
from bimgame.sim.render import MazeRenderer


def _frames(steps: int = 3, batch: int = 4) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    return torch.randint(0, 256, (steps, batch, 1, 84, 84), generator=g, dtype=torch.uint8)


def test_shift_is_one_offset_per_environment_for_the_whole_segment():
    frames = _frames()
    shifted = random_shift(frames, 2, torch.Generator().manual_seed(1))
    assert shifted.shape == frames.shape and shifted.dtype == torch.uint8
    for b in range(frames.shape[1]):
        # Find the offset from the first frame, then every later frame must have moved by the same.
        match = [(dy, dx) for dy in range(-2, 3) for dx in range(-2, 3)
                 if torch.equal(shifted[0, b, :, 8:-8, 8:-8], frames[0, b, :, 8 + dy:76 + dy, 8 + dx:76 + dx])]
        assert len(match) == 1
        dy, dx = match[0]
        for t in range(1, frames.shape[0]):
            assert torch.equal(shifted[t, b, :, 8:-8, 8:-8], frames[t, b, :, 8 + dy:76 + dy, 8 + dx:76 + dx])


def test_shift_draws_from_the_generator_only():
    frames = _frames()
    a = random_shift(frames, 2, torch.Generator().manual_seed(3))
    b = random_shift(frames, 2, torch.Generator().manual_seed(3))
    assert torch.equal(a, b)
    offsets = {tuple(random_shift(frames, 2, torch.Generator().manual_seed(s))[0, 0, 0, 40, 30:50].tolist())
               for s in range(10)}
    assert len(offsets) > 1  # different seeds shift differently
    assert random_shift(frames, 0, torch.Generator()) is frames


def test_replicate_padding_repeats_the_border():
    frames = torch.zeros(1, 1, 1, 84, 84, dtype=torch.uint8)
    frames[..., 0, :] = 200  # top row bright
    for seed in range(20):
        shifted = random_shift(frames, 2, torch.Generator().manual_seed(seed))
        # Rows above the original top row are copies of it, never black padding.
        top = shifted[0, 0, 0]
        assert int(top[0].min()) in (0, 200) and (top[0] == 200).all() or (top[0] == 0).all()
        assert set(torch.unique(shifted).tolist()) <= {0, 200}


def test_the_marble_stays_in_view_anywhere_on_the_board():
    """A marble at the rim, all round the board, is drawn whole after the largest shift: the pixels that differ from the empty maze (shifted the same) are as many as
    before."""
    spec = MazeSpec.merl()
    renderer = MazeRenderer(spec, 84)
    radius = spec.rim_radius - spec.marble_radius
    angles = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    xy = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=-1)[:, None, :]
    marble = torch.as_tensor(renderer.gray(xy))[None, :, None]  # (1, 16, 1, 84, 84)
    empty = torch.as_tensor(renderer.gray(np.zeros((0, 2))))[None, None, None].expand_as(marble).contiguous()
    for seed in range(5):
        shifted_marble = random_shift(marble, 2, torch.Generator().manual_seed(seed))
        shifted_empty = random_shift(empty, 2, torch.Generator().manual_seed(seed))
        before = (marble != empty).flatten(2).sum(-1)
        after = (shifted_marble != shifted_empty).flatten(2).sum(-1)
        assert torch.equal(before, after)
        assert (before > 0).all()


@pytest.mark.parametrize("pad", [-1, MAX_SHIFT + 1, 2.5, True])
def test_bad_shift_is_refused(pad):
    """Also 3 pixels and more: they would cut the marble at the rim (see the test above)."""
    with pytest.raises(ValueError, match="shift"):
        random_shift(_frames(), pad, torch.Generator())


def test_bad_shape_is_refused():
    with pytest.raises(ValueError, match=r"\(T, B, C, H, W\)"):
        random_shift(torch.zeros(4, 1, 84, 84, dtype=torch.uint8), 2, torch.Generator())
