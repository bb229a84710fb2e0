"""The worker processes of a multi-process PPO run (``workers`` > 1) and the process group that joins
them to the run's own process (rank 0).

Why processes with averaged gradients (decentralised distributed PPO, Wijmans et al. 2020) rather
than one learner fed by environment processes: on a CPU machine both halves of PPO — stepping the
environments with the network acting, and the epochs of minibatch updates — are compute, and
synchronous PPO alternates them; with every rank doing both on its own share, every core works in
both phases. The ranks meet only to average each minibatch's gradient (one ``torch.distributed``
gloo all-reduce: PyTorch's own collective, nothing hand-written) and once per rollout, when each
worker sends rank 0 the episodes it finished (rank 0 logs them in rank order, so a run's logs do
not depend on timing).

Measured on a 2-core machine (STG1, state, 2,048-step rollouts): *slower* than one process — two
ranks of 8 environments made 1,500 steps/s where one process of 16 made 2,100. On this network the
cost is the number of small operations one after the other (an acting step, an LSTM step of a
minibatch), which a rank does as often as one process does; each minibatch's all-reduce then adds
10–16 ms. From pixels too: 300 against 440 steps/s in a short run. Whether ranks pay on a machine
with more cores is not measured; PPO's default is one process.

Rank 0 leads: it tells the workers when to collect each rollout (so that they wait for it while it
logs, evaluates and checkpoints, not inside a collective), and when to stop. Each worker ignores
Ctrl-C (the terminal sends it to the whole process group): rank 0 decides when the run stops. A
worker that fails sends its traceback before it exits; rank 0 raises it as a
:class:`~bimgame.learn.run_dir.TrainingError`.
"""

from __future__ import annotations

import dataclasses
import datetime
import multiprocessing
import queue
import signal
import tempfile
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist

from bimgame.learn.learner_settings import policy_network
from bimgame.learn.ppo.learner import RankLearner, adam
from bimgame.learn.ppo.processes import next_message, stop_children
from bimgame.learn.ppo.settings import PPOConfig
from bimgame.learn.ppo.update import GradientAverage
from bimgame.learn.rewards import EnvWrapper
from bimgame.learn.rollout import FinishedEpisode
from bimgame.learn.run_dir import TrainingError
from bimgame.util.processes import exit_when_parent_dies

__all__ = ["WorkerGroup"]

#: How long a rank waits for the others to join the group or to reach an all-reduce (the ranks
#: start every rollout together, so this bounds the difference of their collection times).
_COLLECTIVE_TIMEOUT = datetime.timedelta(minutes=5)


@dataclasses.dataclass(frozen=True)
class _WorkerStart:
    """What a worker process starts from: the run's settings, its rank, the rendezvous file, the step
    the session starts at, and rank 0's weights and Adam statistics (so that every copy is the same)."""

    config: dict[str, Any]
    rank: int
    rendezvous: str
    step: int
    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any]
    teacher: dict[str, torch.Tensor] | None = None
    """The KL term's teacher's weights (π^s's, or the policy's at its last refresh)."""
    taught_since: int = 0
    """The run's step the teacher was set at."""
    env_wrapper: EnvWrapper | None = None
    """The reward shaping every rank's environments are stepped through (picklable)."""


