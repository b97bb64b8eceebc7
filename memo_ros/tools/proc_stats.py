"""Process helpers of the process benchmarks.

CPU time, peak memory and children from /proc (Linux), stop, log tail.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess

CLOCK_TICKS = os.sysconf('SC_CLK_TCK')


def _stat_fields(pid: int) -> list[str]:
    """Fields 3 onwards of /proc/<pid>/stat (after the command name, which may hold spaces)."""
    with open(f'/proc/{pid}/stat') as f:
        return f.read().rsplit(')', 1)[1].split()


def cpu_seconds(pid: int) -> float:
    """Utime + stime of process ``pid``, seconds."""
    fields = _stat_fields(pid)
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # fields 14 and 15 of proc(5)


def _status_mb(pid: int, key: str) -> float | None:
    with open(f'/proc/{pid}/status') as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0
    return None


def peak_rss_mb(pid: int) -> float | None:
    """VmHWM of process ``pid``, MB (None when unavailable)."""
    return _status_mb(pid, 'VmHWM:')


def rss_mb(pid: int) -> float | None:
    """VmRSS of process ``pid`` now, MB (None when unavailable)."""
    return _status_mb(pid, 'VmRSS:')


def children(pid: int) -> dict[int, list[str]]:
    """Return the live child processes of ``pid``: child pid -> its command line."""
    found = {}
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if (
                int(_stat_fields(int(entry.name))[1]) != pid
            ):  # field 4 of proc(5): the parent's pid
                continue
            command = (entry / 'cmdline').read_bytes().split(b'\0')
        except (OSError, IndexError, ValueError):  # ended meanwhile
            continue
        found[int(entry.name)] = [word.decode(errors='replace') for word in command if word]
    return found


def stop_process(process: subprocess.Popen, timeout: float = 5.0) -> None:
    """SIGINT (a clean shutdown), then SIGKILL if it lingers past ``timeout`` s."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=5)


def log_tail(log: Path, lines: int = 10) -> str:
    """Return the last ``lines`` lines of a process's log file ('' when unreadable)."""
    try:
        return '\n'.join(log.read_text(errors='replace').splitlines()[-lines:])
    except OSError:
        return ''
