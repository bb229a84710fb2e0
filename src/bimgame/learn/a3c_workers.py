"""What runs inside an A3C run's spawned processes: the worker (act for a segment, apply its
gradient to the shared weights) and the evaluator (greedy and sampled episodes of the shared
weights every ``eval_every`` steps). :func:`bimgame.learn.a3c.train` starts them; they report to
the parent through its message queue. The entry points are module-level functions, so that the
``spawn`` start method can pickle them by name."""

from __future__ import annotations

import signal
import time
import traceback
from typing import Any

import numpy as np
import torch

from bimgame.envs.randomization import RANDOMIZATION_PRESETS
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.a3c_core import A3CConfig, EnvWrapper, apply_update, evaluate, make_optimizer, network_for
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.augment import random_shift
from bimgame.learn.finetune import DemoWindows, EntropyTarget, RunningScale, Teacher, loss_weights
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.starts import TRUE_START, DemoStartCurriculum, ReverseCurriculum
from bimgame.util.processes import exit_when_parent_dies


def _worker_seeds(config: A3CConfig, rank: int, start_step: int) -> tuple[int, int]:
    """(env seed, torch seed) of a worker; a resumed run (start_step > 0) draws fresh episodes."""
    sequence = np.random.SeedSequence([config.seed, rank, start_step])
    env_seed, torch_seed = sequence.generate_state(2)
    return int(env_seed), int(torch_seed)


def _start_sampler(config: A3CConfig):
    """The start curriculum of a worker's training episodes (None: the task's own starts), for the
    maze the workers' envs are built with (MERL's)."""
    if config.start_curriculum == "demo":
        return DemoStartCurriculum.from_dataset(config.expert_data, config.task,
                                                threshold=config.curriculum_threshold)
    if config.start_curriculum == "reverse":
        # A pool of 32 starts (not the class's 100): each start is tried 3 times before the pool grows,
        # and a failed STG3 episode lasts 750 steps, so 100 starts held one pool for ≈ 230k steps.
        return ReverseCurriculum(config.task, high=config.curriculum_threshold, pool_size=32)
    return None


def _make_env(config: A3CConfig, num_envs: int, **kwargs: Any) -> BallInMazeVectorEnv:
    randomize = None if config.randomize is None else RANDOMIZATION_PRESETS[config.randomize]
    return BallInMazeVectorEnv(num_envs, task=config.task, obs_mode=config.obs, nthread=1,
                               max_episode_steps=config.time_limit, autoreset_mode="same_step",
                               state_info=config.privileged, randomize=randomize, **kwargs)


