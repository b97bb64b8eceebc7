"""Frame decimation that every node of the graph applies alike.

Under overload each node that dropped frames on its own (a full DDS queue, a late update) would
drop different ones, and the tracker would see few frames with every camera. Instead the tracker
announces a decimation: keep every ``every``-th frame, counted on a grid of ``period_ns`` from a
frame stamp ``origin_ns``, from stamp ``from_ns`` on. The announcement goes out ahead of the frames
it concerns, so each contour node, the selector and the tracker keep exactly the same frames.
"""

from __future__ import annotations

from dataclasses import dataclass

CHANGES_KEPT = 8  # announcements remembered: frames still in flight use the one of their stamp


@dataclass(frozen=True)
class Decimation:
    """Keep one frame in ``every`` from stamp ``from_ns`` on.

    The kept frames are those an integer number of ``every * period_ns`` from ``origin_ns`` (a
    kept frame's stamp), rounded to the nearest frame, so stamps jittered by less than a quarter
    period each are kept as if they were regular.
    """

    from_ns: int = 0
    every: int = 1
    period_ns: int = 0
    origin_ns: int = 0

    def keeps(self, stamp_ns: int) -> bool:
        """Whether the frame stamped ``stamp_ns`` is processed."""
        if self.every <= 1 or self.period_ns <= 0:
            return True
        index = round((stamp_ns - self.origin_ns) / self.period_ns)
        return index % self.every == 0

    def to_text(self) -> str:
        """Return the announcement's text (std_msgs/Header frame_id; its stamp is ``from_ns``)."""
        return f'every={self.every} period_ns={self.period_ns} origin_ns={self.origin_ns}'

    @classmethod
    def from_text(cls, from_ns: int, text: str) -> Decimation:
        """Parse an announcement; ValueError names what is wrong with it."""
        fields = dict(item.partition('=')[::2] for item in text.split())
        try:
            every = int(fields['every'])
            period_ns = int(fields['period_ns'])
            origin_ns = int(fields['origin_ns'])
        except (KeyError, ValueError) as exc:
            raise ValueError(f'not a decimation: {text!r}') from exc
        if every < 1 or period_ns < 0:
            raise ValueError(f'every must be >= 1 and period_ns >= 0: {text!r}')
        return cls(from_ns, every, period_ns, origin_ns)


class DecimationSchedule:
    """The decimations announced so far, each in force from its stamp on."""

    def __init__(self) -> None:
        self.changes: list[Decimation] = []

    def add(self, decimation: Decimation) -> None:
        """Take an announcement; one from the same or a later stamp replaces what it overlaps."""
        kept = [d for d in self.changes if d.from_ns < decimation.from_ns]
        self.changes = [*kept, decimation][-CHANGES_KEPT:]

    def at(self, stamp_ns: int) -> Decimation:
        """Return the decimation in force for the frame stamped ``stamp_ns``."""
        for decimation in reversed(self.changes):
            if decimation.from_ns <= stamp_ns:
                return decimation
        return Decimation()

    def keeps(self, stamp_ns: int) -> bool:
        """Whether the frame stamped ``stamp_ns`` is processed."""
        return self.at(stamp_ns).keeps(stamp_ns)

    def clear(self) -> None:
        """Forget every announcement (the stamps jumped back: a new timeline)."""
        self.changes.clear()