def _worker_main(start: _WorkerStart, commands: Any, messages: Any) -> None:
    """A worker process: join the group, then for every ``("go", step)`` rank 0 sends, collect and
    update, and send rank 0 the rollout's finished episodes; ``("stop", _)`` ends it. A failure is
    sent as a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_when_parent_dies()  # a rank 0 killed with kill -9 leaves no worker behind
    torch.set_num_threads(1)
    try:
        config = PPOConfig.from_dict(start.config)
        _join(start.rendezvous, start.rank, config.schedule.workers)
        net = policy_network(config)
        net.load_state_dict(start.model)
        optimizer = adam(net, config)
        optimizer.load_state_dict(start.optimizer)
        step = start.step
        finished: list[FinishedEpisode] = []
        learner = RankLearner(
            config,
            net,
            optimizer,
            rank=start.rank,
            step=step,
            on_episode=finished.append,
            global_step=lambda: step,
            average=GradientAverage(config.schedule.workers),
            teacher=start.teacher,
            taught_since=start.taught_since,
            env_wrapper=start.env_wrapper,
        )
        while True:
            command, step = commands.get()
            if command == "stop":
                break
            learner.rollout_and_update(step)
            messages.put(("episodes", start.rank, list(finished)))
            finished.clear()
    except BaseException:
        messages.put(("error", start.rank, traceback.format_exc()))
        raise
    finally:
        if dist.is_initialized():
            dist.destroy_process_group()


def _join(rendezvous: str, rank: int, world: int) -> None:
    dist.init_process_group(
        "gloo", init_method=f"file://{rendezvous}", rank=rank, world_size=world, timeout=_COLLECTIVE_TIMEOUT
    )


class WorkerGroup:
    """Rank 0's side of a multi-process run: the worker processes and the process group
    (:meth:`start`), the gradient average, and each rollout's episodes of the workers
    (:meth:`episodes`)."""

    def __init__(self, config: PPOConfig):
        self.config = config
        self.world = config.schedule.workers
        self.average = GradientAverage(self.world)
        context = multiprocessing.get_context("spawn")
        self.messages = context.Queue()
        self.commands = [context.Queue() for _ in range(1, self.world)]
        self.context = context
        self.processes: list[Any] = []

    @contextmanager
    def start(
        self,
        net: torch.nn.Module,
        optimizer: torch.optim.Optimizer,
        step: int,
        teacher: dict[str, torch.Tensor] | None = None,
        taught_since: int = 0,
        env_wrapper: EnvWrapper | None = None,
    ) -> Iterator[WorkerGroup]:
        """Start the workers from ``net``'s weights and ``optimizer``'s statistics at ``step`` (with
        the KL term's ``teacher`` weights, set at step ``taught_since``, and the run's reward shaping
        ``env_wrapper``), join them in a process group; on leaving, end them and the group."""
        if dist.is_initialized():
            raise RuntimeError(
                "PPO with workers > 1 makes its own torch.distributed process group; this process has one "
                "already (use workers=1 inside a distributed job)"
            )
        with tempfile.TemporaryDirectory(prefix="bimgame-ppo-") as directory:
            rendezvous = str(Path(directory) / "rendezvous")
            model = {key: value.detach().clone() for key, value in net.state_dict().items()}
            for rank in range(1, self.world):
                start = _WorkerStart(
                    self.config.to_dict(),
                    rank,
                    rendezvous,
                    step,
                    model,
                    optimizer.state_dict(),
                    teacher,
                    taught_since,
                    env_wrapper,
                )
                process = self.context.Process(
                    target=_worker_main, args=(start, self.commands[rank - 1], self.messages), daemon=True
                )
                process.start()
                self.processes.append(process)
            try:
                _join(rendezvous, 0, self.world)
                yield self
            except RuntimeError as error:  # a failed collective: a worker died (it says why), or another error
                failure = self._worker_failure()
                self._stop(terminate=True)
                if failure is None:
                    raise
                raise failure from error
            except BaseException:
                self._stop(terminate=True)
                raise
            self._stop(terminate=False)

    def go(self, step: int) -> None:
        """Tell every worker to collect and train on the rollout at ``step`` (as rank 0 does)."""
        for commands in self.commands:
            commands.put(("go", step))

    def episodes(self) -> list[FinishedEpisode]:
        """The episodes the workers finished in the rollout just trained on, in rank order (waits for
        every worker's message of that rollout)."""
        by_rank: dict[int, list[FinishedEpisode]] = {}
        while len(by_rank) < self.world - 1:
            _, rank, payload = next_message(self.messages, self.processes, "PPO worker", first=1)
            by_rank[rank] = payload
        return [episode for rank in sorted(by_rank) for episode in by_rank[rank]]

    def _worker_failure(self) -> TrainingError | None:
        """A worker's own report of its failure, if one comes within a few seconds."""
        while True:
            try:
                kind, rank, payload = self.messages.get(timeout=5.0)
            except queue.Empty:
                return None
            if kind == "error":
                return TrainingError(f"PPO worker {rank} failed:\n{payload}")

    def _stop(self, *, terminate: bool) -> None:
        """End the workers — at the run's end they have finished, after a failure or an interruption
        they are stopped — and the process group."""
        stop_children(self.commands, self.processes, terminate=terminate)
        if dist.is_initialized():
            dist.destroy_process_group()
