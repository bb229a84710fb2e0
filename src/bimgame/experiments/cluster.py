"""The reproduction on a Ray cluster: :class:`RayBackend` runs every piece as a Ray task that
reserves the CPUs the piece keeps busy (:func:`~bimgame.experiments.costs.piece_cpus`), so
independent pieces run side by side across the nodes, each as soon as what it needs is finished.

**No shared filesystem.** A task works in a fresh directory on its node
(:func:`compute_on_node`): the driver sends it the finished pieces it reads (the expert dataset,
π^s, V̂) as archives through Ray's object store, the task computes the piece there with the same
runner as the local backend and returns the piece's directory as an archive (logs, summaries, final
weights, figures); the driver unpacks it into the reproduction directory atomically
(:func:`bimgame.util.archives.unpack_directory`) and only then records the piece as done. An
archive that other pieces read is put into the object store once, by the driver, so it outlives
the node that computed it.

**Faults.** A task whose node dies, or whose worker process is killed, is retried by Ray on another
node (``max_retries``). Pieces that can continue from a checkpoint (A3C, PPO and DAgger runs,
:attr:`~bimgame.experiments.kinds.PieceKind.resumable`) ship their directory to the driver's node each
time they write a new checkpoint (:class:`SnapshotStore`, an actor pinned to the driver's node,
keeps the latest one per piece in the reproduction's :data:`SNAPSHOTS` directory), so the retried
task continues from the last checkpoint, as a local run continues after an interruption; the other
pieces (dataset, pre-training) start again from scratch. A driver that is stopped and run again with
the same command skips every piece whose outputs it already holds, and continues the unfinished ones
from their snapshots. A piece's outputs reach the reproduction directory only once it finished, and
a piece only ever writes on its own node. A piece that raises is a failure (Ray does not retry it),
recorded like a local failure; its snapshot is kept, so that running the command again continues it
as the local backend continues a failed run from its directory.

**Same results.** A piece computes exactly what it computes locally: the same runner, settings and
seeds; only the directory differs. So the paths a run records in its ``config.json`` (its π^s, V̂
and dataset) are the node's working paths; nothing reads them after the run has finished.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import tarfile
import tempfile
import threading
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bimgame.experiments.backends import PieceOutcome, error_text, run_piece
from bimgame.experiments.budgets import Budget
from bimgame.experiments.costs import piece_cpus
from bimgame.experiments.grid import Piece
from bimgame.experiments.kinds import kind_of
from bimgame.expert.pool import import_ray
from bimgame.learn.runs import CHECKPOINT
from bimgame.util.archives import pack_directory, unpack_directory
from bimgame.util.files import atomic_write_bytes, read_json, write_json

__all__ = [
    "RayBackend",
    "SnapshotStore",
    "CheckpointShipper",
    "compute_on_node",
    "local_cluster",
    "WORK_ROOT_ENV",
    "PIECE_MARKER",
    "SNAPSHOTS",
    "SHIP_POLL_SECONDS",
]

#: Environment variable naming the directory under which a node's tasks work (default: the node's
#: temporary directory).
WORK_ROOT_ENV = "BIMGAME_WORK_ROOT"
#: The file a task writes first into its working directory: the piece, node and process, so a
#: person (or a test) on the node can tell which piece a directory belongs to.
PIECE_MARKER = "bimgame-piece.json"
#: Where in the reproduction directory the driver's node keeps the unfinished pieces' snapshots.
SNAPSHOTS = ".snapshots"
#: How often (seconds) a task looks for a new checkpoint to ship.
SHIP_POLL_SECONDS = 2.0


class SnapshotStore:
    """The latest snapshot (a directory archive) of each unfinished resumable piece, kept by a Ray
    actor on the driver's node, so that it outlives the node that wrote it. Ray has no store of its
    own for this: an object a task puts into the object store is lost with the task's node, and the
    driver cannot read from a task while it runs.

    Each snapshot is also written (atomically) as a file under ``directory`` — the reproduction's
    ``.snapshots/``, on the driver's disk — so that a driver that is stopped and run again continues
    its unfinished pieces from their last checkpoints too."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)

    def _file(self, piece_id: str) -> Path:
        return self.directory / (piece_id.replace("/", "--") + ".tar")

    def put(self, piece_id: str, archive: bytes) -> int:
        """Keep ``archive`` as ``piece_id``'s latest snapshot; returns its size in bytes."""
        atomic_write_bytes(self._file(piece_id), archive)
        return len(archive)

    def latest(self, piece_id: str) -> bytes | None:
        """``piece_id``'s latest snapshot, or None if no attempt shipped one."""
        try:
            return self._file(piece_id).read_bytes()
        except FileNotFoundError:
            return None

    def drop(self, piece_id: str) -> None:
        """Forget ``piece_id``'s snapshot (the piece is done, its outputs in the reproduction)."""
        self._file(piece_id).unlink(missing_ok=True)


