"""Expert datasets: Minari format, exact pixel re-rendering, determinism across workers and backends,
kill-and-resume, integrity checks, refusal to touch foreign directories, the pre-training view."""

from __future__ import annotations

import argparse
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import minari
import numpy as np
import pytest
from minari import EpisodeData

import bimgame.expert.datasets as data
import bimgame.expert.generation as generation
import bimgame.expert.pool as parallel
from bimgame.cli.expert import add_generate_arguments
from bimgame.cli.main import main
from bimgame.envs.env import NO_ACTION, BallInMazeEnv
from bimgame.expert.datasets import DatasetError, dataset_summary, generate_dataset, iterate_sequences, load_dataset
from bimgame.expert.mpc import MPCConfig
from bimgame.util.seeding import episode_seed

CONFIG = MPCConfig(n_samples=4, horizon=8)
ARGS = dict(task="STG1", episodes=3, seed=1, config=CONFIG, max_steps=40, progress=False)
DATASET_ID = "bimgame/stg1-expert-v0"


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted single-worker run: the dataset every other run must reproduce."""
    return generate_dataset(tmp_path_factory.mktemp("data") / "reference", workers=1, **ARGS)


def episodes_of(dataset) -> list[dict]:
    seeds = [m["seed"] for m in dataset.storage.get_episode_metadata(dataset.episode_indices)]
    return [{"seed": seed, "observations": e.observations, "actions": e.actions, "rewards": e.rewards,
             "terminations": e.terminations, "truncations": e.truncations, **e.infos}
            for seed, e in zip(seeds, dataset.iterate_episodes())]


def assert_same_dataset(a, b):
    assert dataset_summary(a)["content_sha256"] == dataset_summary(b)["content_sha256"]
    episodes_a, episodes_b = episodes_of(load_dataset(a)), episodes_of(load_dataset(b))
    assert len(episodes_a) == len(episodes_b)
    for x, y in zip(episodes_a, episodes_b):
        assert x.keys() == y.keys()
        for key in x:
            assert np.array_equal(x[key], y[key]), key


def copy_of(reference, tmp_path):
    return shutil.copytree(reference, tmp_path / "copy")


def test_dataset_loads_with_bimgame_and_with_plain_minari(reference, monkeypatch):
    dataset = load_dataset(reference)
    assert dataset.total_episodes == 3 and dataset.spec.dataset_id == DATASET_ID
    episodes = episodes_of(dataset)
    for index, episode in enumerate(episodes):
        steps = len(episode["actions"])
        assert 1 <= steps <= 40 and episode["seed"] == episode_seed(1, index)
        assert episode["observations"].shape == (steps + 1, 7)
        assert episode["sim_state"].shape[0] == steps + 1 and episode["sim_state"].dtype == np.float64
        assert episode["channel"].shape == (steps + 1, 1)
        assert all(len(episode[k]) == steps for k in ("rewards", "terminations", "truncations"))
        assert set(np.unique(episode["actions"])) <= set(range(5))
        assert episode["terminations"][-1] or episode["truncations"][-1]
    assert dataset.total_steps == sum(len(e["actions"]) for e in episodes)
    env = dataset.recover_environment()
    assert env.spec.id == "BiMGame/STG1-v0" and env.spec.max_episode_steps == 40
    assert env.observation_space.shape == (7,)
    env.close()

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(reference / "minari"))
    plain = minari.load_dataset(DATASET_ID)
    assert DATASET_ID in minari.list_local_datasets()
    for x, y in zip(episodes, episodes_of(plain)):
        for key in x:
            assert np.array_equal(x[key], y[key]), key


def test_pixels_rendered_from_stored_states_equal_the_envs_own(reference):
    dataset = load_dataset(reference)
    seeds = [m["seed"] for m in dataset.storage.get_episode_metadata(dataset.episode_indices)]
    for sequence, seed in zip(iterate_sequences(dataset, obs="pixels"), seeds):
        env = BallInMazeEnv("STG1", obs_mode="pixels")
        obs, _ = env.reset(seed=seed)
        frames, rewards = [obs], []
        for action in sequence.actions:
            obs, reward, terminated, _, _ = env.step(int(action))
            frames.append(obs)
            rewards.append(reward)
        env.close()
        assert sequence.obs.dtype == np.uint8 and sequence.obs.shape == (len(frames) - 1, 1, 84, 84)
        assert np.array_equal(sequence.obs, np.stack(frames[:-1]))
        assert np.array_equal(sequence.rewards, rewards) and terminated == sequence.terminated


def test_same_dataset_whatever_the_number_of_workers(reference, tmp_path, monkeypatch):
    monkeypatch.setattr(generation, "BUILD_CHUNK", 2)  # also: Minari built in several writes
    assert_same_dataset(reference, generate_dataset(tmp_path / "two", workers=2, **ARGS))


def test_killed_generation_is_incomplete_and_resumes_only_the_missing_episodes(reference, tmp_path, monkeypatch):
    out = tmp_path / "run"
    # A subprocess generating with a pause before every episode after the first: killed in the pause.
    code = textwrap.dedent(f"""
        import time
        import bimgame.expert.datasets as d
        import bimgame.expert.pool as p
        from bimgame.expert.mpc import MPCConfig
        real, calls = p.run_expert_episode, []
        def slow(*args, **kwargs):
            if calls:
                time.sleep(30)
            calls.append(1)
            return real(*args, **kwargs)
        p.run_expert_episode = slow
        d.generate_dataset({str(out)!r}, "STG1", 3, seed=1, config=MPCConfig(n_samples=4, horizon=8),
                           max_steps=40, workers=1, progress=False)
    """)
    process = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.monotonic() + 60
    try:
        while not list((out / "episodes").glob("episode_*.npz")):
            assert process.poll() is None, "the generation exited early"
            assert time.monotonic() < deadline, "no episode file appeared"
            time.sleep(0.01)
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    done = sorted((out / "episodes").glob("episode_*.npz"))
    assert len(done) == 1 and not (out / "COMPLETE").exists()
    with pytest.raises(DatasetError, match=r"incomplete \(1 of 3 episode files"):
        load_dataset(out)

    mtimes = {path: path.stat().st_mtime_ns for path in done}
    calls = []
    real = parallel.run_expert_episode

    def counting(task, seed, *args, **kwargs):
        calls.append(seed)
        return real(task, seed, *args, **kwargs)
    monkeypatch.setattr(parallel, "run_expert_episode", counting)
    generate_dataset(out, workers=1, **ARGS)
    assert calls == [episode_seed(1, 1), episode_seed(1, 2)]
    assert {path: path.stat().st_mtime_ns for path in done} == mtimes
    assert_same_dataset(reference, out)


@pytest.mark.parametrize("damage", ["truncate hdf5", "flip a byte in hdf5", "truncate npz", "delete npz",
                                    "delete marker", "delete minari metadata"])
def test_damaged_dataset_raises_and_a_rerun_repairs_it(reference, tmp_path, damage):
    out = copy_of(reference, tmp_path)
    hdf5 = out / "minari" / DATASET_ID / "data" / "main_data.hdf5"
    npz = out / "episodes" / "episode_000001.npz"
    if damage == "truncate hdf5":
        os.truncate(hdf5, hdf5.stat().st_size // 2)
    elif damage == "flip a byte in hdf5":
        raw = bytearray(hdf5.read_bytes())
        raw[len(raw) // 2] ^= 0xFF
        hdf5.write_bytes(bytes(raw))
    elif damage == "truncate npz":
        os.truncate(npz, 100)
    elif damage == "delete npz":
        npz.unlink()
    elif damage == "delete marker":
        (out / "COMPLETE").unlink()
    else:
        (hdf5.parent / "metadata.json").unlink()
    expected = {"truncate hdf5": "main_data.hdf5 has", "flip a byte in hdf5": "SHA-256 mismatch",
                "truncate npz": "episode_000001.npz has 100 bytes", "delete npz": "missing episodes/episode_000001",
                "delete marker": "incomplete", "delete minari metadata": "missing minari/"}[damage]
    with pytest.raises(DatasetError, match=expected):
        load_dataset(out)
    with pytest.warns(UserWarning) if damage != "delete marker" else _no_warning():
        generate_dataset(out, workers=1, **ARGS)
    assert_same_dataset(reference, out)


class _no_warning:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_foreign_directories_are_refused_and_left_untouched(tmp_path):
    foreign = tmp_path / "foreign"
    (foreign / "sub").mkdir(parents=True)
    (foreign / "notes.txt").write_text("mine")
    (foreign / "sub" / "x.bin").write_bytes(b"\x00")
    before = sorted((p.relative_to(foreign), p.stat().st_mtime_ns) for p in foreign.rglob("*"))
    with pytest.raises(FileExistsError, match=r"not empty .* 'notes.txt', 'sub/'.*nothing was changed"):
        generate_dataset(foreign, workers=1, **ARGS)
    (foreign / "generation.json").write_text(json.dumps({"something": "else"}))
    with pytest.raises(FileExistsError, match="not a bimgame generation manifest"):
        generate_dataset(foreign, workers=1, **ARGS)
    (foreign / "generation.json").unlink()
    assert sorted((p.relative_to(foreign), p.stat().st_mtime_ns) for p in foreign.rglob("*")) == before
    assert (foreign / "notes.txt").read_text() == "mine"
    with pytest.raises(DatasetError, match="not a bimgame dataset directory"):
        load_dataset(foreign)


def test_resuming_with_other_arguments_is_refused(reference, tmp_path):
    out = copy_of(reference, tmp_path)
    marker = (out / "COMPLETE").read_bytes()
    with pytest.raises(ValueError, match=r"different arguments \(seed: 1 there, 2 now\).*another directory"):
        generate_dataset(out, workers=1, **{**ARGS, "seed": 2})
    with pytest.raises(ValueError, match="mpc_config"):
        generate_dataset(out, workers=1, **{**ARGS, "config": MPCConfig(n_samples=5, horizon=8)})
    assert (out / "COMPLETE").read_bytes() == marker
    load_dataset(out)


def test_a_finished_dataset_is_returned_as_is(reference):
    marker = (reference / "COMPLETE").read_bytes()
    start = time.perf_counter()
    assert generate_dataset(reference, workers=1, **ARGS) == reference
    assert time.perf_counter() - start < 2 and (reference / "COMPLETE").read_bytes() == marker


@pytest.mark.parametrize("change, error, message", [
    ({"episodes": 0}, ValueError, "episodes must be an integer >= 1"),
    ({"episodes": True}, ValueError, "episodes must be an integer"),
    ({"task": "STG9"}, ValueError, "unknown task 'STG9'"),
    ({"backend": "dask"}, ValueError, "unknown backend 'dask'; allowed: local, ray"),
    ({"workers": 0}, ValueError, "workers must be an integer >= 1"),
    ({"workers": 1.5}, ValueError, "workers must be an integer"),
    ({"seed": -1}, ValueError, "seed must be an integer >= 0"),
    ({"max_steps": 0}, ValueError, "max_steps must be an integer >= 1"),
    ({"ray_address": "auto"}, ValueError, "only used with backend='ray'"),
    ({"config": {"n_samples": 4}}, TypeError, "config must be an MPCConfig"),
])
def test_bad_arguments_name_the_value_and_create_nothing(tmp_path, change, error, message):
    with pytest.raises(error, match=message):
        generate_dataset(tmp_path / "new", **{**ARGS, "workers": 1, **change})
    assert not (tmp_path / "new").exists()


def test_out_dir_that_is_a_file_is_refused(tmp_path):
    path = tmp_path / "file"
    path.write_text("x")
    with pytest.raises(NotADirectoryError, match="not a directory"):
        generate_dataset(path, workers=1, **ARGS)
    assert path.read_text() == "x"
    with pytest.raises(DatasetError, match="not a directory"):
        load_dataset(path)
    with pytest.raises(DatasetError, match="does not exist"):
        load_dataset(tmp_path / "nothing")


def test_missing_ray_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r'pip install "bimgame\[ray\]"'):
        generate_dataset(tmp_path / "new", backend="ray", **ARGS)
    assert not (tmp_path / "new").exists()


class _FakeDataset:
    def __init__(self, episodes):
        self.episodes = episodes

    def iterate_episodes(self):
        return iter(self.episodes)


def test_sequences_shift_previous_actions_and_rewards_and_discount_returns(reference):
    rng = np.random.default_rng(0)
    episodes = []
    for index, (steps, terminated) in enumerate([(7, True), (5, False), (1, True)]):
        ends = np.zeros(steps, dtype=bool)
        ends[-1] = True
        episodes.append(EpisodeData(
            id=index, observations=rng.normal(size=(steps + 1, 7)).astype(np.float32),
            actions=rng.integers(5, size=steps), rewards=rng.choice([-1.0, 0.0, 1.0], size=steps),
            terminations=ends & terminated, truncations=ends & (not terminated), infos={}))
    gamma = 0.9
    sequences = list(iterate_sequences(_FakeDataset(episodes), gamma=gamma))
    assert len(sequences) == 3
    for sequence, episode in zip(sequences, episodes):
        steps = len(episode.rewards)
        direct = [sum(gamma ** (k - t) * episode.rewards[k] for k in range(t, steps)) for t in range(steps)]
        np.testing.assert_allclose(sequence.returns, direct, rtol=1e-6, atol=1e-6)
        assert sequence.prev_actions[0] == NO_ACTION == -1 and sequence.prev_rewards[0] == 0
        assert np.array_equal(sequence.prev_actions[1:], episode.actions[:-1])
        assert np.array_equal(sequence.prev_rewards[1:], episode.rewards[:-1])
        assert np.array_equal(sequence.obs, episode.observations[:-1])
        assert sequence.terminated == bool(episode.terminations[-1])
        assert sequence.truncated == bool(episode.truncations[-1])

    real = list(iterate_sequences(reference))  # a directory works too
    stored = episodes_of(load_dataset(reference))
    assert [len(s) for s in real] == [len(e["actions"]) for e in stored]
    assert all(np.array_equal(s.obs, e["observations"][:-1]) for s, e in zip(real, stored))
    with pytest.raises(ValueError, match="unknown obs 'rgb'"):
        next(iterate_sequences(reference, obs="rgb"))
    with pytest.raises(ValueError, match=r"gamma must be a number in \[0, 1\]"):
        next(iterate_sequences(reference, gamma=1.5))


def test_command_line_generate_and_summarise(reference, tmp_path, capsys):
    out = copy_of(reference, tmp_path)
    assert main(["generate", "--task", "stg1", "--episodes", "3", "--out", str(out), "--seed", "1",
                 "--workers", "1", "--n-samples", "4", "--horizon", "8", "--max-steps", "40",
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert f"{DATASET_ID} in {out}: 3 episodes" in printed and "success" in printed
    assert "per 1000 steps" in printed and "MINARI_DATASETS_PATH" in printed
    summary = dataset_summary(out)
    assert summary["bytes_minari"] > 0 and summary["bytes_episode_files"] > 0
    parser = add_generate_arguments(argparse.ArgumentParser())
    with pytest.raises(SystemExit):
        parser.parse_args(["--out", str(out), "--backend", "dask"])


def test_ray_backend_gives_the_same_dataset(reference, tmp_path):
    pytest.importorskip("ray")
    assert_same_dataset(reference, generate_dataset(tmp_path / "ray", backend="ray", workers=2, **ARGS))


def test_a_relative_output_directory_works(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = generate_dataset("relative/data", workers=1, **ARGS)
    assert out.is_absolute()
    assert load_dataset("relative/data").total_episodes == ARGS["episodes"]
    assert dataset_summary("relative/data")["episodes"] == ARGS["episodes"]


# ------------------------------------------------------------------------------------ full disk
GENERATE_ARGV = ["generate", "--task", "stg1", "--episodes", "3", "--seed", "1", "--workers", "1",
                 "--n-samples", "4", "--horizon", "8", "--max-steps", "40", "--no-progress"]

#: Makes HDF5 dataset number N of a process find the disk full (h5py's ``Group.create_dataset`` is
#: what Minari writes every array with). Used in this process and, through a ``sitecustomize``
#: module, in any Python process started from it (wherever the Minari build runs).
FULL_HDF5 = textwrap.dedent("""
    import errno
    import h5py
    _real_create_dataset = h5py.Group.create_dataset
    _created = []

    def _create_dataset(self, *args, **kwargs):
        _created.append(1)
        if len(_created) == {n}:
            raise OSError(errno.ENOSPC, "No space left on device")
        return _real_create_dataset(self, *args, **kwargs)

    h5py.Group.create_dataset = _create_dataset
