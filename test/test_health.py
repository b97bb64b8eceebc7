"""NodeHealth's log lines: throttled once per reason, every drop still counted."""

from __future__ import annotations

from memo_ros.ros import health
from memo_ros.ros.health import NodeHealth


class _Logger:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def warning(self, message: str, **_) -> None:
        self.lines.append(message)

    info = warning


class _Node:
    """The parts of a node NodeHealth uses, with a logger that keeps every line."""

    def __init__(self) -> None:
        self.logger = _Logger()

    def get_logger(self) -> _Logger:
        return self.logger

    def create_publisher(self, *_):
        return None

    def create_timer(self, *_):
        return None


def test_each_reason_logs_once_per_throttle_period_and_every_drop_is_counted(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(health.time, 'monotonic', lambda: now[0])
    node = _Node()
    h = NodeHealth(node, 'test')  # type: ignore[arg-type]
    h.drop('image_lost', 'an image was lost')
    h.drop('stamp_not_newer', 'a stamp went back')  # another reason: its own line
    h.drop('image_lost', 'an image was lost')  # within the period: counted, not logged
    h.note('reset', 'a reset')
    assert node.logger.lines == [
        'an image was lost [dropped: image_lost, 1 so far]',
        'a stamp went back [dropped: stamp_not_newer, 1 so far]',
        'a reset',
    ]
    now[0] += health.LOG_THROTTLE_S
    h.drop('image_lost', 'an image was lost')
    assert node.logger.lines[-1] == 'an image was lost [dropped: image_lost, 3 so far]'
    assert h.dropped == {'image_lost': 3, 'stamp_not_newer': 1}
