from __future__ import annotations

import csv
import errno
import os
import pickle

import numpy as np
import pytest
import torch

import bimgame.learn.runs as runs
from bimgame.learn.checkpoints import CheckpointError, load_checkpoint, load_weights, save_checkpoint
from bimgame.learn.metric_logs import CsvLog, MetricLog, resumed_rows
from bimgame.learn.runs import discard_new_run, prepare_new_run
from bimgame.util import files
from bimgame.util.files import FileWriteError


def test_checkpoint_round_trip(tmp_path):
    model = torch.nn.Linear(3, 2)
    optimizer = torch.optim.RMSprop(model.parameters(), lr=1e-3)
    model(torch.randn(4, 3, generator=torch.Generator().manual_seed(0))).sum().backward()
    optimizer.step()
    path = save_checkpoint(tmp_path / "c.pt", model=model.state_dict(), optimizer=optimizer.state_dict(),
                           step=1234, config='{"a": 1}')
    payload = load_checkpoint(path)
    assert payload["step"] == 1234 and payload["config"] == '{"a": 1}'
    fresh = torch.nn.Linear(3, 2)
    assert load_weights(fresh, tmp_path / "c.pt") == 1234
    for a, b in zip(model.parameters(), fresh.parameters()):
        torch.testing.assert_close(a, b)
    other = torch.optim.RMSprop(fresh.parameters(), lr=1e-3)
    other.load_state_dict(payload["optimizer"])
    torch.testing.assert_close(other.state_dict()["state"][0]["square_avg"],
                               optimizer.state_dict()["state"][0]["square_avg"])
    assert not list(tmp_path.glob(".*.tmp")), "atomic write leaves no temporary file"