""")


def _fill_disk_at(where: str, out, tmp_path, monkeypatch):
    """Make the disk full at one write of ``where``; returns the file that write makes."""
    if where == "minari build":
        hook = tmp_path / "hook"
        hook.mkdir()
        (hook / "sitecustomize.py").write_text(FULL_HDF5.format(n=5))  # in the first episode's arrays
        monkeypatch.setenv("PYTHONPATH", str(hook))
        monkeypatch.setattr(h5py.Group, "create_dataset", h5py.Group.create_dataset)  # restored afterwards
        exec(FULL_HDF5.format(n=5), {})  # and the same in this process
        return out / "minari" / DATASET_ID / "data" / "main_data.hdf5"
    real = generation.atomic_write_bytes
    target = {"episode file": out / "episodes" / "episode_000001.npz", "marker": out / "COMPLETE"}[where]

    def full_disk(path, payload):
        if Path(path) == target:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(path, payload)
    monkeypatch.setattr(generation, "atomic_write_bytes", full_disk)
    return target


@pytest.mark.parametrize("where", ["episode file", "minari build", "marker"])
def test_a_full_disk_stops_with_a_message_loses_no_episode_and_a_rerun_finishes(reference, tmp_path, monkeypatch,
                                                                                capsys, where):
    out = tmp_path / "run"
    argv = [*GENERATE_ARGV, "--out", str(out)]
    with monkeypatch.context() as patch:
        failed = _fill_disk_at(where, out, tmp_path, patch)
        assert main(argv) == 2
    error = capsys.readouterr().err
    saved = 1 if where == "episode file" else 3
    assert error == (f"bimgame generate: error: no space left on device while writing {failed}; "
                     f"rerun the same command to resume ({saved} of 3 episodes are saved)\n")
    kept = sorted((out / "episodes").glob("episode_*.npz"))
    assert [path.name for path in kept] == [f"episode_{i:06d}.npz" for i in range(saved)]
    assert not (out / "COMPLETE").exists()
    assert not list(out.glob(".minari-build-*")) and not list(out.rglob(".*.tmp"))  # nothing half-written
    with pytest.raises(DatasetError, match="incomplete"):
        load_dataset(out)

    mtimes = {path: path.stat().st_mtime_ns for path in kept}
    assert main(argv) == 0  # the disk has room again
    assert {path: path.stat().st_mtime_ns for path in kept} == mtimes  # kept, not made again
    assert_same_dataset(reference, out)


REALLY_FULL = textwrap.dedent("""
    import json, shutil, subprocess, sys
    from pathlib import Path
    mount_point, reference, copy_to, argv = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4:]
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount_point)], check=True)
    out = mount_point / "run"
    out.mkdir()
    shutil.copy(reference / "generation.json", out)  # the episodes are done: only the Minari build is left
    shutil.copytree(reference / "episodes", out / "episodes")
    command = [sys.executable, "-m", "bimgame.cli.main", *argv, "--out", str(out)]
    first = subprocess.run(command, capture_output=True, text=True)
    leftovers = sorted(path.name for path in out.iterdir() if path.name not in ("episodes", "generation.json", ".lock"))
    shutil.copytree(out, copy_to)  # the run as the full disk left it, to resume where there is room
    print(json.dumps({"code": first.returncode, "error": first.stderr, "leftovers": leftovers}))
