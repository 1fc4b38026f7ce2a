"""Progress of long steps: a bar on a terminal, plain periodic lines in logs."""

from __future__ import annotations

import math
import sys
import time


class Progress:
    """Progress of long steps with rate and ETA: a bar redrawn in place on a terminal; on a file or pipe
    (CI, SLURM logs) plain lines every 10 % or every 30 s, whichever comes first."""

    def __init__(self, enabled: bool = True, stream=None, every_seconds: float = 30.0):
        self.enabled = enabled
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_seconds = every_seconds
        self._state: dict[str, tuple[float, int, float]] = {}  # label -> (start, last tenth, last print time)

    def say(self, msg: str) -> None:
        if self.enabled:
            print(("\r\033[K" if self.tty else "") + msg, file=self.stream, flush=True)

    @staticmethod
    def _clock(seconds: float) -> str:
        seconds = int(max(seconds, 0))
        return (
            f"{seconds // 3600:d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"
            if seconds >= 3600
            else f"{seconds // 60:02d}:{seconds % 60:02d}"
        )

    def _line(self, label: str, done: int, total: int, elapsed: float) -> str:
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        width = 24
        filled = int(width * done / total)
        bar = "#" * filled + "." * (width - filled)
        eta_s = "--:--" if math.isnan(eta) else self._clock(eta)
        return f"{label} [{bar}] {done}/{total} {100 * done / total:3.0f}%  {rate:.1f}/s  elapsed {self._clock(elapsed)}  eta {eta_s}"

    def bar(self, label: str) -> Bar:
        """The callback ``cb(done, total)`` of the step ``label``; ``cb.stage(name)`` is the bar of a later stage of
        the same step (``label: name``), counted on its own."""
        return Bar(self, label)

    def _draw(self, label: str, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        now = time.perf_counter()
        start, last_tenth, last_print = self._state.get(label, (now, -1, 0.0))
        if done == 0 or label not in self._state:
            start, last_tenth, last_print = now, -1, 0.0
        tenth = int(10 * done / total)
        if self.tty:
            print(
                "\r\033[K" + self._line(label, done, total, now - start),
                end="\n" if done >= total else "",
                file=self.stream,
                flush=True,
            )
        elif done >= total or tenth > last_tenth or now - last_print >= self.every_seconds:
            print(self._line(label, done, total, now - start), file=self.stream, flush=True)
            last_tenth, last_print = max(tenth, last_tenth), now
        self._state[label] = (start, last_tenth, last_print)


class Bar:
    """One step's progress callback, ``bar(done, total)``. A step made of stages of different kinds (a kinematic
    rollout's records, then its collision check, sample by sample) reports each on its own bar, ``bar.stage(name)``,
    so no stage sits at 99 % of another's count while it runs; code that knows no stages just calls the bar."""

    def __init__(self, progress: Progress, label: str):
        self.progress, self.label = progress, label

    def __call__(self, done: int, total: int) -> None:
        self.progress._draw(self.label, done, total)

    def stage(self, name: str) -> Bar:
        return Bar(self.progress, f"{self.label}: {name}")
