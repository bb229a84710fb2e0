"""``bimgame play``: play the circular maze or the labyrinth in a browser, watch a trained agent or
the MPC expert, record human episodes (the maze's)."""

from __future__ import annotations

import argparse
import ipaddress
import logging
import sys
from pathlib import Path

from bimgame.cli.argtypes import add_max_steps_argument, non_negative_int, seed
from bimgame.envs.puzzles import TASK_NAMES
from bimgame.learn.common import read_run
from bimgame.learn.runs import torch_threads
from bimgame.play.agent import is_expert
from bimgame.play.recording import HumanRecording
from bimgame.play.server import serve
from bimgame.play.session import PlaySession, refuse_unsupported

__all__ = ["add_parsers", "run_play"]


def add_parsers(verbs: argparse._SubParsersAction) -> None:
    """Add the ``play`` verb to the command line's sub-parsers."""
    parser = verbs.add_parser("play", help="play in a browser: arrow keys tilt the board; record, or watch an agent")
    parser.add_argument(
        "--task",
        choices=TASK_NAMES,
        default=None,
        type=str.upper,
        help="a task of the circular maze or of CyberRunner's labyrinth (LABYRINTH-EASY, -MEDIUM, -HARD) "
        "(default: the agent's task with --agent RUN, else FULL)",
    )
    add_max_steps_argument(parser)
    parser.add_argument(
        "--record",
        type=Path,
        default=None,
        metavar="DIR",
        help="record your episodes into DIR as a Minari dataset like bimgame generate's "
        "(marked source: human; the circular maze's tasks only); an earlier recording in DIR is appended to",
    )
    parser.add_argument(
        "--agent",
        type=str,
        default=None,
        metavar="RUN",
        help="a trained run (A3C, PPO or pre-trained policy) of the task's puzzle, or 'expert' (the puzzle's "
        "MPC expert; a run directory named so: ./expert), that plays while you watch; H takes over",
    )
    parser.add_argument("--sampled", action="store_true", help="the agent samples its actions (default: greedy)")
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this computer only)"
    )
    parser.add_argument("--port", type=_port, default=8765, help="port (default 8765; 0: any free port)")
    parser.add_argument("--seed", type=seed, default=0, help="seed of the episodes' start positions (default 0)")
    parser.add_argument("--quiet", action="store_true", help="log only warnings (default: connections and episodes)")
    parser.set_defaults(run=run_play)


def run_play(args: argparse.Namespace) -> int:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("bimgame play: %(message)s"))
    logger = logging.getLogger("bimgame.play")
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING if args.quiet else logging.INFO)
    if not _is_loopback(args.host):
        print(
            f"bimgame play: warning: listening on {args.host}: anyone who can reach it can play and write "
            "into the recording (there is no password)",
            file=sys.stderr,
        )
    run_agent = args.agent is not None and not is_expert(args.agent)
    task = args.task or (read_run(args.agent).task if run_agent else "FULL")
    refuse_unsupported(task, recording=args.record is not None)  # before a recording directory is made
    recording = None
    if args.record is not None:
        recording = HumanRecording(args.record, task, max_steps=args.max_steps, seed=args.seed)
        before = recording.open()
        print(f"bimgame play: recording into {recording.out_dir} ({before} episodes there already)", file=sys.stderr)
    status = 0
    try:
        with torch_threads(1):
            session = PlaySession(
                task,
                max_steps=args.max_steps,
                seed=args.seed,
                agent=args.agent,
                greedy=not args.sampled,
                recording=recording,
            )
            try:
                serve(session, host=args.host, port=args.port, on_ready=lambda url: _ready(url, session))
            finally:
                session.close()  # records the person's unfinished episode (truncated)
    except KeyboardInterrupt:  # before the server was up (after, Ctrl-C stops it cleanly)
        status = 130
    finally:
        if recording is not None and not _finish_recording(recording):
            status = 130
    print("bimgame play: stopped", file=sys.stderr)
    return status


def _ready(url: str, session: PlaySession) -> None:
    who = f"; {session.agent.description} plays, H takes over" if session.agent is not None else ""
    print(
        f"bimgame play: {session.task} (limit {session.max_steps} steps){who} — open {url} in a browser (Ctrl-C stops)",
        flush=True,
    )


def _finish_recording(recording: HumanRecording) -> bool:
    print(f"bimgame play: finishing the dataset in {recording.out_dir} …", file=sys.stderr, flush=True)
    try:
        complete = recording.close()
    except KeyboardInterrupt:  # a second Ctrl-C
        print(
            "bimgame play: interrupted: the episode files are kept and the next 'bimgame play --record "
            f"{recording.out_dir}' rebuilds the dataset",
            file=sys.stderr,
        )
        return False
    state = "complete" if complete else f"not complete ({recording.last_error}); the episode files are kept"
    print(f"bimgame play: {recording.out_dir}: {recording.episodes} episodes, dataset {state}", file=sys.stderr)
    return True


def _port(text: str) -> int:
    value = non_negative_int(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"expected a port from 0 to 65535, got {text!r}")
    return value


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
