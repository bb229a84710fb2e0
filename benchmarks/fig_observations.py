"""The environments page's picture: what an agent sees. The circular maze from above and its 84×84
pixel observation (STG1), CyberRunner's labyrinth (easy) as the board and its pixel observation, and
the 64×64 crop around the marble of its ``cyberrunner`` observation, each after the same seeded reset
and 40 random actions.

Writes ``--out`` (default docs/environments/observations.png).

Usage: python benchmarks/fig_observations.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import bimgame  # noqa: F401  (registers the ids)
from bimgame.util.images import save_png, subplots

ROOT = Path(__file__).resolve().parents[1]


def _after_random_actions(env_id: str, steps: int = 40, **options) -> tuple[np.ndarray, object]:
    """The observation after a seeded reset and ``steps`` seeded random actions, and the env's render."""
    env = gym.make(env_id, render_mode="rgb_array", **options)
    obs, _ = env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(steps):
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            break
    frame = env.render()
    env.close()
    return obs, frame


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "environments" / "observations.png")
    args = parser.parse_args(argv)
    maze_pixels, maze_frame = _after_random_actions("BiMGame/STG1-v0", obs_mode="pixels")
    lab_pixels, lab_frame = _after_random_actions("BiMGame/Labyrinth-Easy-v0", obs_mode="pixels")
    lab_cr, _ = _after_random_actions("BiMGame/Labyrinth-Easy-v0", obs_mode="cyberrunner")
    crop = lab_cr["image"] if isinstance(lab_cr, dict) else lab_cr
    panels = [
        (maze_frame, "circular maze (render)"),
        (maze_pixels[0], "STG1 obs_mode='pixels' (84×84)"),
        (lab_frame, "labyrinth, easy (render)"),
        (lab_pixels[0], "labyrinth obs_mode='pixels'"),
        (np.squeeze(crop), "obs_mode='cyberrunner': 64×64 crop"),
    ]
    fig, axes = subplots(1, len(panels), figsize=(3 * len(panels), 3.2), layout="constrained")
    for axis, (image, title) in zip(axes, panels, strict=True):
        axis.imshow(image, cmap="gray" if np.ndim(image) == 2 else None, vmin=0, vmax=255)
        axis.set_title(title, fontsize=9)
        axis.set_axis_off()
    print(f"wrote {save_png(fig, args.out, dpi=100)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
