"""The tracker's choice of decimation from the load it sees.

A live graph that cannot process every frame should stay on time with fewer frames rather than
fall behind with all of them. Decimation helps only where frames queue: a frame that waited for
the tracker behind a newer one, or that lacked a camera's contours (a contour node behind loses
images). The governor raises the decimation (keep one frame in 2, 3, ...) while the last frames
were all later than the target and each of them had queued so, and lowers it again after a calm
spell in which nothing queued and the tracker, busy a fraction u of the time, would stay under
``max_load`` with the frames kept again (u * every / (every - 1)). A lowering that is undone
soon doubles the next calm spell, so a graph at the edge of its capacity does not oscillate.
Latency that does not come from queueing (transport, a contour node's own pace) is not shed.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from memo_ros.core.latency.decimation import Decimation

PERIOD_STAMPS = 31  # recent frame stamps the frame period is the median step of
MAX_CALM_S = 60.0
LOAD_WINDOW_S = 2.0  # the tracker's busy fraction is measured over this much wall time


@dataclass(frozen=True)
class GovernorSettings:
    """How the decimation follows the load."""

    latency_target_s: float = 0.08  # the last `window` frames all later than this, queued: raise
    min_rate_hz: float = 20.0  # never fewer frames a second kept (the motion between them grows)
    window: int = 5
    max_load: float = 0.7  # the tracker's busy fraction a lowering must stay under
    settle_s: float = 0.5  # no change for this long after one: frames in flight are the old ones
    calm_s: float = 3.0  # nothing queued this long (and the load allows) lowers the decimation
    lead_s: float = 0.2  # a change applies to stamps this far past the newest heard of


@dataclass(frozen=True)
class FrameLoad:
    """What one processed frame says about the load."""

    latency_s: float  # first heard of to processed (wall clock)
    busy_s: float  # the tracker's wall time on it
    queued: bool  # a newer kept frame waited meanwhile, or a camera's contours were missing


class LatencyGovernor:
    """Decides the decimation the tracker announces to the graph."""

    def __init__(self, settings: GovernorSettings) -> None:
        self.settings = settings
        self.current = Decimation()
        self.stamps: deque[int] = deque(maxlen=PERIOD_STAMPS)
        self.recent: deque[FrameLoad] = deque(maxlen=settings.window)
        self.busy: deque[tuple[float, float]] = deque()  # (end time, busy seconds)
        self.changed_at: float | None = None
        self.calm_s = settings.calm_s
        self.lowered_at: float | None = None
        self.calm_since: float | None = None

    def heard(self, stamp_ns: int) -> None:
        """Note a frame's stamp (any message of it): the frame period comes from them."""
        if not self.stamps or stamp_ns > self.stamps[-1]:
            self.stamps.append(stamp_ns)

    def period_ns(self) -> int:
        """Return the median step between the frame stamps heard of, 0 while unknown."""
        if len(self.stamps) < 3:
            return 0
        return int(np.median(np.diff(np.asarray(self.stamps, np.int64))))

    def restart(self) -> None:
        """Forget the recent frames (a start, a reset): its backlog says nothing of the load."""
        self.recent.clear()
        self.busy.clear()
        self.calm_since = None

    def processed(self, frame: FrameLoad, now: float) -> None:
        """Note a processed frame at monotonic time ``now``."""
        self.recent.append(frame)
        self.busy.append((now, frame.busy_s))
        while self.busy and now - self.busy[0][0] > LOAD_WINDOW_S:
            self.busy.popleft()
        if frame.queued:
            self.calm_since = None
        elif self.calm_since is None:
            self.calm_since = now

    def load(self, now: float) -> float:
        """Return the tracker's busy fraction over the last LOAD_WINDOW_S."""
        if not self.busy:
            return 0.0
        span = max(now - self.busy[0][0] + self.busy[0][1], 1e-3)
        return sum(b for _, b in self.busy) / span

    def decide(self, now: float) -> Decimation | None:
        """Return a new decimation to announce, or None to keep the current one."""
        s = self.settings
        most = self.most_every()
        # capped lower only when the rate clearly changed, not by a period's jitter
        allowed = 1 if s.latency_target_s <= 0 else min(self.current.every, self.most_every(0.5))
        if allowed != self.current.every:  # the policy was switched off or capped lower
            return self._change(allowed, now)
        if s.latency_target_s <= 0 or not self.stamps:
            return None
        if self.changed_at is not None and now - self.changed_at < s.settle_s:
            return None
        every = self.current.every
        if self._queueing() and every < most:
            if self.lowered_at is not None and now - self.lowered_at < 2 * self.calm_s:
                self.calm_s = min(2 * self.calm_s, MAX_CALM_S)  # that lowering was too soon
            return self._change(every + 1, now)
        calm = self.calm_since is not None and now - self.calm_since >= self.calm_s
        if every > 1 and calm and self.load(now) * every / (every - 1) < s.max_load:
            if self.lowered_at is not None and now - self.lowered_at > 4 * self.calm_s:
                self.calm_s = s.calm_s  # the last lowering held
            self.lowered_at = now
            return self._change(every - 1, now)
        return None

    def most_every(self, slack: float = 0.05) -> int:
        """Return the largest decimation that keeps min_rate_hz frames a second (1 at least).

        ``slack``: the fraction of a frame the quotient may fall short (a period a few per cent
        long, stamp jitter, must not cap it one lower).
        """
        period = self.period_ns()
        if period <= 0:
            return 1
        return max(1, int(1e9 / (period * self.settings.min_rate_hz) + slack))

    def _queueing(self) -> bool:
        """Whether each of the last `window` frames was late and had queued."""
        recent = self.recent
        if len(recent) < (recent.maxlen or 1):
            return False
        target = self.settings.latency_target_s
        return all(f.queued and f.latency_s > target for f in recent)

    def _change(self, every: int, now: float) -> Decimation | None:
        period = self.period_ns()
        if period <= 0:
            return None
        origin = self.stamps[-1]
        lead = max(int(self.settings.lead_s * 1e9), 3 * period)
        self.current = Decimation(origin + lead, every, period, origin)
        self.changed_at = now
        self.recent.clear()
        self.calm_since = None
        return self.current
