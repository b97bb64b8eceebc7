"""The live latency policy's core: the decimation every node applies alike, and the governor."""

from __future__ import annotations

import numpy as np
import pytest

from memo_ros.core.latency.decimation import Decimation, DecimationSchedule
from memo_ros.core.latency.governor import FrameLoad, GovernorSettings, LatencyGovernor

PERIOD = 33_333_333  # 30 Hz, ns
T0 = 1_700_000_000_000_000_000


def stamps(n: int, start: int = T0, jitter: float = 0.0, seed: int = 0) -> np.ndarray:
    """Frame stamps at 30 Hz, each moved by up to ``jitter`` of a period."""
    noise = np.random.default_rng(seed).uniform(-jitter, jitter, n) * PERIOD
    return start + np.arange(n, dtype=np.int64) * PERIOD + noise.astype(np.int64)


def test_decimation_keeps_every_nth_frame_through_stamp_jitter():
    s = stamps(300, jitter=0.24)
    d = Decimation(from_ns=0, every=3, period_ns=PERIOD, origin_ns=int(s[0]))
    kept = np.array([d.keeps(int(t)) for t in s])
    assert np.array_equal(np.flatnonzero(kept), np.arange(0, 300, 3))
    assert all(Decimation().keeps(int(t)) for t in s)  # the default keeps every frame


def test_announcement_text_round_trips_and_refuses_garbage():
    d = Decimation(from_ns=T0 + 5, every=4, period_ns=PERIOD, origin_ns=T0)
    assert Decimation.from_text(d.from_ns, d.to_text()) == d
    for bad in ('', 'every=two period_ns=1 origin_ns=0', 'every=0 period_ns=1 origin_ns=0'):
        with pytest.raises(ValueError):
            Decimation.from_text(0, bad)


def test_schedule_applies_each_announcement_from_its_stamp():
    s = [int(t) for t in stamps(120)]
    schedule = DecimationSchedule()
    schedule.add(Decimation(s[30], 2, PERIOD, s[24]))
    schedule.add(Decimation(s[90], 1, PERIOD, s[84]))
    kept = [k for k, t in enumerate(s) if schedule.keeps(t)]
    assert kept == list(range(30)) + list(range(30, 90, 2)) + list(range(90, 120))
    # an announcement from an earlier stamp replaces the ones it overlaps
    schedule.add(Decimation(s[60], 3, PERIOD, s[54]))
    assert [schedule.at(t).every for t in (s[29], s[59], s[60], s[119])] == [1, 2, 3, 3]
    schedule.clear()
    assert all(schedule.keeps(t) for t in s)


def feed(
    governor: LatencyGovernor,
    frame_stamps,
    latency: float,
    now: float,
    queued: bool = True,
    busy: float = 0.02,
    rate: float = 30,
):
    """Hear frames at ``rate`` frames/s of wall time, process the kept ones; the decisions."""
    decisions = []
    for t in frame_stamps:
        governor.heard(int(t))
        if governor.current.keeps(int(t)):
            governor.processed(FrameLoad(latency, busy, queued), now)
        decision = governor.decide(now)
        if decision is not None:
            decisions.append((now, int(t), decision))
        now += 1 / rate
    return decisions, now


def test_governor_sheds_while_frames_queue_and_keeps_more_again_when_calm():
    settings = GovernorSettings(latency_target_s=0.08, min_rate_hz=7.5)
    governor = LatencyGovernor(settings)
    s = stamps(600, jitter=0.1)
    decisions, now = feed(governor, s[:150], latency=0.3, now=0.0)
    everies = [d.every for _, _, d in decisions]
    assert everies == [2, 3, 4]  # one step per settle_s, down to 7.5 of 30 frames a second
    for when, newest, d in decisions:
        assert d.from_ns > newest  # announced ahead of the frames it concerns
        assert d.period_ns == pytest.approx(PERIOD, rel=0.05)
    # nothing queues, and at 20 ms a frame the tracker has room for the frames kept again
    decisions, now = feed(governor, s[150:600], latency=0.05, now=now, queued=False)
    assert [d.every for _, _, d in decisions] == [3, 2, 1]
    gaps = np.diff([when for when, _, _ in decisions])
    assert np.all(gaps >= settings.calm_s)


def test_latency_that_does_not_queue_is_not_shed():
    """A slow transport makes every frame late, but keeping fewer frames would not help."""
    governor = LatencyGovernor(GovernorSettings(latency_target_s=0.08, min_rate_hz=10.0))
    assert feed(governor, stamps(300), latency=0.3, now=0.0, queued=False)[0] == []


def test_a_busy_tracker_keeps_its_decimation():
    """Calm at one frame in 2, but 25 ms a frame at 15 frames/s would be 75 % busy at 30."""
    governor = LatencyGovernor(GovernorSettings(latency_target_s=0.08, min_rate_hz=15.0))
    s = stamps(600)
    _, now = feed(governor, s[:60], 0.3, 0.0)
    assert governor.current.every == 2
    assert feed(governor, s[60:600], 0.05, now, queued=False, busy=0.025)[0] == []
    assert feed(governor, s[60:600], 0.05, now + 20, queued=False, busy=0.015)[0] != []


def test_governor_backs_off_when_a_lowering_brings_the_queue_back():
    governor = LatencyGovernor(GovernorSettings(latency_target_s=0.08, min_rate_hz=15.0))
    s = stamps(2000)
    _, now = feed(governor, s[:60], 0.3, 0.0)
    assert governor.current.every == 2
    lowered, now = feed(governor, s[60:200], 0.05, now, queued=False)
    assert [d.every for _, _, d in lowered] == [1]
    raised, now = feed(governor, s[200:260], 0.3, now)
    assert [d.every for _, _, d in raised] == [2]
    assert governor.calm_s == 2 * GovernorSettings().calm_s  # the next calm spell is longer
    again, now = feed(governor, s[260:600], 0.05, now, queued=False)
    assert again and again[0][0] - raised[0][0] >= governor.calm_s


def test_governor_switched_off_keeps_every_frame_again():
    governor = LatencyGovernor(GovernorSettings(latency_target_s=0.08, min_rate_hz=10.0))
    _, now = feed(governor, stamps(60), 0.3, 0.0)
    assert governor.current.every > 1
    governor.settings = GovernorSettings(latency_target_s=0.0)
    decision = governor.decide(now + 5)
    assert decision is not None and decision.every == 1
    assert feed(governor, stamps(60, start=T0 + 60 * PERIOD), 0.3, now + 6)[0] == []


def test_a_start_backlog_is_forgotten():
    governor = LatencyGovernor(GovernorSettings(latency_target_s=0.08, min_rate_hz=10.0))
    s = stamps(20)
    for t in s[:4]:
        governor.heard(int(t))
        governor.processed(FrameLoad(2.0, 2.0, True), 0.0)
    governor.restart()
    decisions, _ = feed(governor, s[4:], 0.02, 0.1, queued=False)
    assert decisions == []


def test_the_decimation_keeps_min_rate_frames_a_second():
    """At 30 Hz the default (20 frames a second kept at least) sheds nothing; at 60 Hz, 1 in 3."""
    at_30 = LatencyGovernor(GovernorSettings(latency_target_s=0.08))
    assert feed(at_30, stamps(300), 0.3, 0.0)[0] == []
    at_60 = LatencyGovernor(GovernorSettings(latency_target_s=0.08))
    fast = T0 + np.arange(600, dtype=np.int64) * (PERIOD // 2)
    decisions, _ = feed(at_60, fast, 0.3, 0.0, rate=60)
    assert [d.every for _, _, d in decisions] == [2, 3]
