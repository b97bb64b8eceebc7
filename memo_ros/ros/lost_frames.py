"""Count the frames a node never received, from a companion stream that announces every frame.

A camera driver publishes one camera_info per image with the same stamp.  The
camera_info subscription is reliable and cheap, the image subscription best
effort with a short queue: an image dropped on the way or overwritten in a full
queue never reaches the node's callback, but its camera_info does.  Stamps are
in order on each stream, so once an image of stamp s arrived, every announced
stamp before s whose image did not come is lost for good.  The last images of a
stream have no newer one after them: an announcement unanswered for long is lost too.
A frame whose camera_info was lost as well shows only as a gap in the stamps of a
regular stream: :meth:`LostFrameCounter.missing` counts those.

The counter keeps the node's clock, not the wire's: only an image the node took into its
frame history (:meth:`LostFrameCounter.received`) tells which announced frames are past.  An
image it refused or dropped (a bad encoding, out of order) still answers its own announcement
(:meth:`LostFrameCounter.arrived`) but moves no clock: its stamp may be anything (a fuzzed
message stamped years ahead would otherwise make every later frame look past, and lost).
"""

from __future__ import annotations

from collections import deque
import heapq
import time

RECENT = 512  # stamps remembered on each side: far more than any queue holds
PERIODS = 16  # intervals between stamps the frame period is the median of
GAP = 1.5  # an interval this many periods long or longer has frames missing in it
REGULAR = 0.1  # a stream is regular when its last PERIODS intervals and a gap are whole periods
# within this fraction of one: only there does a gap tell frames (a player's or a software
# clock's jitter, a stall, would otherwise count frames that were never sent)