class CheckpointShipper:
    """Ships a running piece's directory to the :class:`SnapshotStore` each time its checkpoint file
    is replaced, from a thread of the task, and records each shipment in the task's
    :data:`PIECE_MARKER` (``shipped``: how many, ``shipped_bytes``: the last one's size).

    A directory is packed while the run goes on: the checkpoint is replaced atomically, so the
    archive holds a whole one, and the logs packed after it reach at least its step (a row cut off
    mid-write is dropped on resume, as after a kill)."""

    def __init__(self, store: Any, piece_id: str, directory: Path, marker: Path, poll_seconds: float):
        import ray

        self.ray, self.store, self.piece_id = ray, store, piece_id
        self.directory, self.marker, self.poll_seconds = directory, marker, poll_seconds
        self.shipped = 0
        self._last_stamp: int | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"ship {piece_id}", daemon=True)

    def __enter__(self) -> CheckpointShipper:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _loop(self) -> None:
        while not self._stop.wait(self.poll_seconds):
            self.ship_if_new()

    def ship_if_new(self) -> bool:
        """Ship the directory if its checkpoint changed since the last shipment; whether it did."""
        try:
            stamp = (self.directory / CHECKPOINT).stat().st_mtime_ns
        except OSError:
            return False  # no checkpoint yet
        if stamp == self._last_stamp:
            return False
        try:
            archive = pack_directory(self.directory)
        except OSError:
            return False  # a temporary file vanished while it was packed: the next look ships it
        size = self.ray.get(self.store.put.remote(self.piece_id, archive))
        self._last_stamp, self.shipped = stamp, self.shipped + 1
        write_json(self.marker, {**(read_json(self.marker) or {}), "shipped": self.shipped, "shipped_bytes": size})
        return True


def compute_on_node(
    piece: Piece,
    budget: Budget,
    input_paths: list[str],
    store: Any,
    *archives: bytes,
    poll_seconds: float = SHIP_POLL_SECONDS,
) -> dict[str, Any]:
    """The body of a piece's Ray task: unpack the pieces it reads (``archives``, one per path of
    ``input_paths``) into a fresh working directory, and the piece's latest snapshot in ``store``
    (a :class:`SnapshotStore` actor) if an earlier attempt shipped one; compute the piece there —
    shipping its directory to ``store`` at every new checkpoint if it is resumable — and return its
    directory as an archive with the runner's note and the node's name. The working directory is
    removed afterwards, whatever happens."""
    import ray

    root = os.environ.get(WORK_ROOT_ENV) or None
    if root is not None:
        Path(root).mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="bimgame-piece-", dir=root))
    node_id = ray.get_runtime_context().get_node_id()
    node = f"{socket.gethostname()} ({node_id[:12]})"
    try:
        write_json(work / PIECE_MARKER, {"piece": piece.id, "node_id": node_id, "pid": os.getpid()})
        for path, archive in zip(input_paths, archives, strict=True):
            unpack_directory(archive, work / path)
        resumable = kind_of(piece).resumable
        snapshot = ray.get(store.latest.remote(piece.id)) if resumable else None
        if snapshot is not None:  # an earlier attempt's node died: continue from its last checkpoint
            unpack_directory(snapshot, work / piece.path)
        started = time.monotonic()
        shipping = (
            CheckpointShipper(store, piece.id, work / piece.path, work / PIECE_MARKER, poll_seconds)
            if resumable
            else contextlib.nullcontext()
        )
        try:
            with shipping:
                note = run_piece(piece, budget, work)
        except KeyboardInterrupt:
            raise RuntimeError(f"{piece.id} stopped before it finished on {node}") from None
        if snapshot is not None:
            note = f"{note}, shipped back by an earlier attempt"
        return {
            "archive": pack_directory(work / piece.path),
            "note": note,
            "node": node,
            "seconds": time.monotonic() - started,
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)


