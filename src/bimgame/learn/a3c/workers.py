"""What runs inside an A3C run's spawned processes: the worker (act for a segment, apply its
gradient to the shared weights) and the evaluator (greedy and sampled episodes of the shared
weights every ``eval_every`` steps). :func:`bimgame.learn.a3c.train` starts them; they report to
the parent through its message queue. The entry points are module-level functions, so that the
``spawn`` start method can pickle them by name."""

from __future__ import annotations

import dataclasses
import signal
import time
import traceback
from typing import Any

import numpy as np
import torch

from bimgame.envs.puzzles import PuzzleSpec, PuzzleVectorEnv
from bimgame.envs.randomization import RANDOMIZATION_PRESETS
from bimgame.learn.a3c.settings import A3CConfig
from bimgame.learn.a3c.update import apply_update, make_optimizer, network_for
from bimgame.learn.actor import RecurrentActor
from bimgame.learn.augment import random_shift
from bimgame.learn.common import run_evaluation
from bimgame.learn.curricula import start_curriculum
from bimgame.learn.finetune import DemoWindows, EntropyTarget, LossWeights, RunningScale, Teacher, loss_weights
from bimgame.learn.loss_terms import BehaviourCloning, LossTerm, TeacherKL
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rewards import EnvWrapper, shaped_env
from bimgame.learn.rollout import FinishedEpisode, NonFiniteReward, RolloutCollector, Segment, training_env
from bimgame.sim.maze import MazeSpec
from bimgame.util.processes import exit_when_parent_dies


def _worker_seeds(config: A3CConfig, rank: int, start_step: int) -> tuple[int, int]:
    """(env seed, torch seed) of a worker; a resumed run (start_step > 0) draws fresh episodes."""
    sequence = np.random.SeedSequence([config.seed, rank, start_step])
    env_seed, torch_seed = sequence.generate_state(2)
    return int(env_seed), int(torch_seed)


def _make_env(config: A3CConfig, num_envs: int, **kwargs: Any) -> PuzzleVectorEnv:
    randomize = None if config.randomize is None else RANDOMIZATION_PRESETS[config.randomize]
    return training_env(
        num_envs,
        task=config.task,
        obs=config.network.obs,
        time_limit=config.time_limit,
        privileged=config.network.privileged,
        randomize=randomize,
        **config.maze_options,
        **kwargs,
    )


@dataclasses.dataclass(frozen=True)
class RunShared:
    """What every process of an A3C run receives when it is spawned: the settings, the shared weights
    and optimiser statistics, and the run's step counter, stop event and message queue."""

    config: A3CConfig
    shared: RecurrentActorCritic
    optimizer_state: list[dict]
    counter: Any
    """multiprocessing Value("q"): environment steps of all workers together."""
    stop: Any
    """multiprocessing Event: set when the run stops."""
    messages: Any
    """multiprocessing Queue of (kind, rank, payload) reports to the parent."""
    env_wrapper: EnvWrapper | None
    start_step: int
    """The step the session starts from (0, or a resumed checkpoint's)."""
    teacher_weights: dict[str, torch.Tensor] | None = None
    """π^s for the KL term (see :mod:`bimgame.learn.finetune`)."""


def _worker(rank: int, run: RunShared) -> None:
    """One A3C worker process: act, compute the segment's gradient, apply it to the shared weights."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    exit_when_parent_dies()  # a parent killed with kill -9 leaves no worker behind
    torch.set_num_threads(1)
    try:
        _worker_loop(rank, run)
    except Exception:  # noqa: BLE001 - any failure goes to the parent as a traceback, which stops the run
        run.messages.put(("error", rank, traceback.format_exc()))
    finally:
        run.messages.put(("exit", rank, None))


def _worker_loop(rank: int, run: RunShared) -> None:
    """Collect a segment, compute its loss, apply the gradient to the shared weights, report; until
    the run's steps are done or it is told to stop."""
    config, counter, messages = run.config, run.counter, run.messages
    env_seed, torch_seed = _worker_seeds(config, rank, run.start_step)
    collector, local = _collector(rank, run, torch_seed)
    collector.reset(env_seed, counter.value)
    learner = _WorkerUpdate(config, rank, run, local, collector.base_env.maze)
    report = _UpdateReport(config.schedule.log_every)
    while not run.stop.is_set() and counter.value < config.schedule.steps:
        local.load_state_dict(run.shared.state_dict())
        step_at_start = counter.value
        try:
            segment = collector.collect(config.optimization.n_steps, step_at_start)
        except NonFiniteReward as error:
            nan = {"step": error.step, "what": "reward from the env", "rewards": error.rewards.tolist()}
            messages.put(("nan", rank, nan))
            return
        parts = learner.update(segment, step_at_start)
        if not parts.pop("applied"):
            grad_norm = parts.pop("grad_norm")
            messages.put(("nan", rank, {"step": int(counter.value), "what": "loss", "grad_norm": grad_norm, **parts}))
            return
        with counter.get_lock():
            counter.value += config.steps_per_update
        report.add(parts, config.steps_per_update)
        if report.due:
            status = collector.curriculum_status()
            payload = report.flush(int(counter.value), learner.weights, status, learner.entropy_coef)
            messages.put(("update", rank, payload))


