"""The one-line terminal status of `bag play` and `bag record`."""

from __future__ import annotations

import argparse
import sys
import time

STATUS_PERIOD = 0.2  # seconds between two updates of the terminal status line


class StatusLine:
    r"""One stderr line rewritten with \r at most five times a second (only when enabled)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._last = 0.0
        self._width = 0

    def show(self, text: str, force: bool = False) -> None:
        """Rewrite the line with ``text`` unless it was rewritten less than STATUS_PERIOD ago."""
        now = time.monotonic()
        if not self.enabled or (not force and now - self._last < STATUS_PERIOD):
            return
        self._last = now
        sys.stderr.write(f'\r{text:<{self._width}}')
        sys.stderr.flush()
        self._width = max(self._width, len(text))

    def close(self) -> None:
        """End the line so later output starts on a fresh one."""
        if self.enabled and self._width:
            sys.stderr.write('\n')
            sys.stderr.flush()


def progress_enabled(args: argparse.Namespace) -> bool:
    """Status lines only on a terminal, unless --progress asks for them."""
    return bool(args.progress or sys.stderr.isatty())
