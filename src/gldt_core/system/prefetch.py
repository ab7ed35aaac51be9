"""Read and decode the next frames in a background thread while the GL-DT system works on this one.

Offline, decoding a 1080p JPEG is a real share of a frame's cost beside the global detector. A
camera driver decodes beside the perception stack; the offline runner does the same with
:class:`FramePrefetcher`. OpenCV's decoders and onnxruntime release the GIL, so the thread decodes
on whatever core the detector leaves idle (onnxruntime's intra-op threads cannot keep every core
busy on a network as narrow as these, 8-64 channels).

Frames come out in the source's order, unchanged, so the tracks are the same with and without
it. An exception raised by the source reaches the consumer at the position it happened, after
every frame read before it; stopping early (``close``) lets the thread finish the frame it is on
and joins it, so the caller can close the source safely afterwards.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Iterable, Iterator
from typing import Any

LOG = logging.getLogger("gldt.system")

#: How long ``close`` waits for the reading thread to finish the frame it is on.
JOIN_TIMEOUT_S = 10.0


class _End:
    """Marks the end of the source, or its failure (``error``)."""

    def __init__(self, error: BaseException | None = None):
        self.error = error


class FramePrefetcher:
    """Iterate ``frames`` ahead of the consumer in a daemon thread: ``depth`` items queued, plus
    the one the thread holds while it waits for room. Use it as a context manager (or call
    ``close``) so the thread stops with the consumer. The source must hand out a new array per
    frame, as every ``gldt_core.io.sources`` source does: a decoder that reused one buffer would
    overwrite the frames waiting in the queue.

    ``fetch_seconds`` is the time the thread spent reading and decoding and ``frames_read`` how
    many frames that bought; :attr:`read_ms_per_frame` is the one over the other, for the report of
    where the time goes. Both count frames read ahead that the consumer never took (it stopped
    early). The consumer's own waiting is what its loop measures around ``next``.
    """

    def __init__(self, frames: Iterable[Any], depth: int = 2):
        if depth < 1:
            raise ValueError(f"prefetch depth must be >= 1, got {depth}")
        self._source = iter(frames)
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._finished = False
        self.fetch_seconds = 0.0
        self.frames_read = 0
        self._thread = threading.Thread(target=self._read, name="gldt-frame-prefetch", daemon=True)
        self._thread.start()

    def _put(self, item: Any) -> bool:
        """Queue ``item`` unless the consumer has stopped; False when it has."""
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _read(self) -> None:
        while not self._stop.is_set():
            start = time.perf_counter()
            try:
                item = next(self._source)
            except StopIteration:
                self._put(_End())
                return
            except BaseException as error:  # handed to the consumer, raised there
                self._put(_End(error))
                return
            finally:
                self.fetch_seconds += time.perf_counter() - start
            self.frames_read += 1
            if not self._put(item):
                return

    @property
    def read_ms_per_frame(self) -> float:
        """Milliseconds the thread spent on each frame it read (0 before the first)."""
        return 1000.0 * self.fetch_seconds / max(self.frames_read, 1)

    def __iter__(self) -> Iterator[Any]:
        return self

    def __next__(self) -> Any:
        while True:
            if self._finished:
                raise StopIteration
            try:
                item = self._queue.get(timeout=0.1)  # wakes up to see a close() from another thread
                break
            except queue.Empty:
                continue
        if isinstance(item, _End):
            self._finished = True
            self._thread.join()
            if item.error is not None:
                raise item.error
            raise StopIteration
        return item

    def close(self) -> None:
        """Stop reading ahead and wait for the thread to leave the source alone."""
        self._finished = True
        self._stop.set()
        self._thread.join(JOIN_TIMEOUT_S)
        if self._thread.is_alive():
            LOG.warning("frame prefetch thread still inside the source after %.0f s", JOIN_TIMEOUT_S)

    def __enter__(self) -> FramePrefetcher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
