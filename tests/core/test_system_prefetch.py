"""FramePrefetcher and ``run_frames(prefetch=N)``: frames read ahead in a thread come out in order
and unchanged, a failing source fails at the same place, and stopping early leaves the source alone."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from gldt_core.system.prefetch import FramePrefetcher
from support import REAL_BAG


def test_every_item_comes_out_once_in_order() -> None:
    items = list(range(50))
    with FramePrefetcher(iter(items), depth=3) as ahead:
        assert list(ahead) == items
        assert next(ahead, "done") == "done"  # exhausted stays exhausted


def test_the_thread_reads_ahead_while_the_consumer_works() -> None:
    """With the consumer busy, the source is read by another thread, up to ``depth`` items ahead."""
    readers: list[str] = []

    def source():
        for index in range(6):
            readers.append(threading.current_thread().name)
            yield index

    with FramePrefetcher(source(), depth=2) as ahead:
        assert next(ahead) == 0
        deadline = time.monotonic() + 10
        while len(readers) < 4 and time.monotonic() < deadline:  # the consumer "processes" frame 0
            time.sleep(0.01)
        time.sleep(0.2)
        assert len(readers) == 4  # frame 0 taken, 1-2 queued, 3 read and waiting for room: no further
        assert list(ahead) == [1, 2, 3, 4, 5]
    assert set(readers) == {"gldt-frame-prefetch"}


def test_a_failing_source_fails_after_the_frames_before_it() -> None:
    def source():
        yield "a"
        yield "b"
        raise OSError("truncated chunk at offset 1234")

    ahead = FramePrefetcher(source(), depth=4)
    assert next(ahead) == "a" and next(ahead) == "b"
    with pytest.raises(OSError, match="truncated chunk"):
        next(ahead)
    with pytest.raises(StopIteration):
        next(ahead)


def test_close_stops_reading_and_the_source_is_not_touched_afterwards() -> None:
    reads: list[float] = []

    def endless():
        while True:
            reads.append(time.perf_counter())
            yield len(reads)

    ahead = FramePrefetcher(endless(), depth=2)
    assert next(ahead) == 1
    ahead.close()
    closed_at = time.perf_counter()
    count = len(reads)
    time.sleep(0.3)
    assert len(reads) == count <= 4 and all(t < closed_at for t in reads)
    with pytest.raises(StopIteration):
        next(ahead)


def test_close_from_another_thread_ends_a_consumer_waiting_for_a_frame() -> None:
    def stalled():
        yield 1
        time.sleep(3)  # a source that hangs (a network stream, a slow disk)
        yield 2

    ahead = FramePrefetcher(stalled(), depth=1)
    assert next(ahead) == 1
    threading.Timer(0.2, ahead.close).start()
    started = time.monotonic()
    with pytest.raises(StopIteration):
        next(ahead)
    assert time.monotonic() - started < 2.5  # woken by close, not by the source's next frame


def test_depth_must_be_positive() -> None:
    with pytest.raises(ValueError, match="depth must be >= 1"):
        FramePrefetcher(iter([]), depth=0)


def test_frames_read_counts_what_the_thread_read_not_what_was_taken() -> None:
    """The per-frame read time divides by the frames read: those read ahead and never taken too."""
    produced: list[int] = []

    def source():
        for index in range(20):
            produced.append(index)
            yield index

    ahead = FramePrefetcher(source(), depth=3)
    assert next(ahead) == 0
    deadline = time.monotonic() + 10
    while len(produced) < 5 and time.monotonic() < deadline:  # 1 taken, 3 queued, 1 waiting
        time.sleep(0.01)
    ahead.close()
    assert len(produced) == 5
    assert ahead.frames_read == len(produced)
    assert ahead.read_ms_per_frame == pytest.approx(1000.0 * ahead.fetch_seconds / len(produced))


def test_run_frames_with_prefetch_gives_the_same_tracks() -> None:
    from gldt_core.io.sources import open_source
    from gldt_core.system import GLDTSystem
    from gldt_core.system.runner import run_frames

    pipeline = GLDTSystem()
    inline = run_frames(pipeline, open_source(str(REAL_BAG)), max_frames=45)
    pipeline.reset()
    ahead = run_frames(pipeline, open_source(str(REAL_BAG)), max_frames=45, prefetch=2)
    assert inline.frames == ahead.frames == 45 and len(inline.rows) > 0
    np.testing.assert_array_equal(inline.rows, ahead.rows)
    assert inline.prefetch_ms is None and ahead.prefetch_ms is not None and ahead.prefetch_ms > 0
    with pytest.raises(ValueError, match="prefetch must be >= 0"):
        run_frames(pipeline, [], prefetch=-1)


def test_gldt_run_refuses_a_negative_prefetch(tmp_path: Path, capsys) -> None:
    from gldt_core.cli import main

    assert main(["run", "--bag", str(REAL_BAG), "--out", str(tmp_path / "t.txt"), "--prefetch", "-1"]) == 2
    assert "--prefetch must be >= 0" in capsys.readouterr().err
