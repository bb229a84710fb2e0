"""Image augmentation for learning from pixels: random shifts (DrQ, Kostrikov et al. 2020).

Each environment's frames are padded by ``pad`` pixels on every side, repeating the border pixels
(replicate padding, so no artificial black frame appears), and cropped back to their size at an
offset drawn uniformly from ``[0, 2·pad]`` in each axis. One offset per environment holds for the
whole segment, so motion between consecutive frames stays what the camera saw — the LSTM infers
the marble's velocity from it. The shift is at most :data:`MAX_SHIFT` = 2 pixels: the rendered
board leaves 2 pixels between the marble at the rim and the frame's edge (measured on the 84×84
frame), so a marble anywhere on the board stays whole in the image; DrQ's usual 4 pixels would cut
a third of it off at the rim (tested).

Written here rather than taken from a library: the torchvision / kornia random crops draw from the
global generator and shift each frame independently; this one draws from a passed generator and
keeps a shift fixed across a recurrent segment.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from bimgame.util.settings import is_integer

__all__ = ["MAX_SHIFT", "random_shift"]

#: The largest shift allowed: the margin between the marble at the rim and the 84×84 frame's edge.
MAX_SHIFT = 2


def random_shift(frames: torch.Tensor, pad: int, generator: torch.Generator) -> torch.Tensor:
    """``frames`` (T, B, C, H, W), each environment b shifted by one offset drawn from ``generator``
    of up to ``pad`` pixels in each direction, edges replicated. Same dtype and shape; ``pad`` 0
    returns ``frames`` itself."""
    if not (is_integer(pad) and 0 <= pad <= MAX_SHIFT):
        raise ValueError(f"the shift must be an integer in 0..{MAX_SHIFT} pixels, got {pad!r}")
    if frames.dim() != 5:
        raise ValueError(f"random_shift needs frames of shape (T, B, C, H, W), got {tuple(frames.shape)}")
    if pad == 0:
        return frames
    steps, batch, channels, height, width = frames.shape
    # (B, T·C, H, W): one padding call for every frame of an environment.
    stacked = frames.permute(1, 0, 2, 3, 4).reshape(batch, steps * channels, height, width).float()
    padded = F.pad(stacked, (pad, pad, pad, pad), mode="replicate")
    offsets = torch.randint(0, 2 * pad + 1, (batch, 2), generator=generator)
    out = torch.stack([padded[b, :, dy : dy + height, dx : dx + width] for b, (dy, dx) in enumerate(offsets.tolist())])
    out = out.reshape(batch, steps, channels, height, width).permute(1, 0, 2, 3, 4)
    return out.to(frames.dtype).contiguous()
