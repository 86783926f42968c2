"""Rows that arrive over time (fieldbus.row_source) played by fieldbus.playback without a bus:
the chunks join exactly, a late producer leaves the job on the verified stop tail, a stop
stays on the rows received, and the window stays bounded."""

import numpy as np

from nurbsmotion.fieldbus.playback import Playback
from nurbsmotion.fieldbus.row_source import RowChunk, RowFeed, chunk_figures

PERIOD_S = 0.001
ACCEL = [2e6, 2e6]


def ramp(first: int, n: int, step: int) -> np.ndarray:
    """n rows moving ``step`` counts per cycle on axis 0, -step/2 on axis 1, from row ``first``."""
    i = np.arange(first, first + n)
    return np.column_stack([i * step, -(i * step) // 2]).astype(np.int64)


def stop_tail(after: np.ndarray, step: int, cycles: int) -> np.ndarray:
    """Rows from ``after`` decelerating linearly to rest (what Resume.stop gives, in counts)."""
    speeds = np.linspace(step, 0, cycles + 1)[1:]
    x = after[0] + np.cumsum(speeds)
    return np.column_stack([np.round(x), np.round(-x / 2)]).astype(np.int64)


def chunk(rows: np.ndarray, tail: np.ndarray, pauses: tuple[int, ...] = ()) -> RowChunk:
    step, accel = chunk_figures(np.concatenate([rows, tail]), np.zeros((0, 2), np.int64), PERIOD_S)
    return RowChunk(rows, tail, pauses, step, accel)


def playback(feed: RowFeed) -> Playback:
    first = feed.take_first()
    assert first is not None
    return Playback(feed, 1.0, 1.0, list(first.max_step), list(first.max_accel), first.pauses, feed=feed,
                    accel_limits=ACCEL, period_s=PERIOD_S)


def play(pb: Playback, cycles: int, between=None) -> tuple[list[list[int]], bool]:
    out, sent, done = [0, 0], [], False
    for k in range(cycles):
        if between is not None:
            between(k)
        done = pb.advance(out)
        sent.append(list(out))
        if done:
            break
    return sent, done


def test_chunks_queued_ahead_play_as_one_plan():
    feed = RowFeed(2)
    parts = [ramp(0, 500, 10), ramp(500, 500, 10), ramp(1000, 300, 10)]
    for k, rows in enumerate(parts):
        tail = np.zeros((0, 2), np.int64) if k == len(parts) - 1 else stop_tail(rows[-1], 10, 50)
        assert feed.put(chunk(rows, tail))
    feed.close()
    sent, done = play(playback(feed), 5000)
    assert done and sent == np.concatenate(parts).tolist()
    assert feed.fell_behind_row == -1


def test_a_late_producer_leaves_the_job_on_the_stop_tail_at_rest():
    feed = RowFeed(2)
    rows = ramp(0, 400, 10)
    tail = stop_tail(rows[-1], 10, 60)
    feed.put(chunk(rows, tail))
    sent, done = play(playback(feed), 2000)
    assert done and sent == np.concatenate([rows, tail]).tolist()
    assert feed.fell_behind_row == 399
    late = ramp(400, 100, 10)  # arrives after the playback left the planned rows: not used
    feed.put(chunk(late, np.zeros((0, 2), np.int64)))
    assert feed.take(len(sent) - 1.0, False) is None


def test_a_chunk_arriving_just_in_time_replaces_the_tail():
    feed = RowFeed(2)
    first, second = ramp(0, 300, 10), ramp(300, 300, 10)
    feed.put(chunk(first, stop_tail(first[-1], 10, 40)))
    pb = playback(feed)

    def producer(k: int) -> None:
        if k == 299:  # the playback handed out row 298: row 299 (the last planned) comes next
            feed.put(chunk(second, np.zeros((0, 2), np.int64)))
            feed.close()

    sent, done = play(pb, 2000, producer)
    assert done and sent == np.concatenate([first, second]).tolist()


def test_the_playback_waits_at_rest_for_a_chunk_after_a_chunk_that_ends_at_rest():
    feed = RowFeed(2)
    first = np.concatenate([ramp(0, 100, 5), np.repeat(ramp(99, 1, 5), 5, axis=0)])  # ends at rest
    second = ramp(100, 50, 5)
    feed.put(chunk(first, np.zeros((0, 2), np.int64)))
    pb = playback(feed)
    sent, done = play(pb, 200)
    assert not done and sent[-1] == first[-1].tolist() and len(sent) == 200
    feed.put(chunk(second, np.zeros((0, 2), np.int64)))
    feed.close()
    more, done = play(pb, 200)
    assert done and more == second.tolist()


def test_a_stop_ramp_stays_on_the_rows_received_and_ends_at_rest():
    feed = RowFeed(2)
    rows = ramp(0, 400, 40)
    tail = stop_tail(rows[-1], 40, 30)
    feed.put(chunk(rows, tail))
    pb = playback(feed)
    play(pb, 390)
    feed.put(chunk(ramp(400, 400, 40), np.zeros((0, 2), np.int64)))
    pb.start_stop(ACCEL, PERIOD_S)
    out, path = [0, 0], []
    while pb.stop_step(out):
        path.append(out[0])
    path.append(out[0])
    assert path == sorted(path) and path[-1] <= tail[-1, 0]
    assert feed.waiting == 1  # no chunk joins a stop under way


def play_chunks(feed: RowFeed, chunks: int, rows_each: int, tail_rows: int, each_cycle=None) -> Playback:
    """Put ``chunks`` ramps of ``rows_each`` rows (with stop tails) one by one, playing
    ``rows_each`` cycles after each; ``each_cycle()`` after every cycle. The playback."""
    pb = None
    out = [0, 0]
    for c in range(chunks):
        rows = ramp(c * rows_each, rows_each, 3)
        assert feed.put(chunk(rows, stop_tail(rows[-1], 3, tail_rows)), timeout_s=1.0)
        if pb is None:
            pb = playback(feed)
        for _ in range(rows_each):
            pb.advance(out)
            if each_cycle is not None:
                each_cycle()
    assert pb is not None
    return pb


def test_the_window_is_bounded_whatever_the_job_length():
    feed = RowFeed(2, max_chunks=2, keep_rows=256)
    sizes: list[int] = []
    pb = play_chunks(feed, 100, 1000, 20, lambda: sizes.append(len(feed.buf)))
    longest = max(sizes)
    assert feed.planned_end == 100 * 1000 and pb.index >= 99 * 1000
    assert longest <= 256 + 2 * 1000 + 20 + 1


def test_pauses_arrive_with_their_chunk():
    feed = RowFeed(2)
    first = ramp(0, 200, 5)
    feed.put(chunk(first, stop_tail(first[-1], 5, 10)))
    second = np.concatenate([ramp(200, 100, 5), np.repeat(ramp(299, 1, 5), 3, axis=0), ramp(300, 50, 5)])
    feed.put(chunk(second, np.zeros((0, 2), np.int64), pauses=(301,)))
    feed.close()
    pb = playback(feed)
    sent, _ = play(pb, 400)
    assert pb.at_pause() and len(sent) == 400 and pb.index == 301


def test_the_offset_moves_every_row_and_stop_tail_as_its_chunk_joins():
    feed = RowFeed(2, max_chunks=4, ahead_rows=10_000)
    feed.offset = np.array([1000, -7], np.int64)
    first, second = ramp(0, 50, 10), ramp(50, 50, 10)
    assert feed.put(chunk(first, stop_tail(first[-1], 10, 5)))
    assert feed.put(chunk(second, stop_tail(second[-1], 10, 5)))
    feed.take_first()
    feed.take(10.0, False)
    expected = np.concatenate([first, second, stop_tail(second[-1], 10, 5)]) + [1000, -7]
    assert feed.end == len(expected)
    assert all(feed[i, j] == expected[i, j] for i in range(feed.end) for j in range(2))


def test_the_window_is_read_from_another_thread_as_one_buffer_and_its_first_row():
    """RowFeed.window pairs the buffer with its global first row in one store (the service reads
    it off the cycle thread: the way a streamed job moves an axis, for limit inputs)."""
    feed = RowFeed(2, max_chunks=2, keep_rows=16)
    pb = play_chunks(feed, 3, 100, 5)
    buf, base = feed.window
    assert base > 0 and buf is feed.buf and base == feed.base
    row = pb.index
    assert list(buf[row - base]) == [row * 3, -(row * 3) // 2]
