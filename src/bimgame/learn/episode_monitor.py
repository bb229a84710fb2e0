"""Recent training success and throughput, for a learner's progress bar and its update logs: the
success rate over the most recently *started* finished episodes (counting by end step would favour
the short, successful episodes that finish first) and environment steps per second over the last
30 seconds. Every learner that logs training episodes shares it."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["Monitor"]


class Monitor:
    """Recent training episodes (by the step they started at) and throughput, for the progress bar
    and the logs."""

    def __init__(self, start_step: int, window: int = 100):
        self.window = window
        self.episodes: list[dict] = []
        self.start_time = time.monotonic()
        self._marks: list[tuple[float, int]] = [(self.start_time, start_step)]

    def restore(self, rows: list[dict[str, str]]) -> None:
        """The episodes a resumed run logged before its checkpoint (rows of episodes.csv), so that the
        recent success continues where it was."""
        for row in rows[-4 * self.window :]:
            try:
                self.episode(
                    {
                        "start_step": int(float(row["start_step"])),
                        "return": float(row["return"]),
                        "length": int(float(row["length"])),
                        "success": row["success"] == "True",
                        "true_start": row.get("true_start", "True") != "False",
                    }
                )
            except (KeyError, ValueError):
                continue  # a row another version wrote differently: not worth refusing the resume for

    def episode(self, payload: dict) -> None:
        if not payload.get("true_start", True):
            return  # a start curriculum's episode: training success counts the task's own starts only
        self.episodes.append(payload)
        if len(self.episodes) > 4 * self.window:
            self.episodes = self.episodes[-2 * self.window :]

    def recent(self) -> dict[str, float]:
        # The most recently *started* finished episodes: counting by end step favours the short,
        # successful episodes that finish first.
        recent = sorted(self.episodes, key=lambda e: e["start_step"])[-self.window :]
        if not recent:
            return {"recent_success": float("nan"), "recent_return": float("nan"), "recent_length": float("nan")}
        return {
            "recent_success": float(np.mean([e["success"] for e in recent])),
            "recent_return": float(np.mean([e["return"] for e in recent])),
            "recent_length": float(np.mean([e["length"] for e in recent])),
        }

    def sps(self, step: int) -> float:
        now = time.monotonic()
        self._marks.append((now, step))
        while len(self._marks) > 2 and now - self._marks[0][0] > 30.0:
            self._marks.pop(0)
        (t0, s0) = self._marks[0]
        return (step - s0) / (now - t0) if now > t0 else 0.0