class LostFrameCounter:
    """Matches announced stamps (camera_info) with received ones (images).

    Returns newly lost stamps.
    """

    def __init__(self, recent: int = RECENT) -> None:
        self._settled: deque[int] = deque(maxlen=recent)  # received or already counted lost
        self._settled_set: set[int] = set()
        self._waiting: dict[int, float] = {}  # announced stamp -> monotonic time it came
        self._lost: set[int] = set()  # settled stamps that were counted lost
        self._recent = recent
        self.newest_received: int | None = None  # the newest image the node took: its clock
        self._newest_announced: int | None = None
        self._intervals: deque[int] = deque(maxlen=PERIODS)
        self._unchecked: list[int] = []  # heap: stamps of either stream not yet checked for gaps
        self._unchecked_set: set[int] = set()
        self._checked: int | None = None  # the newest stamp checked for a gap before it

    def announced(self, stamp: int) -> list[int]:
        """Return a frame was announced.

        ``[stamp]`` when its image is already known lost, else [] (also for an unstamped
        announcement, stamp 0, which names no frame).
        """
        if stamp == 0 or stamp in self._settled_set or stamp in self._waiting:
            return []
        self._saw(stamp)
        in_order = self._newest_announced is None or stamp >= self._newest_announced
        if in_order:
            self._newest_announced = stamp
        if in_order and self.newest_received is not None and stamp < self.newest_received:
            self._settle(stamp, lost=True)
            return [stamp]  # a newer image came first: this one's never will
        # (an announcement older than one before it starts a new timeline, a bag loop or a clock
        # set back: its image may still come, the node's clock follows once it does)
        lost = []
        if len(self._waiting) >= self._recent:  # no image for long: the stream is not per frame
            oldest = next(iter(self._waiting))  # the longest waiting
            del self._waiting[oldest]
            self._settle(oldest, lost=True)
            lost.append(oldest)
        self._waiting[stamp] = time.monotonic()
        return lost

    def missing(self) -> int:
        """Return how many more frames of a regular stream came neither as image nor camera_info.

        Both streams have passed every stamp up to the older of their newest (the images' as the
        node took them): there, consecutive stamps of either stream a whole number (2 or more) of
        frame periods apart have frames missing between them, the period being the median of the
        last intervals, all within ``REGULAR`` of it.  0 until the period is known, and while the
        stream is not regular.
        """
        if self._newest_announced is None or self.newest_received is None:
            return 0
        mark = min(self._newest_announced, self.newest_received)
        count = 0
        while self._unchecked and self._unchecked[0] <= mark:
            stamp = heapq.heappop(self._unchecked)
            self._unchecked_set.discard(stamp)
            if self._checked is not None:
                count += self._frames_within(stamp - self._checked)
            self._checked = stamp
        return count

    def _frames_within(self, interval: int) -> int:
        """Return the frames missing within ``interval`` (ns) between two stamps that came."""
        period = self._period()
        if period and interval >= GAP * period:
            periods = round(interval / period)
            if abs(interval - periods * period) <= REGULAR * period:
                return periods - 1
        self._intervals.append(interval)
        return 0

    def _period(self) -> int | None:
        """Return the frame period: the median of the last intervals, if all are within REGULAR."""
        if len(self._intervals) < PERIODS:
            return None
        ordered = sorted(self._intervals)
        median = ordered[PERIODS // 2]
        spread = max(ordered[-1] - median, median - ordered[0])
        return median if spread <= REGULAR * median else None

    def _saw(self, stamp: int) -> None:
        """Remember a stamp of either stream for :meth:`missing` (a bounded number of them)."""
        if (self._checked is not None and stamp <= self._checked) or stamp in self._unchecked_set:
            return
        if len(self._unchecked) >= 2 * self._recent:  # far ahead of one stream: search anew
            self._unchecked.clear()
            self._unchecked_set.clear()
            self._checked = None
            self._intervals.clear()
        heapq.heappush(self._unchecked, stamp)
        self._unchecked_set.add(stamp)

    def received(self, stamp: int) -> list[int]:
        """Return the node took an image into its frame history (its clock is now at least there).

        The announced stamps before it that had none, oldest first (now lost).
        """
        self._settle(stamp)
        self._waiting.pop(stamp, None)
        self._saw(stamp)
        if self.newest_received is None or stamp > self.newest_received:
            self.newest_received = stamp
        lost = sorted(s for s in self._waiting if s < stamp)
        for s in lost:
            del self._waiting[s]
            self._settle(s, lost=True)
        return lost

    def arrived(self, stamp: int) -> None:
        """Note an image the node did not take into its frame history (refused, out of order).

        It answers its own announcement (the node counts it under its own reason) but moves no
        clock and shows no other frame lost: its stamp is not trusted.
        """
        if stamp == 0:
            return
        self._waiting.pop(stamp, None)
        self._settle(stamp)
        self._saw(stamp)

    def expired(self, age: float, now: float | None = None) -> list[int]:
        """Return the announced stamps whose image has not come within ``age`` seconds (now lost).

        Oldest first.
        """
        now = time.monotonic() if now is None else now
        lost = []
        for s, came in self._waiting.items():  # in the order they came
            if now - came <= age:
                break
            lost.append(s)
        for s in lost:
            del self._waiting[s]
            self._settle(s, lost=True)
        return sorted(lost)

    def counted_lost(self, stamp: int) -> bool:
        """Return whether ``stamp`` was already counted lost (its image came too late)."""
        return stamp in self._lost

    def _settle(self, stamp: int, lost: bool = False) -> None:
        """Remember ``stamp`` as accounted for (received or lost).

        Forgetting the oldest beyond ``recent``.
        """
        if stamp in self._settled_set:
            return
        if len(self._settled) == self._settled.maxlen:
            oldest = self._settled[0]
            self._settled_set.discard(oldest)
            self._lost.discard(oldest)
        self._settled.append(stamp)
        self._settled_set.add(stamp)
        if lost:
            self._lost.add(stamp)

    def reset(self) -> list[int]:
        """Start a new timeline (the node's clock jumped back); return the stamps now lost.

        Those are the announcements of the old timeline newer than its last image, which no image
        will answer; announcements before it belong to the new timeline and keep waiting (any of
        the old one's there were counted lost already).  The rest is forgotten, so that the new
        timeline may repeat the old one's stamps (a bag played again).
        """
        clock, waiting = self.newest_received, self._waiting
        self.__init__(self._recent)
        lost = sorted(s for s in waiting if clock is not None and s >= clock)
        for s in lost:
            del waiting[s]
        self._waiting = waiting
        return lost