class _WorkerUpdate:
    """A worker's update of the shared weights from one segment, with the run's optional parts chosen
    once at the start: its loss terms (KL to π^s, behaviour cloning), advantage scaling, adapting
    entropy coefficient and frame augmentation."""

    def __init__(self, config: A3CConfig, rank: int, run: RunShared, local: RecurrentActorCritic, maze: PuzzleSpec):
        settings, finetuning = config.optimization, config.finetuning
        self.config, self.local = config, local
        self.optimizer = _shared_optimizer(config, run)
        self.shared_params = list(run.shared.parameters())
        self.terms = _loss_terms(config, rank, run, maze)
        self.advantage_scale = RunningScale() if finetuning is not None and finetuning.advantage_norm else None
        self.entropy_target = (
            None
            if settings.entropy_target is None
            else EntropyTarget(settings.entropy_target, settings.entropy_target_steps, settings.entropy_coef)
        )
        self.adapted_entropy_coef: float | None = None
        self.augment_generator = torch.Generator().manual_seed(_stream_seed(config, rank, run.start_step, 2))
        self.weights = LossWeights()

    @property
    def entropy_coef(self) -> float:
        """The entropy coefficient of the latest update."""
        fixed = self.config.optimization.entropy_coef
        return fixed if self.adapted_entropy_coef is None else self.adapted_entropy_coef

    def update(self, segment: Segment, step: int) -> dict[str, Any]:
        """Apply one segment's gradient (see :func:`~bimgame.learn.a3c.update.apply_update`); its losses,
        with ``applied`` False when the loss or gradient was not finite."""
        self.weights = weights = loss_weights(self.config.finetuning, step)
        for term in self.terms:
            term.prepare(segment, weights)
        self.terms = [term for term in self.terms if not term.finished]
        shift = self.config.optimization.augment_shift
        if shift:  # after the terms, which follow the frames as the learner acted on them
            segment = segment.replace(obs=random_shift(segment.obs, shift, self.augment_generator))
        parts = apply_update(
            self.local,
            self.shared_params,
            self.optimizer,
            segment,
            self.config,
            weights,
            terms=self.terms,
            advantage_scale=self.advantage_scale,
            entropy_coef=self.adapted_entropy_coef,
        )
        parts.pop("loss")
        if self.entropy_target is not None and parts["applied"]:
            self.adapted_entropy_coef = self.entropy_target.update(parts["entropy"], step)
        return parts


def _stream_seed(config: A3CConfig, rank: int, start_step: int, stream: int) -> int:
    """The seed of a worker's ``stream``-th generator (1: expert windows, 2: augmentation)."""
    return int(np.random.SeedSequence([config.seed, rank, start_step, stream]).generate_state(1)[0])


def _collector(rank: int, run: RunShared, torch_seed: int) -> tuple[RolloutCollector, RecurrentActorCritic]:
    """A worker's rollout collector (its envs, start curriculum and sampling actor) and the local
    network it acts with, which each update loads the shared weights into."""
    config = run.config
    curriculum = start_curriculum(config.task, config.curriculum, config.expert_data)
    base_env = _make_env(config, config.schedule.envs_per_worker, start_sampler=curriculum)
    env = shaped_env(base_env, run.env_wrapper)
    local = network_for(config, base_env.maze)
    actor = RecurrentActor(local, config.schedule.envs_per_worker, generator=torch.Generator().manual_seed(torch_seed))

    def book(episode: FinishedEpisode) -> None:
        run.messages.put(("episode", rank, episode.row()))

    collector = RolloutCollector(
        env,
        base_env,
        actor,
        gamma=config.optimization.gamma,
        tilt_input=config.network.tilt_input,
        privileged=config.network.privileged,
        curriculum=curriculum,
        on_episode=book,
        global_step=lambda: run.counter.value,
    )
    return collector, local