def _worker(rank: int, config: A3CConfig, shared: RecurrentActorCritic, optimizer_state: list[dict],
            counter, stop, messages, env_wrapper: EnvWrapper | None, start_step: int,
            teacher_weights: dict[str, torch.Tensor] | None = None) -> None:
    """One A3C worker process: act, compute the segment's gradient, apply it to the shared weights.
    ``teacher_weights``: π^s for the KL term (see :mod:`bimgame.learn.finetune`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    exit_when_parent_dies()  # a parent killed with kill -9 leaves no worker behind
    torch.set_num_threads(1)
    try:
        _worker_loop(rank, config, shared, optimizer_state, counter, stop, messages, env_wrapper, start_step,
                     teacher_weights)
    except Exception:
        messages.put(("error", rank, traceback.format_exc()))
    finally:
        messages.put(("exit", rank, None))


def _worker_loop(rank, config, shared, optimizer_state, counter, stop, messages, env_wrapper, start_step,
                 teacher_weights):
    env_seed, torch_seed = _worker_seeds(config, rank, start_step)
    curriculum = _start_sampler(config)
    base_env = _make_env(config, config.envs_per_worker, start_sampler=curriculum)
    env = env_wrapper(base_env) if env_wrapper is not None else base_env
    max_tilt = base_env.maze.max_tilt
    local = network_for(config, base_env.maze)
    optimizer = make_optimizer(config, shared)
    shared_params = list(shared.parameters())
    # The shared statistics are listed in the optimiser's parameter order (see shared_optimizer_state).
    for param, state in zip([p for group in optimizer.param_groups for p in group["params"]], optimizer_state):
        optimizer.state[param] = state
    generator = torch.Generator().manual_seed(torch_seed)
    finetuning: dict = {"advantage_scale": RunningScale() if config.advantage_norm else None}
    entropy_target = None if config.entropy_target is None else \
        EntropyTarget(config.entropy_target, config.entropy_target_steps, config.entropy_coef)
    teacher = None
    if teacher_weights is not None:
        teacher_net = network_for(config, base_env.maze)
        teacher_net.load_state_dict(teacher_weights)
        teacher = Teacher(teacher_net, config.envs_per_worker, config.kl_temperature)
    demos, demo_rng = None, np.random.default_rng(np.random.SeedSequence([config.seed, rank, start_step, 1]))
    if config.bc_coef > 0:
        demos = DemoWindows.from_dataset(config.expert_data, config.task, config.obs, config.gamma, base_env.maze)
    actor = RecurrentActor(local, config.envs_per_worker, generator=generator)
    obs, info = env.reset(seed=env_seed)
    tilt = tilt_input(info, max_tilt)
    augment_generator = torch.Generator().manual_seed(int(np.random.SeedSequence([config.seed, rank, start_step, 2])
                                                          .generate_state(1)[0]))
    keys = ("obs", "prev_action", "prev_reward", "tilt", "starts") + (("privileged",) if config.privileged else ())
    n, batch = config.n_steps, config.envs_per_worker
    episode_return = np.zeros(batch)
    episode_length = np.zeros(batch, dtype=np.int64)
    episode_start = np.full(batch, counter.value, dtype=np.int64)
    stats = {"policy_loss": 0.0, "value_loss": 0.0, "entropy": 0.0, "kl": 0.0, "bc": 0.0, "aux_frame": 0.0,
             "aux_memory": 0.0, "grad_norm": 0.0, "updates": 0}
    since_report = 0
    while not stop.is_set() and counter.value < config.steps:
        local.load_state_dict(shared.state_dict())
        h0, c0 = actor.state
        seg: dict[str, list] = {k: [] for k in keys + ("actions", "rewards")}
        step_at_start = counter.value
        for _ in range(n):
            obs = torch.as_tensor(obs)
            _record_inputs(seg, obs, actor, tilt, info)
            actions, _, _ = actor.act(obs, tilt)
            if curriculum is not None:
                start_tags = base_env.start_tags.copy()  # the step resets finished envs and their tags
            obs, reward, terminated, truncated, info = env.step(actions.numpy())
            reward = np.asarray(reward, dtype=np.float64)
            if not np.all(np.isfinite(reward)):
                messages.put(("nan", rank, {"step": int(counter.value), "what": "reward from the env",
                                            "rewards": reward.tolist()}))
                return
            done = terminated | truncated
            rewards_t = torch.as_tensor(reward, dtype=torch.float32)
            cut = truncated & ~terminated
            if cut.any():
                # A time limit is not a terminal state: bootstrap from the value of the last
                # observation, which SAME_STEP autoreset keeps in info["final_obs"].
                rewards_t = rewards_t + config.gamma * _final_values(actor, actions, reward, info, cut, max_tilt,
                                                                     config.privileged)
            seg["actions"].append(actions)
            seg["rewards"].append(rewards_t)
            # Learning curves show the task's own reward, also when a wrapper shapes it.
            episode_return += np.asarray(info.get("task_reward", reward), dtype=np.float64)
            episode_length += 1
            for i in np.flatnonzero(done):
                tag = TRUE_START
                if curriculum is not None:
                    tag = int(start_tags[i])
                    curriculum.record(tag, bool(terminated[i]))
                messages.put(("episode", rank, {
                    "start_step": int(episode_start[i]), "end_step": int(counter.value),
                    "return": float(episode_return[i]), "length": int(episode_length[i]),
                    "success": bool(terminated[i]), "true_start": tag == TRUE_START}))
            episode_return[done] = 0.0
            episode_length[done] = 0
            episode_start[done] = step_at_start
            actor.observe(actions, reward, done)
            tilt = tilt_input(info, max_tilt)
        _record_inputs(seg, torch.as_tensor(obs), actor, tilt, info)
        segment = {k: torch.stack(v) for k, v in seg.items()}
        # Which episodes ended at each step: what the actor marks as starting the step after.
        segment.update(ends=segment["starts"][1:], h0=h0, c0=c0)
        if not config.tilt_input:
            segment.pop("tilt")
        weights = loss_weights(config, step_at_start)
        if teacher is not None:  # it follows every segment, so that its LSTM state stays the learner's
            finetuning["teacher_log_probs"] = teacher.follow(segment)
            if weights.kl == 0 and config.kl_decay_steps > 0 and step_at_start >= config.kl_decay_steps:
                teacher, finetuning["teacher_log_probs"] = None, None  # annealed away: stop paying for it
        finetuning["demo_windows"] = demos.sample(batch, demo_rng) if demos is not None and weights.bc > 0 else None
        if config.augment_shift:  # after the teacher, which follows the frames as the learner acted on them
            segment["obs"] = random_shift(segment["obs"], config.augment_shift, augment_generator)
        parts = apply_update(local, shared_params, optimizer, segment, config, weights, **finetuning)
        parts.pop("loss")
        if entropy_target is not None and parts["applied"]:
            finetuning["entropy_coef"] = entropy_target.update(parts["entropy"], step_at_start)
        grad_norm = parts.pop("grad_norm")
        if not parts.pop("applied"):
            messages.put(("nan", rank, {"step": int(counter.value), "what": "loss", "grad_norm": grad_norm,
                                        **parts}))
            return
        with counter.get_lock():
            counter.value += config.steps_per_update
        for key in ("policy_loss", "value_loss", "entropy", "kl", "bc", "aux_frame", "aux_memory"):
            stats[key] += parts.get(key, float("nan") if key in _OPTIONAL_TERMS else 0.0)
        stats["grad_norm"] += grad_norm
        stats["updates"] += 1
        since_report += config.steps_per_update
        if since_report >= config.log_every:
            count = stats.pop("updates")
            messages.put(("update", rank, {"step": int(counter.value), **{k: v / count for k, v in stats.items()},
                                           "actor_weight": weights.actor, "kl_weight": weights.kl,
                                           "bc_weight": weights.bc, "entropy_coef": finetuning.get(
                                               "entropy_coef", config.entropy_coef),
                                           **(curriculum.status() if curriculum is not None else {})}))
            stats = {k: 0.0 for k in stats} | {"updates": 0}
            since_report = 0


#: Loss terms that only some runs have: logged as NaN (an empty cell) where a run has none.
_OPTIONAL_TERMS = ("kl", "bc", "aux_frame", "aux_memory")


def _record_inputs(seg: dict[str, list], obs: torch.Tensor, actor: RecurrentActor, tilt: torch.Tensor,
                   info: dict) -> None:
    """Append one step's network inputs (and, where the segment keeps it, the privileged state of
    the same step) to the segment being collected."""
    seg["obs"].append(obs)
    seg["prev_action"].append(actor.prev_action)
    seg["prev_reward"].append(actor.prev_reward)
    seg["tilt"].append(tilt)
    seg["starts"].append(actor.starts)
    if "privileged" in seg:
        seg["privileged"].append(torch.as_tensor(info["state"]))


def _final_values(actor: RecurrentActor, actions: torch.Tensor, reward: np.ndarray, info: dict,
                  cut: np.ndarray, max_tilt: float, privileged: bool = False) -> torch.Tensor:
    """V of the last observation of time-limited episodes (0 elsewhere), from the state after the
    step, without changing the actor; ``privileged``: the critic also reads the final state."""
    final_obs = info["final_obs"]
    final_tilt = tilt_input(info["final_info"], max_tilt)
    final_state = torch.as_tensor(info["final_info"]["state"]) if privileged else None
    with torch.no_grad():
        _, values, _ = actor.net.step(torch.as_tensor(final_obs), actions,
                                      torch.as_tensor(reward, dtype=torch.float32), final_tilt, actor.state,
                                      privileged=final_state)
    # Envs that were not cut hold NaN with an asymmetric critic's partial state; only cut ones count.
    return torch.where(torch.as_tensor(cut), values, torch.zeros_like(values))


def _evaluator(config: A3CConfig, shared: RecurrentActorCritic, counter, stop, messages, start_step: int,
               initial_weights: dict[str, torch.Tensor]) -> None:
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
        messages.put(("eval", -1, {"step": start_step, **evaluate(local, config)}))
        next_eval = (start_step // config.eval_every + 1) * config.eval_every
        while not stop.is_set():
            step = counter.value
            if step >= config.steps:
                break
            if step < next_eval:
                time.sleep(0.1)
                continue
            local.load_state_dict(shared.state_dict())
            messages.put(("eval", -1, {"step": int(step), **evaluate(local, config)}))
            next_eval = (step // config.eval_every + 1) * config.eval_every
    except Exception:
        messages.put(("error", -1, traceback.format_exc()))
    finally:
        messages.put(("exit", -1, None))
