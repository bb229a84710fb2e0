"""The reproduction on a Ray cluster, on Ray's own multi-node test cluster on this machine (a head
without CPUs and two one-CPU nodes, so every piece runs on a node other than the driver's and
independent pieces run on different nodes): the grid equals the local grid's numbers, a restarted
driver recomputes nothing that finished, a piece whose node dies is continued on another node from
the last checkpoint it shipped back, a piece that raises on a node is a recorded failure, and
pieces that fit no node are refused."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from bimgame.experiments.cluster import (  # noqa: E402
    PIECE_MARKER,
    SNAPSHOTS,
    WORK_ROOT_ENV,
    CheckpointShipper,
    SnapshotStore,
    local_cluster,
)
from bimgame.experiments.plan import load_status  # noqa: E402
from bimgame.experiments.reproduce import reproduce  # noqa: E402
from bimgame.experiments.runners import a3c_config_for  # noqa: E402
from bimgame.expert.datasets import dataset_summary, generate_dataset  # noqa: E402
from bimgame.learn.a3c import train  # noqa: E402
from bimgame.learn.curves import read_table  # noqa: E402
from bimgame.util.archives import pack_directory, unpack_directory  # noqa: E402

pytestmark = pytest.mark.xdist_group("ray-cluster")  # one cluster per test process


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A head node without CPUs and two worker nodes of one CPU each; the driver (this process)
    joins it through the head before the workers exist, so it never sits on a node a test removes.
    Yields the cluster and the root under which the nodes' tasks work (the nodes inherit it from
    this process's environment, as a real node would from its own)."""
    work_root = tmp_path_factory.mktemp("node-work")
    previous = os.environ.get(WORK_ROOT_ENV)
    os.environ[WORK_ROOT_ENV] = str(work_root)
    with local_cluster(nodes=2, cpus_per_node=1) as cluster:
        yield cluster, work_root
    if previous is None:
        os.environ.pop(WORK_ROOT_ENV, None)
    else:
        os.environ[WORK_ROOT_ENV] = previous


def _equal_tables(a: Path, b: Path, skip: tuple[str, ...] = ()) -> None:
    """Two CSV logs hold the same numbers, apart from the wall-clock columns ``skip``."""
    left, right = read_table(a), read_table(b)
    assert sorted(left) == sorted(right)
    for column in left:
        if column not in skip:
            np.testing.assert_array_equal(left[column], right[column], err_msg=f"{a.name}: {column}")


def _summary(path: Path) -> dict:
    values = json.loads(path.read_text())
    return {k: v for k, v in values.items() if k not in ("seconds", "steps_per_second", "updated", "written")}


def _mtimes(root: Path) -> dict[str, int]:
    """Modification times of every file of the pieces' directories."""
    return {str(p): p.stat().st_mtime_ns for part in ("data", "pretrain", "runs") for p in (root / part).rglob("*")
            if p.is_file()}


def test_the_grid_on_two_nodes_equals_the_local_grid_and_a_restart_recomputes_nothing(cluster, tmp_path,
                                                                                        tiny_budget):
    budget = dataclasses.replace(tiny_budget, seeds=1)
    local = reproduce(tmp_path / "local", budget, progress=False)
    on_ray = reproduce(tmp_path / "ray", budget, progress=False, backend="ray")
    assert local.complete and on_ray.complete
    assert sorted(on_ray.computed) == sorted(local.computed) and len(on_ray.computed) == 6
    status = load_status(tmp_path / "ray")
    assert status["invocations"][-1]["backend"] == "ray" and status["invocations"][-1]["cluster_cpus"] == 2
    nodes = {entry["node"] for entry in status["pieces"].values()}
    assert len(nodes) == 2, nodes  # independent pieces ran side by side, on both nodes
    # Every result equals the local backend's, apart from wall-clock columns.
    a, b = tmp_path / "local", tmp_path / "ray"
    for episode in sorted((a / "data" / "episodes").iterdir()):
        assert episode.read_bytes() == (b / "data" / "episodes" / episode.name).read_bytes()
    for target in ("policy", "value"):
        piece = f"pretrain/STG1/{target}-seed0"
        _equal_tables(a / piece / "pretrain.csv", b / piece / "pretrain.csv", skip=("seconds",))
        assert _summary(a / piece / "summary.json") == _summary(b / piece / "summary.json")
    for algorithm in ("a3c", "pretrain-a3c-value"):
        run = f"runs/STG1/{algorithm}/seed0"
        assert (a / run / "episodes.csv").read_bytes() == (b / run / "episodes.csv").read_bytes()
        _equal_tables(a / run / "updates.csv", b / run / "updates.csv", skip=("seconds", "sps"))
        assert _summary(a / run / "summary.json") == _summary(b / run / "summary.json")
    _equal_tables(a / "runs/STG1/dagger/seed0/dagger.csv", b / "runs/STG1/dagger/seed0/dagger.csv",
                  skip=("seconds",))
    assert not list(b.rglob(".*.incoming-*")) and not list(b.rglob(".*.replaced-*"))

    # A driver run again with the same command skips everything that finished ...
    before = _mtimes(b)
    again = reproduce(b, budget, progress=False, backend="ray")
    assert again.computed == [] and len(again.reused) == 6 and _mtimes(b) == before
    # ... and computes only what is missing, with the finished pieces it needs shipped from the driver.
    shutil.rmtree(b / "runs/STG1/pretrain-a3c-value/seed0")
    third = reproduce(b, budget, progress=False, backend="ray")
    assert third.computed == ["runs/STG1/pretrain-a3c-value/seed0"] and len(third.reused) == 5
    assert (a / "runs/STG1/pretrain-a3c-value/seed0/episodes.csv").read_bytes() == \
        (b / "runs/STG1/pretrain-a3c-value/seed0/episodes.csv").read_bytes()
    counts = {k: v["computed"] for k, v in load_status(b)["pieces"].items()}
    assert counts.pop("runs/STG1/pretrain-a3c-value/seed0") == 2 and set(counts.values()) == {1}