def _shared_optimizer(config: A3CConfig, run: RunShared) -> torch.optim.Optimizer:
    """An optimiser of the shared weights whose statistics are the run's shared ones."""
    optimizer = make_optimizer(config, run.shared)
    # The shared statistics are listed in the optimiser's parameter order (see shared_optimizer_state).
    for param, state in zip(
        [p for group in optimizer.param_groups for p in group["params"]], run.optimizer_state, strict=True
    ):
        optimizer.state[param] = state
    return optimizer


def _loss_terms(config: A3CConfig, rank: int, run: RunShared, maze: PuzzleSpec) -> list[LossTerm]:
    """The run's optional loss terms, in the order they are added to the loss: the KL to π^s when the
    run has a teacher, behaviour cloning when ``bc_coef`` > 0."""
    terms: list[LossTerm] = []
    finetuning, envs = config.finetuning, config.schedule.envs_per_worker
    if run.teacher_weights is not None:
        assert finetuning is not None  # a run has a teacher only for a KL term (kl_coef > 0)
        teacher_net = network_for(config, maze)
        teacher_net.load_state_dict(run.teacher_weights)
        teacher = Teacher(teacher_net, envs, finetuning.kl_temperature)
        terms.append(TeacherKL(teacher, finetuning.kl_decay_steps))
    if finetuning is not None and finetuning.bc_coef > 0:
        assert config.expert_data is not None  # A3CConfig refuses behaviour cloning without one
        assert isinstance(maze, MazeSpec)  # and expert data on the labyrinth
        gamma = config.optimization.gamma
        demos = DemoWindows.from_dataset(config.expert_data, config.task, config.network.obs, gamma, maze)
        rng = np.random.default_rng(np.random.SeedSequence([config.seed, rank, run.start_step, 1]))
        terms.append(BehaviourCloning(demos, envs, rng))
    return terms


#: Loss terms that only some runs have: logged as NaN (an empty cell) where a run has none.
_OPTIONAL_TERMS = ("kl", "bc", "aux_frame", "aux_memory")
#: The losses an update report averages.
_AVERAGED = ("policy_loss", "value_loss", "entropy", "kl", "bc", "aux_frame", "aux_memory", "grad_norm")


class _UpdateReport:
    """Averages a worker's update losses over ``every`` environment steps, for its ``update`` reports."""

    def __init__(self, every: int):
        self.every = every
        self._reset()

    def _reset(self) -> None:
        self.sums = dict.fromkeys(_AVERAGED, 0.0)
        self.updates = 0
        self.since = 0

    def add(self, parts: dict[str, float], steps: int) -> None:
        for key in _AVERAGED:
            self.sums[key] += parts.get(key, float("nan") if key in _OPTIONAL_TERMS else 0.0)
        self.updates += 1
        self.since += steps

    @property
    def due(self) -> bool:
        return self.since >= self.every

    def flush(
        self,
        step: int,
        weights: LossWeights,
        status: dict[str, float],
        entropy_coef: float,
    ) -> dict[str, Any]:
        """The report's payload; starts the next average."""
        payload = {
            "step": step,
            **{k: v / self.updates for k, v in self.sums.items()},
            "actor_weight": weights.actor,
            "kl_weight": weights.kl,
            "bc_weight": weights.bc,
            "entropy_coef": entropy_coef,
            **status,
        }
        self._reset()
        return payload


def _evaluator(
    config: A3CConfig,
    shared: RecurrentActorCritic,
    counter,
    stop,
    messages,
    start_step: int,
    initial_weights: dict[str, torch.Tensor],
) -> None:
    """Evaluator process: greedy and sampled episodes (same start positions every time) of the weights
    the session starts from, at its first step — step 0 of a fresh run (the initial random or
    pre-trained policy), the checkpoint's step of a resumed one, whose earlier rows from that step on
    were dropped — then every ``eval_every`` steps of the shared weights."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_when_parent_dies()
    torch.set_num_threads(1)
    try:
        local = network_for(config)
        # A copy of the weights taken before any worker started.
        local.load_state_dict(initial_weights)
        messages.put(("eval", -1, {"step": start_step, **run_evaluation(local, config)}))
        next_eval = (start_step // config.schedule.eval_every + 1) * config.schedule.eval_every
        while not stop.is_set():
            step = counter.value
            if step >= config.schedule.steps:
                break
            if step < next_eval:
                time.sleep(0.1)
                continue
            local.load_state_dict(shared.state_dict())
            messages.put(("eval", -1, {"step": int(step), **run_evaluation(local, config)}))
            next_eval = (step // config.schedule.eval_every + 1) * config.schedule.eval_every
    except Exception:  # noqa: BLE001 - any failure goes to the parent as a traceback, which stops the run
        messages.put(("error", -1, traceback.format_exc()))
    finally:
        messages.put(("exit", -1, None))