class _Payload:
    """Unpickling this object would create a file: proof that code ran."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_malicious_pickle_checkpoint_is_refused(tmp_path):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pt"
    torch.save({"format": "bimgame-checkpoint-1", "model": {}, "step": 0, "x": _Payload(marker)}, path)
    with pytest.raises(CheckpointError, match="refused to load"):
        load_checkpoint(path)
    assert not marker.exists()
    # A plain pickle file (not even a torch archive) is refused too, without running it.
    path.write_bytes(pickle.dumps(_Payload(marker)))
    with pytest.raises(CheckpointError):
        load_checkpoint(path)
    assert not marker.exists()


def test_bad_checkpoints_are_named(tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint at"):
        load_checkpoint(tmp_path / "missing.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not a bimgame checkpoint"):
        load_checkpoint(tmp_path / "foreign.pt")
    (tmp_path / "truncated.pt").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(CheckpointError, match="cannot read checkpoint"):
        load_checkpoint(tmp_path / "truncated.pt")
    save_checkpoint(tmp_path / "nan.pt", model={"w": torch.tensor([1.0, float("nan")])}, step=3)
    with pytest.raises(CheckpointError, match="not finite"):
        load_checkpoint(tmp_path / "nan.pt")
    save_checkpoint(tmp_path / "small.pt", model=torch.nn.Linear(2, 2).state_dict(), step=3)
    with pytest.raises(CheckpointError, match="shape mismatch"):
        load_weights(torch.nn.Linear(3, 2), tmp_path / "small.pt")


def test_a_maze_network_of_the_old_layout_is_named(tmp_path):
    """A network that read the maze encoding as plain inputs (stored before NetConfig.maze_size) does
    not start a network that reads it through weights of its own: the error says why."""
    from bimgame.learn.nets import NetConfig, build_network

    old = build_network(NetConfig(encoder="mlp", obs_shape=(135,), features=8, hidden=8))
    save_checkpoint(tmp_path / "old.pt", model=old.state_dict(), step=3)
    new = build_network(NetConfig(encoder="mlp", obs_shape=(135,), features=8, hidden=8, maze_size=128))
    with pytest.raises(CheckpointError, match="read it as plain inputs and cannot start new runs"):
        load_weights(new, tmp_path / "old.pt")


def test_resumed_rows_keep_what_was_logged_before_the_checkpoint(tmp_path):
    """Rows at exactly the checkpoint's step came after it (e.g. episodes that ended in the segment
    the checkpoint did not include) and are dropped, unless the table logs such rows before writing
    the checkpoint (``keep_equal``: A3C's updates, DAgger's iterations)."""
    log = CsvLog(tmp_path / "x.csv", ["step", "value"])
    for step in (10, 20, 30):
        log.write({"step": step, "value": step / 10})
    log.close()
    assert [r["step"] for r in resumed_rows(tmp_path / "x.csv", ["step", "value"], 20)] == ["10"]
    kept = resumed_rows(tmp_path / "x.csv", ["step", "value"], 20, keep_equal=True)
    assert kept == [{"step": "10", "value": "1"}, {"step": "20", "value": "2"}]
    log = CsvLog(tmp_path / "x.csv", ["step", "value"], rows=kept)
    log.write({"step": 25, "value": 0.5})
    log.close()
    with open(tmp_path / "x.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["step"]) for r in rows] == [10, 20, 25]
    assert resumed_rows(tmp_path / "missing.csv", ["step", "value"], 20) == []


def test_torch_threads_restores_and_never_exceeds_the_callers_setting():
    from bimgame.learn.runs import torch_threads

    previous = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        with torch_threads() as count:
            assert count == 1 and torch.get_num_threads() == 1
        with torch_threads(2):
            assert torch.get_num_threads() == 2
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(previous)


# ------------------------------------------------------------------------- resuming logs
def test_a_log_with_another_header_is_refused_not_emptied(tmp_path):
    path = tmp_path / "episodes.csv"
    path.write_text("step,start,reward\r\n10,0,1\r\n")
    with pytest.raises(ValueError) as refused:
        resumed_rows(path, ["step", "start", "return"], 100)
    message = str(refused.value)
    assert str(path) in message and "step,start,reward" in message and "step,start,return" in message
    path.write_text("")
    with pytest.raises(ValueError, match=r"header \(none: empty\)"):
        resumed_rows(path, ["step", "value"], 100)


def test_a_row_cut_off_by_a_kill_is_dropped_and_a_damaged_row_refused(tmp_path):
    path = tmp_path / "x.csv"
    path.write_text("step,value\r\n10,1\r\n20,2\r\n3")  # killed while writing "30,3"
    assert [r["step"] for r in resumed_rows(path, ["step", "value"], 100)] == ["10", "20"]
    path.write_text("step,value\r\n10,1\r\n20\r\n30,3\r\n")
    with pytest.raises(ValueError, match=r"x.csv line 3 has 1 fields, its header 2"):
        resumed_rows(path, ["step", "value"], 100)
    path.write_text("step,value\r\n10,1\r\nlater,2\r\n")
    with pytest.raises(ValueError, match=r"x.csv line 3: step 'later' is not a number"):
        resumed_rows(path, ["step", "value"], 100)


def test_metric_log_checks_every_table_before_rewriting_any(tmp_path):
    (tmp_path / "a.csv").write_text("step,x\r\n1,1\r\n5,5\r\n")
    (tmp_path / "b.csv").write_text("step,other\r\n1,1\r\n")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(ValueError, match="b.csv"):
        MetricLog(tmp_path, {"a": ["x"], "b": ["y"]}, resume_step=3, tensorboard=False)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


# ------------------------------------------------------------------------- full disks
def _no_space(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_writes_that_fail_name_the_file(tmp_path, monkeypatch):
    log = CsvLog(tmp_path / "x.csv", ["step", "value"])

    class FullDisk:
        def write(self, text):
            _no_space()

        def flush(self):
            _no_space()

        def close(self):
            _no_space()
    log._handle = FullDisk()
    log._writer = csv.DictWriter(log._handle, log.fields)
    with pytest.raises(FileWriteError, match=rf"cannot write {tmp_path / 'x.csv'}: No space left on device"):
        log.write({"step": 1, "value": 2})
    log.close()  # the failure was reported once; closing does not raise it again
    monkeypatch.setattr(files, "atomic_write_bytes", _no_space)  # what every writer of a run uses
    with pytest.raises(FileWriteError, match=rf"cannot write {tmp_path / 'c.pt'}: No space left on device"):
        save_checkpoint(tmp_path / "c.pt", model={"w": torch.zeros(2)}, step=1)
    with pytest.raises(FileWriteError, match="summary.json: No space left on device. Resume later"):
        try:
            runs.write_run_json(tmp_path / "summary.json", {"a": 1})
        except FileWriteError as error:
            raise error.with_advice("Resume later")
    assert isinstance(FileWriteError("x", "y"), OSError)


# ------------------------------------------------------------------------- checkpoints
class _Code:
    def __reduce__(self):
        # os.system, not print: a library imported earlier in the process (Ray) may replace print.
        return (os.system, ("true",))


def test_checkpoint_messages_say_why_and_never_pass_on_torchs_advice(tmp_path):
    """torch's own message says to load with weights_only=False — that would run the file's code."""
    full = save_checkpoint(tmp_path / "full.pt", model=torch.nn.Linear(30, 30).state_dict(), step=1)
    random_bytes = np.random.default_rng(0).integers(0, 256, size=300, dtype=np.uint8).tobytes()
    files = {"empty.pt": b"", "random.pt": random_bytes, "pickle.pt": pickle.dumps(_Code()),
             "truncated.pt": full.read_bytes()[:400]}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    torch.save({"x": _Code()}, tmp_path / "code.pt")
    expected = {"empty.pt": "the file is empty", "random.pt": "not a PyTorch checkpoint, or it is damaged",
                "pickle.pt": "not a PyTorch checkpoint, or it is damaged", "truncated.pt": "it is truncated",
                "code.pt": f"holds objects other than tensors and plain data ({os.name}.system); loading such a file "
                           "could run code, so bimgame never does"}
    for name, says in expected.items():
        with pytest.raises(CheckpointError) as refused:
            load_checkpoint(tmp_path / name)
        message = str(refused.value)
        assert str(tmp_path / name) in message and says in message, message
        assert "weights_only" not in message and "trusted" not in message and "safe_globals" not in message, message
        assert "\n" not in message


def test_any_damaged_bytes_are_refused_as_a_damaged_checkpoint(tmp_path):
    """Random bytes make torch's unpickler raise IndexError, KeyError or struct.error about 7% of the
    time, not only UnpicklingError; every one must still come out as a CheckpointError naming the file."""
    rng = np.random.default_rng(3)
    path = tmp_path / "damaged.pt"
    for _ in range(300):
        path.write_bytes(rng.integers(0, 256, size=int(rng.integers(1, 600)), dtype=np.uint8).tobytes())
        with pytest.raises(CheckpointError) as refused:
            load_checkpoint(path)
        assert str(path) in str(refused.value)


# ------------------------------------------------------------------------- run directories
def test_new_runs_go_into_new_or_empty_directories_only(tmp_path):
    assert prepare_new_run(tmp_path / "new", what="A3C", flag="--run-dir", kind="a3c") is True
    (tmp_path / "empty").mkdir()
    assert prepare_new_run(tmp_path / "empty", what="A3C", flag="--run-dir", kind="a3c") is False
    (tmp_path / "empty" / ".config.json.x1y2.tmp").write_text("")  # a temporary left by a kill
    assert prepare_new_run(tmp_path / "empty", what="A3C", flag="--run-dir", kind="a3c") is False
    many = tmp_path / "many"
    many.mkdir()
    for i in range(7):
        (many / f"f{i}").write_text("")
    (many / "sub").mkdir()
    with pytest.raises(ValueError, match=r"found 8 entries: 'f0', 'f1', 'f2', 'f3', 'f4', …\); nothing was changed"):
        prepare_new_run(many, what="pre-training", flag="--out")


def test_discarding_a_failed_new_run_removes_only_its_own_files(tmp_path):
    run_dir = tmp_path / "run"
    (run_dir / "tb").mkdir(parents=True)
    for name in ("config.json", "checkpoint.pt", ".checkpoint.pt.abc.tmp", "tb/events", "mine.txt"):
        (run_dir / name).write_text("x")
    discard_new_run(run_dir, True, ["config.json", "checkpoint.pt", "tb", "episodes.csv"])
    assert [p.name for p in run_dir.iterdir()] == ["mine.txt"]
    (run_dir / "mine.txt").unlink()
    discard_new_run(run_dir, False, ["config.json"])
    assert run_dir.is_dir()  # it existed before the run: kept, empty
    discard_new_run(run_dir, True, ["config.json"])
    assert not run_dir.exists()