class RayBackend:
    """Pieces as Ray tasks on a cluster (see the module notes).

    Args:
        out_dir: the reproduction directory on the driver, where results are unpacked.
        pieces: the plan's pieces (to know which finished pieces others read).
        address: the cluster to join (``ray.init(address=...)``, e.g. ``auto`` or ``HOST:6379``);
            None joins the Ray already initialised in this process, else starts a new local one.
        max_retries: how often Ray reruns a task whose node or worker process died.
    """

    capacity = None
    queues = True

    def __init__(
        self, out_dir: Path, budget: Budget, pieces: list[Piece], *, address: str | None = None, max_retries: int = 3
    ):
        if not (isinstance(max_retries, int) and max_retries >= 0):
            raise ValueError(f"max_retries must be an integer >= 0, got {max_retries!r}")
        self.ray = import_ray()
        self.out_dir, self.budget, self.max_retries = out_dir, budget, max_retries
        self.pieces = {p.id: p for p in pieces}
        self._read = {need for piece in pieces for need in piece.needs}  # pieces that others read
        self._started_ray = False
        if not self.ray.is_initialized():
            if address is None:  # a new Ray on this machine, even if a cluster runs here too
                self.ray.init(address="local", include_dashboard=False, log_to_driver=False)
            else:
                self.ray.init(address=address, include_dashboard=False, log_to_driver=False)
            self._started_ray = True
        nodes = [n for n in self.ray.nodes() if n.get("Alive")]
        self.nodes = len(nodes)
        self.cpus = float(sum(n["Resources"].get("CPU", 0.0) for n in nodes))
        self.largest_node_cpus = max((n["Resources"].get("CPU", 0.0) for n in nodes), default=0.0)
        self._task = self.ray.remote(compute_on_node)
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy  # part of Ray, which is optional

        driver_node = NodeAffinitySchedulingStrategy(node_id=self.ray.get_runtime_context().get_node_id(), soft=False)
        self._store = (
            self.ray.remote(SnapshotStore)
            .options(num_cpus=0, scheduling_strategy=driver_node)
            .remote((out_dir / SNAPSHOTS).resolve())
        )
        self._inputs: dict[str, Any] = {}
        self._in_flight: dict[Any, tuple[Piece, float]] = {}

    def check_fits(self, pieces: list[Piece]) -> None:
        """Refuse (ValueError) pieces that need more CPUs than the cluster's largest node has: Ray
        would queue them forever."""
        too_big = sorted(
            {
                (piece_cpus(p, self.budget), p.kind)
                for p in pieces
                if piece_cpus(p, self.budget) > self.largest_node_cpus
            }
        )
        if too_big:
            wants = ", ".join(f"{kind} pieces need {cpus}" for cpus, kind in too_big)
            raise ValueError(
                f"the cluster's largest node has {self.largest_node_cpus:g} CPUs, but {wants} "
                f"(an A3C run: its workers plus its evaluator). Add bigger nodes, or use a budget "
                f"with fewer workers per run"
            )

    def _input(self, piece_id: str) -> Any:
        """The object-store reference of a finished piece's archive (put once, by the driver)."""
        if piece_id not in self._inputs:
            path = self.pieces[piece_id].path
            self._inputs[piece_id] = self.ray.put(pack_directory(self.out_dir / path))
        return self._inputs[piece_id]

    def submit(self, piece: Piece) -> None:
        paths = [self.pieces[n].path for n in piece.needs]
        options = dict(
            num_cpus=piece_cpus(piece, self.budget),
            max_retries=self.max_retries,
            retry_exceptions=False,
            name=f"bimgame:{piece.id}",
        )
        ref = self._task.options(**options).remote(
            piece, self.budget, paths, self._store, *(self._input(n) for n in piece.needs)
        )
        self._in_flight[ref] = (piece, time.monotonic())

    def next_outcome(self) -> PieceOutcome:
        if not self._in_flight:
            raise RuntimeError("no piece is in flight")
        (ref,), _ = self.ray.wait(list(self._in_flight), num_returns=1)
        piece, submitted = self._in_flight.pop(ref)
        try:
            result = self.ray.get(ref)
        except self.ray.exceptions.RayTaskError as error:
            cause = error.cause if getattr(error, "cause", None) is not None else error
            return PieceOutcome(piece, time.monotonic() - submitted, error=error_text(cause), traceback=str(error))
        except self.ray.exceptions.RayError as error:  # the node or worker died more often than max_retries
            return PieceOutcome(
                piece, time.monotonic() - submitted, error=error_text(error), traceback=traceback.format_exc()
            )
        try:
            unpack_directory(result["archive"], self.out_dir / piece.path)
        except (OSError, tarfile.TarError) as error:
            return PieceOutcome(
                piece, result["seconds"], error=error_text(error), traceback=traceback.format_exc(), node=result["node"]
            )
        self.ray.get(self._store.drop.remote(piece.id))  # its outputs are in place: no attempt continues it
        if piece.id in self._read:
            self._inputs[piece.id] = self.ray.put(result["archive"])
        return PieceOutcome(piece, result["seconds"], note=result["note"], node=result["node"])

    def close(self) -> None:
        for ref in list(self._in_flight):
            self.ray.cancel(ref, force=True)
        self._in_flight.clear()
        self._inputs.clear()
        self.ray.kill(self._store)
        if self._started_ray:
            self.ray.shutdown()


@contextlib.contextmanager
def local_cluster(nodes: int = 2, cpus_per_node: int = 1) -> Iterator[Any]:
    """A multi-node Ray cluster on this machine (``ray.cluster_utils.Cluster``: a head without CPUs
    and ``nodes`` worker nodes), with this process joined as its driver; yields the cluster. The
    driver joins through the head before the worker nodes exist, so it never sits on a node that
    ``cluster.remove_node`` takes away. For trying the Ray backend (the tests and
    ``benchmarks/bench_cluster.py``); the nodes inherit this process's environment."""
    ray = import_ray()
    from ray.cluster_utils import Cluster  # part of Ray, which is optional

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "include_dashboard": False})
    try:
        ray.init(address=cluster.address, log_to_driver=False)
        for _ in range(nodes):
            cluster.add_node(num_cpus=cpus_per_node)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        ray.shutdown()
        cluster.shutdown()
