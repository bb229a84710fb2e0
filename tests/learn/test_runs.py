from __future__ import annotations

import csv
import pickle

import pytest
import torch

from bimgame.learn.runs import CheckpointError, CsvLog, load_checkpoint, load_weights, save_checkpoint


def test_checkpoint_round_trip(tmp_path):
    model = torch.nn.Linear(3, 2)
    optimizer = torch.optim.RMSprop(model.parameters(), lr=1e-3)
    model(torch.randn(4, 3)).sum().backward()
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


def test_csv_log_resume_drops_rows_after_the_checkpoint(tmp_path):
    log = CsvLog(tmp_path / "x.csv", ["step", "value"])
    for step in (10, 20, 30):
        log.write({"step": step, "value": step / 10})
    log.close()
    log = CsvLog(tmp_path / "x.csv", ["step", "value"], keep_until=20)
    log.write({"step": 25, "value": 0.5})
    log.close()
    with open(tmp_path / "x.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["step"]) for r in rows] == [10, 20, 25]


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
