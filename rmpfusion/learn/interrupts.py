"""Stopping on a signal without losing work: while a training loop runs, SIGTERM and SIGINT only set a flag, and
the loop checkpoints at the end of the current step before stopping as the signal would have."""

from __future__ import annotations

import signal
import sys
import threading
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from typing import Self  # Python 3.11; annotations only, which are not evaluated


class StopOnSignal:
    """While training, SIGTERM and SIGINT only set a flag; the loop then checkpoints at the end of the current
    step and calls ``stop``, which does what the signal would have done: exit with status 128+signum for a
    default SIGTERM, KeyboardInterrupt for a default SIGINT, or call a handler someone else installed and go on
    training if it returns (submitit's SIGTERM handler does: the job lives on until its requeue). SIGUSR1/2 are
    taken only when a Python handler is installed (submitit's preemption signal requeues the job: the checkpoint
    comes first). A second Ctrl-C stops at once."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)
    CHAINED = tuple(getattr(signal, n) for n in ("SIGUSR1", "SIGUSR2") if hasattr(signal, n))

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> Self:
        if threading.current_thread() is threading.main_thread():
            for s in self.SIGNALS + self.CHAINED:
                old = signal.getsignal(s)
                if old in (signal.SIG_IGN, None) or (s in self.CHAINED and not callable(old)):
                    continue
                self._old[s] = old
                signal.signal(s, self._handler)
        return self

    def _handler(self, signum, frame) -> None:
        if self.signum == signal.SIGINT and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum

    def __exit__(self, *exc) -> None:
        for s, old in self._old.items():
            signal.signal(s, old)
        self._old = {}

    def stop(self, where: str) -> None:
        signum, self.signum = self.signum, None
        assert signum is not None, "stop is called only after a signal arrived"
        name = signal.Signals(signum).name
        old = self._old.get(signum, signal.SIG_DFL)
        print(f"rmpfusion: {name} received; {where}", file=sys.stderr, flush=True)
        if callable(old) and old is not signal.default_int_handler:
            old(signum, None)  # someone else's handler decides; if it returns, training goes on
            return
        self.__exit__()
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)