def test_a_restarted_driver_continues_an_unfinished_run_from_its_snapshot(cluster, tmp_path, tiny_budget):
    """A driver stopped while a run was under way on a node left the run's last shipped snapshot in
    the reproduction's .snapshots/; the same command continues the run from it."""
    budget = dataclasses.replace(tiny_budget, algorithms=("a3c",), seeds=1)
    partial = tmp_path / "elsewhere" / "run"
    train(a3c_config_for(budget, "STG1", 0).with_flat(steps=800), partial, progress=False,
          extra_config={"reward": {"value_reward": None, "geodesic_coef": None}})
    # Mark the first attempt's first episode (length 9999), to tell a continued run from a new one.
    log = partial / "episodes.csv"
    header, first, *rest = log.read_text().splitlines(keepends=True)
    fields = first.split(",")
    fields[header.split(",").index("length")] = "9999"
    log.write_text("".join([header, ",".join(fields), *rest]))
    SnapshotStore(tmp_path / "out" / SNAPSHOTS).put("runs/STG1/a3c/seed0", pack_directory(partial))
    result = reproduce(tmp_path / "out", budget, progress=False, backend="ray")
    assert result.complete and result.computed == ["data", "runs/STG1/a3c/seed0"]
    entry = load_status(tmp_path / "out")["pieces"]["runs/STG1/a3c/seed0"]
    assert entry["note"] == "resumed from its checkpoint, shipped back by an earlier attempt", entry
    assert read_table(tmp_path / "out/runs/STG1/a3c/seed0/episodes.csv")["length"][0] == 9999  # the first attempt's
    assert not list((tmp_path / "out" / SNAPSHOTS).iterdir())


def test_a_piece_that_raises_on_a_node_is_a_recorded_failure(cluster, tmp_path, tiny_budget):
    budget = dataclasses.replace(tiny_budget, algorithms=("pretrain+a3c",), seeds=1)
    reproduce(tmp_path, budget, progress=False, stop_after=2)  # the dataset and π^s, locally
    (tmp_path / "pretrain/STG1/policy-seed0/checkpoint.pt").write_bytes(b"damaged after it finished")
    result = reproduce(tmp_path, budget, progress=False, backend="ray")
    assert list(result.failed) == ["runs/STG1/pretrain-a3c/seed0"] and result.computed == []
    entry = load_status(tmp_path)["pieces"]["runs/STG1/pretrain-a3c/seed0"]
    assert entry["state"] == "failed" and "checkpoint.pt" in entry["error"] and entry["traceback"]
    assert not (tmp_path / "runs").exists()  # nothing of a failed piece reaches the driver


def test_pieces_that_fit_no_node_are_refused(cluster, tmp_path, tiny_budget):
    budget = tiny_budget.replace(algorithms=("a3c",), seeds=1, a3c={"workers": 2})
    with pytest.raises(ValueError, match=r"largest node has 1 CPUs, but a3c pieces need 2"):
        reproduce(tmp_path, budget, progress=False, backend="ray")


def test_generate_on_two_nodes_gives_the_local_dataset(cluster, tmp_path):
    args = dict(task="STG1", episodes=2, seed=3, max_steps=20, progress=False)
    local = generate_dataset(tmp_path / "local", workers=1, **args)
    on_ray = generate_dataset(tmp_path / "ray", backend="ray", workers=2, **args)
    assert dataset_summary(local)["content_sha256"] == dataset_summary(on_ray)["content_sha256"]


