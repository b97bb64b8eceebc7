"""LostFrameCounter: images that never arrived are found from their camera_info, each just once."""

import random
import time

from memo_ros.ros.lost_frames import LostFrameCounter


def test_announced_frames_without_an_image_are_lost_once_a_newer_image_arrives():
    c = LostFrameCounter()
    assert c.announced(1) == [] and c.received(1) == []
    assert c.announced(2) == [] and c.announced(3) == []
    assert c.received(3) == [2]  # 2 never came, and images arrive in order
    assert c.announced(4) == [] and c.announced(5) == []
    assert c.received(5) == [4]
    assert c.received(6) == []  # an image before its camera_info
    assert c.announced(6) == []
    assert c.announced(2) == []  # a repeated announcement is not a second loss


def test_an_announcement_older_than_the_newest_image_is_lost_at_once_unstamped_ones_name_none():
    c = LostFrameCounter()
    c.received(10)
    assert c.announced(9) == [9]
    assert c.announced(10) == []
    assert c.announced(0) == []
    c.reset()
    assert c.announced(9) == [] and c.received(9) == []


def test_memory_stays_bounded_when_the_announcing_stream_is_not_per_frame():
    c = LostFrameCounter(recent=16)
    for stamp in range(1, 1000):
        c.announced(stamp)
    assert len(c._waiting) <= 16
    for stamp in range(2000, 3000):
        c.received(stamp)
    assert len(c._settled) <= 16 and len(c._settled_set) <= 16


def test_an_unanswered_announcement_is_lost_after_a_while_and_its_late_image_is_known():
    c = LostFrameCounter()
    c.announced(1)
    assert c.expired(2.0, now=time.monotonic()) == []  # not yet
    assert c.expired(2.0, now=time.monotonic() + 3.0) == [1]  # the last frame of a burst
    assert c.counted_lost(1) and not c.counted_lost(2)
    assert c.expired(2.0, now=time.monotonic() + 3.0) == []  # once


def test_frames_missing_from_both_streams_are_counted_from_the_gaps_in_the_stamps():
    c = LostFrameCounter()
    period = 3_333_333
    missing = 0
    gone = {20, 21, 22, 40}  # neither image nor camera_info came
    info_only = {30, 31}  # images lost, camera_info came
    image_only = {35}  # camera_info lost, image came
    lost = 0
    for k in range(1, 60):
        stamp = k * period
        if k in gone:
            continue
        if k not in image_only:
            lost += len(c.announced(stamp))
        if k not in info_only:
            lost += len(c.received(stamp))
        missing += c.missing()
    assert lost == len(info_only)
    assert missing == len(gone)


def test_an_image_the_node_refused_moves_no_clock_whatever_its_stamp():
    # a fuzzed image stamped years ahead, refused for its encoding: later frames are not past
    c = LostFrameCounter()
    future = 1_900_000_000 * 10**9
    assert c.announced(future) == []
    c.arrived(future)
    assert c.announced(1) == [] and c.received(1) == []
    assert c.announced(2) == [] and c.announced(3) == []
    assert c.received(3) == [2]  # the node's clock, from the images it took
    assert not c.counted_lost(1) and not c.counted_lost(3) and c.counted_lost(2)


def test_announcements_going_back_start_a_new_timeline_and_its_frames_are_counted_once():
    c = LostFrameCounter()
    for stamp in (100, 101):
        assert c.announced(stamp) == [] and c.received(stamp) == []
    assert c.announced(102) == []  # its image never comes: the old timeline ends
    # the bag starts again: camera_info stamped before the newest image waits for its image
    for stamp in (1, 2, 3):
        assert c.announced(stamp) == []
    c.arrived(1)  # the node drops the first two images out of order...
    c.arrived(2)
    assert c.reset() == [102]  # ...and resets at the third: the old timeline's last is lost
    assert c.received(3) == []
    assert c.announced(4) == [] and c.announced(5) == [] and c.received(5) == [4]
    assert not any(c.counted_lost(s) for s in (1, 2, 3, 5))


def _both_streams(c: LostFrameCounter, stamps) -> int:
    """Announce and receive each stamp; return the frames_missing counted."""
    missing = 0
    for stamp in stamps:
        assert c.announced(stamp) == [] and c.received(stamp) == []
        missing += c.missing()
    return missing


def test_a_stall_or_jitter_of_the_stamps_is_no_missing_frame():
    period = 33_333_333
    rng = random.Random(0)
    # a player stamping with the wall clock, regular within 0.3 ms, stalling 20 ms now and then
    stamps, stamp = [], 0
    for k in range(1, 300):
        stamp += period + rng.randint(-300_000, 300_000) + (20_000_000 if k % 40 == 0 else 0)
        stamps.append(stamp)
    assert _both_streams(LostFrameCounter(), stamps) == 0
    # jitter of 4 ms (12 %): a stream too irregular for a gap to tell frames, even a real one
    stamps = [k * period + rng.randint(-4_000_000, 4_000_000) for k in range(1, 300) if k != 150]
    assert _both_streams(LostFrameCounter(), stamps) == 0


def test_a_regular_stream_with_a_stall_still_counts_its_whole_missing_periods():
    period = 33_333_333
    stamps = [k * period + (k % 3) * 100_000 for k in range(1, 200) if k not in (60, 120, 121)]
    stamps = [s + 17_000_000 if s > 90 * period else s for s in stamps]  # one stall at 90
    assert _both_streams(LostFrameCounter(), stamps) == 3


def test_stamps_kept_for_the_gap_search_stay_bounded_when_one_stream_runs_ahead():
    c = LostFrameCounter(recent=16)
    for stamp in range(1, 5000):
        c.announced(stamp)  # no image is ever taken: nothing is checked
    assert len(c._unchecked) <= 32 and len(c._unchecked_set) <= 32
