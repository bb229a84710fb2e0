"""What the privileged state vector holds, for the networks that learn from it: which of its values
one observed frame shows (the auxiliary frame head's targets).

The privileged state is a puzzle's state observation (:func:`~bimgame.envs.puzzles.state_obs_scale`
gives its divisors), and the two puzzles lay it out differently:

- ``maze`` (:class:`~bimgame.envs.observe.Observer`): per marble x, y, vx, vy, then the tilt about
  x and y, then each marble's channel (5·n + 2 values);
- ``labyrinth`` (:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv`'s ``obs_mode="state"``): x, y,
  vx, vy, the tilt about x and y, the progress along the path, then the 5 path points ahead relative
  to the marble (17 values).

Its length alone cannot tell them apart (17 is also the maze with three marbles), so a network
names its layout (``NetConfig.state_layout``).
"""

from __future__ import annotations

from bimgame.envs.labyrinth_cyberrunner import PATH_AHEAD
from bimgame.envs.puzzles import LABYRINTH, MAZE

__all__ = ["STATE_LAYOUTS", "frame_visible"]

#: The privileged state's layouts: the puzzles' (:attr:`~bimgame.envs.puzzles.Puzzle.family`).
STATE_LAYOUTS = (MAZE, LABYRINTH)
#: The labyrinth's state length: x, y, vx, vy, the tilt, the progress, the path points ahead.
_LABYRINTH_SIZE = 7 + 2 * PATH_AHEAD
#: The labyrinth's state values that are functions of the marble's position alone: x, y, the
#: progress and the coordinates of the path points ahead.
_LABYRINTH_POSITION = [0, 1, *range(6, _LABYRINTH_SIZE)]
#: The labyrinth's marble velocity (vx, vy): what two frames show besides the position.
_LABYRINTH_VELOCITY = [2, 3]


def frame_visible(privileged_size: int, state_layout: str = MAZE, frames: int = 1) -> list[int]:
    """Indices of the privileged state that the encoder's input shows. The maze: each marble's x, y
    and channel (not its velocity, nor the tilt: frames are drawn in the board's frame). The
    labyrinth: the marble's position and what follows from it (progress, path points ahead), and
    with two frames (``frames=2``, the labyrinth's ``motion``) its velocity too; never the tilt."""
    if state_layout not in STATE_LAYOUTS:
        raise ValueError(f"state_layout must be one of {STATE_LAYOUTS}, got {state_layout!r}")
    if state_layout == LABYRINTH:
        if privileged_size != _LABYRINTH_SIZE:
            raise ValueError(
                f"the labyrinth's privileged state has {_LABYRINTH_SIZE} values, got privileged_size {privileged_size}"
            )
        return sorted(_LABYRINTH_POSITION + (_LABYRINTH_VELOCITY if frames > 1 else []))
    n = (privileged_size - 2) // 5
    return [4 * i + k for i in range(n) for k in (0, 1)] + [4 * n + 2 + i for i in range(n)]