def test_snapshots_are_files_that_a_new_store_finds_until_they_are_dropped(tmp_path):
    store = SnapshotStore(tmp_path / SNAPSHOTS)
    assert store.latest("runs/STG1/a3c/seed0") is None
    assert store.put("runs/STG1/a3c/seed0", b"first") == 5 and store.put("runs/STG1/a3c/seed0", b"second") == 6
    assert SnapshotStore(tmp_path / SNAPSHOTS).latest("runs/STG1/a3c/seed0") == b"second"  # a restarted driver's
    assert [p.name for p in (tmp_path / SNAPSHOTS).iterdir()] == ["runs--STG1--a3c--seed0.tar"]
    store.drop("runs/STG1/a3c/seed0")
    store.drop("runs/STG1/a3c/seed0")  # dropping twice is fine
    assert SnapshotStore(tmp_path / SNAPSHOTS).latest("runs/STG1/a3c/seed0") is None


def test_a_running_piece_ships_each_new_checkpoint_to_the_driver_node(cluster, tmp_path):
    store = ray.remote(SnapshotStore).options(num_cpus=0).remote(tmp_path / SNAPSHOTS)
    run = tmp_path / "run"
    run.mkdir()
    marker = tmp_path / PIECE_MARKER
    marker.write_text(json.dumps({"piece": "runs/STG1/a3c/seed0"}))
    shipper = CheckpointShipper(store, "runs/STG1/a3c/seed0", run, marker, poll_seconds=60.0)
    (run / "episodes.csv").write_text("step\n1\n")
    assert not shipper.ship_if_new()  # no checkpoint yet: nothing to continue from
    assert ray.get(store.latest.remote("runs/STG1/a3c/seed0")) is None
    (run / "checkpoint.pt").write_bytes(b"first")
    assert shipper.ship_if_new() and not shipper.ship_if_new()  # once per checkpoint
    (run / "checkpoint.pt").write_bytes(b"second")
    os.utime(run / "checkpoint.pt", ns=(1, 1))  # a new checkpoint (a new mtime)
    assert shipper.ship_if_new()
    unpack_directory(ray.get(store.latest.remote("runs/STG1/a3c/seed0")), tmp_path / "copy")
    assert (tmp_path / "copy/checkpoint.pt").read_bytes() == b"second"
    assert (tmp_path / "copy/episodes.csv").read_text() == "step\n1\n"
    info = json.loads(marker.read_text())
    assert info["piece"] == "runs/STG1/a3c/seed0" and info["shipped"] == 2 and info["shipped_bytes"] > 0
    ray.get(store.drop.remote("runs/STG1/a3c/seed0"))
    assert ray.get(store.latest.remote("runs/STG1/a3c/seed0")) is None
    ray.kill(store)


def test_a_piece_whose_node_dies_continues_on_another_node_from_its_shipped_checkpoint(cluster, tmp_path,
                                                                                     tiny_budget):
    """Last in the module: it removes a node (and adds a fresh one back)."""
    ray_cluster, work_root = cluster
    budget = tiny_budget.replace(name="long", algorithms=("a3c",), seeds=1,
                                 a3c={"steps": {"STG1": 20_000}, "checkpoint_every": 2_000})
    outcome: dict = {}
    driver = threading.Thread(target=lambda: outcome.update(
        result=reproduce(tmp_path, budget, progress=False, backend="ray")))
    driver.start()
    victim = None
    deadline = time.monotonic() + 120
    while victim is None and time.monotonic() < deadline:
        for marker in work_root.glob(f"*/{PIECE_MARKER}"):
            try:
                info = json.loads(marker.read_text())
            except (OSError, ValueError):
                continue  # being replaced
            if info["piece"] == "runs/STG1/a3c/seed0" and info.get("shipped", 0) >= 1:
                victim = info["node_id"]  # the run is under way there, and a checkpoint reached the driver
        time.sleep(0.2)
    assert victim is not None, "the A3C piece never shipped a checkpoint"
    node = next(n for n in ray_cluster.worker_nodes if n.node_id == victim)
    ray_cluster.remove_node(node, allow_graceful=False)
    driver.join(timeout=300)
    assert not driver.is_alive()
    result = outcome["result"]
    assert result.complete and sorted(result.computed) == ["data", "runs/STG1/a3c/seed0"]
    entry = load_status(tmp_path)["pieces"]["runs/STG1/a3c/seed0"]
    assert entry["state"] == "done" and victim[:12] not in entry["node"]
    # The retried task continued from the checkpoint the first node shipped, not from scratch.
    assert entry["note"] == "resumed from its checkpoint, shipped back by an earlier attempt", entry
    assert not list((tmp_path / SNAPSHOTS).iterdir())  # dropped once the piece was done
    summary = json.loads((tmp_path / "runs/STG1/a3c/seed0/summary.json").read_text())
    assert summary["stopped"] == "finished" and summary["steps"] >= 20_000
    ray_cluster.add_node(num_cpus=1)
    ray_cluster.wait_for_nodes()