""")


def test_a_really_full_filesystem_during_the_minari_build(reference, tmp_path):
    """The real thing: HDF5 writing onto a full filesystem (a 64 kB tmpfs, mounted in a private user
    and mount namespace) used to end in a RuntimeError or a segmentation fault with hundreds of lines
    of HDF5 errors."""
    small = tmp_path / "small"
    small.mkdir()
    namespace = ["unshare", "--user", "--map-root-user", "--mount"]
    if shutil.which("unshare") is None or subprocess.run(
            [*namespace, "mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(small)],
            capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs user and mount namespaces)")
    copy = tmp_path / "copy"
    result = subprocess.run([*namespace, sys.executable, "-c", REALLY_FULL, str(small), str(reference), str(copy),
                             *GENERATE_ARGV], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["code"] == 2, report["error"][-3000:]
    hdf5 = small / "run" / "minari" / DATASET_ID / "data" / "main_data.hdf5"
    assert report["error"].splitlines() == [
        f"bimgame generate: error: no space left on device while writing {hdf5}; "
        "rerun the same command to resume (3 of 3 episodes are saved)"], report["error"][-3000:]
    assert report["leftovers"] == []  # no partial build, no marker
    kept = sorted(copy.glob("episodes/episode_*.npz"))
    assert len(kept) == 3 and all(
        path.read_bytes() == (reference / "episodes" / path.name).read_bytes() for path in kept)
    generate_dataset(copy, workers=1, **ARGS)  # resumed where there is room
    assert_same_dataset(reference, copy)
