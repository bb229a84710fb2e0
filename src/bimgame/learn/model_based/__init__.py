"""A model-based learner for CyberRunner's labyrinth: plan through a marble model fitted from the
learner's own experience.

CyberRunner (Bi & D'Andrea, 2023) learned the real board with a world model (DreamerV3). This
learner asks the simpler question of what a learned model buys on the simulated board: it explores
with random tilts, fits the marble's one-step law from the transitions it saw
(:class:`~bimgame.learn.model_based.marble_law.MarbleLaw`, least squares), and plans every action with
the labyrinth's MPC (:class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC`) through that model instead
of the simulator (:class:`~bimgame.learn.model_based.marble_model.MarbleModel`); every episode it plays
adds its transitions and the law is fitted again (:func:`~bimgame.learn.model_based.training.learn_model_based`).

What is learned and what is given. Learned: how the marble's velocity and the board's tilt change
in one action step, from the tilt, the velocity and the commanded tilt rate — the physics the
simulator hides (the marble rolls, the servos lag). Given, as to the expert: the layout — walls,
holes, the path and its reward — which the model uses to stop the marble at walls
(:class:`~bimgame.learn.model_based.contacts.WallContacts`) and the planner to score sequences.
CyberRunner's reward needs the path too; its model learned the walls and holes from pixels.

Why a linear law and not a network (one-off measurements on random play, not a benchmark): away
from the walls the marble's step is linear in tilt, velocity and command (least squares on the 1,239
free transitions of 40k random steps on the hard board: R² 0.994 for both velocity components), and
a few hundred such transitions pin its 54 numbers. A 2×256 network given the wall distances around
the marble as well, fitted on 40–160k transitions of the same play, predicted the velocity change
with R² 0.6–0.85 only (93% of random play leans on a wall, and a contact is discontinuous), and the
planner through it, refitted on its own episodes as here, reached 22–24% of the hard path at best
(9% with this module's wall contacts added after its step). Contacts are therefore geometry here
(:mod:`~bimgame.learn.model_based.contacts`), not learned.
"""

from bimgame.learn.model_based.agent import ModelBasedAgent
from bimgame.learn.model_based.contacts import WallContacts
from bimgame.learn.model_based.marble_law import MarbleLaw
from bimgame.learn.model_based.marble_model import MarbleModel
from bimgame.learn.model_based.training import ModelBasedRun, ModelBasedSettings, learn_model_based
from bimgame.learn.model_based.transitions import Transitions

__all__ = [
    "ModelBasedAgent",
    "WallContacts",
    "MarbleLaw",
    "MarbleModel",
    "ModelBasedSettings",
    "ModelBasedRun",
    "learn_model_based",
    "Transitions",
]
