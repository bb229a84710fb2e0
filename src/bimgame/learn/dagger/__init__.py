"""DAgger with the MPC expert (Ross, Gordon & Bagnell, AISTATS 2011), the paper's baseline: the
learner's rollouts labelled by the expert, aggregated, and the learner retrained on all of them.

The package's modules, one job each: :mod:`~bimgame.learn.dagger.settings` (:class:`DAggerConfig`),
:mod:`~bimgame.learn.dagger.rollouts` (the expert-labelled rollouts of one iteration),
:mod:`~bimgame.learn.dagger.starts` (on the labyrinth, rollouts started in the expert's states),
:mod:`~bimgame.learn.dagger.teacher` (on the labyrinth, a trained policy labelling instead of the MPC expert),
:mod:`~bimgame.learn.dagger.best` (the best iterate kept in ``best.pt``) and
:mod:`~bimgame.learn.dagger.training` (:func:`dagger`: the iterations in a resumable run directory; the
algorithm in detail). The public API is importable from the package.
"""

from bimgame.learn.dagger.rollouts import collect_episodes
from bimgame.learn.dagger.settings import DAggerConfig, resolve_dagger_config
from bimgame.learn.dagger.training import DAggerResult, dagger
from bimgame.learn.run_dir import BEST
from bimgame.learn.runs import KIND_DAGGER

__all__ = ["resolve_dagger_config", "DAggerConfig", "DAggerResult", "dagger", "collect_episodes", "KIND_DAGGER", "BEST"]
