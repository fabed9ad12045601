"""Log lines summarised instead of repeated (pure, no rclpy).

Bad input arrives in floods: one line per dropped message gave 1300 lines in 13 s. A line is
logged the first time its *kind* (the text with its numbers blanked) appears; repeats within
``period`` seconds are counted and said as one summary line when the period ends (at the next
line of that kind, or at :meth:`LogThrottle.flush`).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable

_NUMBER = re.compile(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?")


def kind_of(text: str) -> str:
    """The line with its numbers replaced by '#': lines differing only in counts, stamps or
    sizes are of one kind."""
    return _NUMBER.sub("#", text)


class LogThrottle:
    """``emit(text)`` logs through ``sink`` at most once per kind and period; :meth:`flush`
    (call it now and then, e.g. with the diagnostics) says how many were held back."""

    def __init__(self, sink: Callable[[str], None], period: float = 5.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.sink, self.period, self.clock = sink, period, clock
        self._first: dict[str, float] = {}  # kind -> time its period started
        self._held: dict[str, tuple[int, str]] = {}  # kind -> (count, latest text)

    def emit(self, text: str) -> None:
        k = kind_of(text)
        now = self.clock()
        start = self._first.get(k)
        if start is None or now - start >= self.period:
            self._first[k] = now
            n, _ = self._held.pop(k, (0, ""))
            self.sink(text if not n else self._summary(n + 1, text))
            return
        n, _ = self._held.get(k, (0, ""))
        self._held[k] = (n + 1, text)

    def flush(self, force: bool = False) -> None:
        """Say what was held back of every kind whose period is over (all of them: force)."""
        now = self.clock()
        for k in list(self._held):
            if force or now - self._first[k] >= self.period:
                n, text = self._held.pop(k)
                self._first[k] = now
                self.sink(self._summary(n, text))

    def _summary(self, n: int, text: str) -> str:
        return f"{text} ({n} like this in the last {self.period:g} s)"
