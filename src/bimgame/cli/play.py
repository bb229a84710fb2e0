"""``bimgame play``: play the maze in a browser, watch a trained agent, record human episodes."""

from __future__ import annotations

import argparse
import ipaddress
import logging
import sys
from pathlib import Path

from bimgame.cli.argtypes import (
    add_max_steps_argument,
    add_task_argument,
    non_negative_int,
    seed,
)
from bimgame.learn.common import read_run
from bimgame.learn.runs import torch_threads
from bimgame.play.recording import HumanRecording
from bimgame.play.server import serve
from bimgame.play.session import PlaySession

__all__ = ["add_parsers", "run_play"]


def add_parsers(verbs: argparse._SubParsersAction) -> None:
    """Add the ``play`` verb to the command line's sub-parsers."""
    parser = verbs.add_parser("play", help="play in a browser: arrow keys tilt the board; record, or watch an agent")
    add_task_argument(parser, None, help="the task (default: the agent's task with --agent, else FULL)")
    add_max_steps_argument(parser)
    parser.add_argument(
        "--record",
        type=Path,
        default=None,
        metavar="DIR",
        help="record your episodes into DIR as a Minari dataset like bimgame generate's "
        "(marked source: human); an earlier recording in DIR is appended to",
    )
    parser.add_argument(
        "--agent",
        type=Path,
        default=None,
        metavar="RUN",
        help="a trained run (A3C or pre-trained policy) that plays while you watch; H takes over",
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
    task = args.task or (read_run(args.agent).task if args.agent is not None else "FULL")
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
        f"bimgame play: {session.task.value} (limit {session.max_steps} steps){who} — open {url} in a browser "
        "(Ctrl-C stops)",
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
