"""Count the frames a node never received, from a companion stream that announces every frame.

A camera driver publishes one camera_info per image with the same stamp.  The
camera_info subscription is reliable and cheap, the image subscription best
effort with a short queue: an image dropped on the way or overwritten in a full
queue never reaches the node's callback, but its camera_info does.  Stamps are
in order on each stream, so once an image of stamp s arrived, every announced
stamp before s whose image did not come is lost for good.
"""

from __future__ import annotations

from collections import deque

RECENT = 512  # stamps remembered on each side: far more than any queue holds


class LostFrameCounter:
    """Matches announced stamps (camera_info) with received ones (images).

    Returns newly lost stamps.
    """

    def __init__(self, recent: int = RECENT) -> None:
        self._settled: deque[int] = deque(maxlen=recent)  # received or already counted lost
        self._settled_set: set[int] = set()
        self._waiting: set[int] = set()
        self._recent = recent
        self.newest_received: int | None = None

    def announced(self, stamp: int) -> list[int]:
        """Return a frame was announced.

        ``[stamp]`` when its image is already known lost, else [] (also for an unstamped
        announcement, stamp 0, which names no frame).
        """
        if stamp == 0 or stamp in self._settled_set or stamp in self._waiting:
            return []
        if self.newest_received is not None and stamp < self.newest_received:
            self._settle(stamp)
            return [stamp]  # a newer image came first: this one's never will
        if (
            len(self._waiting) >= self._recent
        ):  # no image for a long time: the stream is not per frame
            self._waiting.discard(min(self._waiting))
        self._waiting.add(stamp)
        return []

    def received(self, stamp: int) -> list[int]:
        """Return an image arrived.

        The announced stamps before it that had none, oldest first (now lost).
        """
        self._settle(stamp)
        self._waiting.discard(stamp)
        if self.newest_received is None or stamp > self.newest_received:
            self.newest_received = stamp
        lost = sorted(s for s in self._waiting if s < stamp)
        self._waiting.difference_update(lost)
        for s in lost:
            self._settle(s)
        return lost

    def _settle(self, stamp: int) -> None:
        """Remember ``stamp`` as accounted for (received or lost).

        Forgetting the oldest beyond ``recent``.
        """
        if stamp in self._settled_set:
            return
        if len(self._settled) == self._settled.maxlen:
            self._settled_set.discard(self._settled[0])
        self._settled.append(stamp)
        self._settled_set.add(stamp)

    def reset(self) -> None:
        """Forget everything (time jump backwards)."""
        self.__init__(self._recent)
