"""A one-line terminal progress indicator for long tool runs."""

from __future__ import annotations

import sys
import time


class Progress:
    """Rewrites one stderr line (at most 5 times a second) with done/total, rate and ETA."""

    def __init__(self, total: int, label: str, enabled: bool = True) -> None:
        self.total, self.label, self.enabled = max(total, 1), label, enabled
        self._start = time.monotonic()
        self._last = 0.0

    def update(self, done: int) -> None:
        """Show ``done`` items on the status line.

        Only on a terminal, and at most a few times a second.
        """
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < 0.2 and done < self.total:
            return
        self._last = now
        elapsed = now - self._start
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else 0.0
        sys.stderr.write(
            f'\r{self.label}: {done}/{self.total} ({100 * done / self.total:3.0f}%) '
            f'{rate:.1f}/s, {eta:.0f} s left '
        )
        sys.stderr.flush()

    def close(self) -> None:
        """End the status line."""
        if self.enabled:
            sys.stderr.write('\n')
            sys.stderr.flush()
