"""Drive a :class:`GLDTSystem` over a whole frame source (the offline runner and the benches).

Keeps only what a run needs afterwards - MOTChallenge track rows, the mode of each frame, stage
times - so memory stays flat however long the video is. Decoding time is measured here (it
happens when the source yields the next frame) and booked as the ``decode`` stage; with
``prefetch`` the source is read in a background thread (:mod:`gldt_core.system.prefetch`) and
``decode`` is only what the loop still waited for.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gldt_core.schedule.scheduler import Mode
from gldt_core.system.gldt_system import GLDTSystem


@dataclass(frozen=True)
class SimpleFrame:
    """The minimal frame record :func:`run_frames` needs (what ``gldt_core.io.sources`` sources yield)."""

    index: int
    stamp: float
    image: np.ndarray
    ground_truth: np.ndarray | None = None


@dataclass
class RunResult:
    """Outcome of one run: ``rows`` are MOTChallenge ``(N, 10)`` with 1-based frames."""

    rows: np.ndarray
    frames: int
    seconds: float  # wall clock of the whole loop, decoding included
    global_frames: int
    modes: np.ndarray  # (frames,) bool, True where GD ran
    ground_truth: np.ndarray | None = None
    stage_ms: dict[str, float] = field(default_factory=dict)  # ms per frame per stage
    reinitialisations: int = 0
    prefetch_ms: float | None = None  # ms per frame the prefetch thread spent reading (None: inline)

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    @property
    def global_share(self) -> float:
        return self.global_frames / self.frames if self.frames else 0.0


def tracks_to_mot(tracks: np.ndarray, frame_number: int, classes: np.ndarray | None = None) -> np.ndarray:
    """``(M, 6)`` ``[x1,y1,x2,y2,id,score]`` -> MOTChallenge rows ``frame,id,x,y,w,h,score,class,-1,-1``;
    ``class`` is the track's class id from ``classes`` (``(M,)`` or the ``(M, 2)`` of
    :attr:`GLDTSystem.track_classes`), -1 (unknown) without."""
    tracks = np.asarray(tracks, dtype=np.float64).reshape(-1, 6)
    out = np.full((len(tracks), 10), -1.0)
    out[:, 0] = frame_number
    out[:, 1] = tracks[:, 4]
    out[:, 2] = tracks[:, 0]
    out[:, 3] = tracks[:, 1]
    out[:, 4] = tracks[:, 2] - tracks[:, 0]
    out[:, 5] = tracks[:, 3] - tracks[:, 1]
    out[:, 6] = tracks[:, 5]
    if classes is not None:
        classes = np.asarray(classes, dtype=np.float64)
        out[:, 7] = classes[:, 0] if classes.ndim == 2 else classes
    return out


def _timed(frames: Iterable[Any], system: GLDTSystem, limit: int | None) -> Iterator[Any]:
    """Yield at most ``limit`` frames, booking the time spent fetching each as ``decode``."""
    iterator = iter(frames)
    fetched = 0
    while limit is None or fetched < limit:
        fetched += 1
        start = time.perf_counter()
        try:
            frame = next(iterator)
        except StopIteration:
            return
        system.timer.add("decode", time.perf_counter() - start)
        yield frame


class _Recorder:
    """What one system's run keeps per frame: track rows, the mode, ground truth if asked."""

    def __init__(
        self,
        system: GLDTSystem,
        on_frame: Callable[[Any, np.ndarray], None] | None,
        collect_ground_truth: bool,
    ) -> None:
        self.system = system
        self.on_frame = on_frame
        self.collect_ground_truth = collect_ground_truth
        self.rows: list[np.ndarray] = []
        self.gt_rows: list[np.ndarray] = []
        self.modes: list[bool] = []

    def step(self, frame: Any) -> None:
        tracks = self.system.process(frame.image, frame.stamp)
        self.rows.append(tracks_to_mot(tracks, int(frame.index) + 1, getattr(self.system, "track_classes", None)))
        self.modes.append(self.system.state.mode is Mode.GLOBAL)
        if self.collect_ground_truth:
            gt = getattr(frame, "ground_truth", None)
            if gt is not None and len(gt):
                self.gt_rows.append(np.asarray(gt, dtype=np.float64).reshape(-1, 10))
        if self.on_frame is not None:
            self.on_frame(frame, tracks)

    def result(self, seconds: float, prefetch_ms: float | None = None) -> RunResult:
        """The run's result; ``prefetch_ms`` is the reading thread's time per frame, if one ran."""
        count = len(self.modes)
        table = np.vstack(self.rows) if self.rows else np.zeros((0, 10))
        gt_table = None
        if self.collect_ground_truth:
            gt_table = np.vstack(self.gt_rows) if self.gt_rows else np.zeros((0, 10))
        mode_array = np.asarray(self.modes, dtype=bool)
        return RunResult(
            rows=table,
            frames=count,
            seconds=seconds,
            global_frames=int(mode_array.sum()),
            modes=mode_array,
            ground_truth=gt_table,
            stage_ms={name: ms for name, ms, _, _ in self.system.timer.breakdown(count)},
            reinitialisations=self.system.state.reinitialisations,
            prefetch_ms=prefetch_ms,
        )


def run_frames(
    system: GLDTSystem,
    frames: Iterable[Any],
    *,
    max_frames: int | None = None,
    on_frame: Callable[[Any, np.ndarray], None] | None = None,
    collect_ground_truth: bool = False,
    prefetch: int = 0,
) -> RunResult:
    """Process every frame of ``frames`` (objects with ``index``, ``stamp``, ``image`` and
    optionally ``ground_truth``); ``on_frame(frame, tracks)`` is called after each (overlay,
    progress bar). Output frame numbers are ``index + 1`` (MOTChallenge is 1-based).
    ``prefetch`` > 0 reads that many frames ahead in a background thread (same frames, same tracks;
    each frame must own its image array, see :class:`~gldt_core.system.prefetch.FramePrefetcher`)."""
    recorder = _Recorder(system, on_frame, collect_ground_truth)
    if prefetch < 0:
        raise ValueError(f"prefetch must be >= 0, got {prefetch}")
    start = time.perf_counter()
    if not prefetch:
        for frame in _timed(frames, system, max_frames):
            recorder.step(frame)
        return recorder.result(time.perf_counter() - start)
    from gldt_core.system.prefetch import FramePrefetcher

    with FramePrefetcher(frames, prefetch) as ahead:
        for frame in _timed(ahead, system, max_frames):
            recorder.step(frame)
        seconds = time.perf_counter() - start
    return recorder.result(seconds, ahead.read_ms_per_frame)


def run_frames_interleaved(
    systems: Sequence[GLDTSystem],
    frames: Iterable[Any],
    *,
    on_frame: Sequence[Callable[[Any, np.ndarray], None] | None] | None = None,
) -> list[RunResult]:
    """:func:`run_frames` for several systems at once, taking turns frame by frame.

    For comparing their speed on a shared machine, whose CPU speed drifts within seconds:
    systems run one after the other see different machines, systems that take
    turns on every frame see the same one. Each frame is decoded once; its decode time is booked
    to every system (each would have had to decode it), and each system's ``seconds`` is that
    plus its own processing. Every system gets exactly the frames and results it would get from
    :func:`run_frames`, as long as the systems share no mutable state.
    """
    callbacks = list(on_frame) if on_frame is not None else [None] * len(systems)
    if len(callbacks) != len(systems):
        raise ValueError(f"run_frames_interleaved: {len(callbacks)} on_frame callbacks for {len(systems)} systems")
    recorders = [_Recorder(system, callback, False) for system, callback in zip(systems, callbacks)]
    seconds = [0.0] * len(recorders)
    iterator = iter(frames)
    while True:
        start = time.perf_counter()
        try:
            frame = next(iterator)
        except StopIteration:
            break
        decode = time.perf_counter() - start
        for index, recorder in enumerate(recorders):
            recorder.system.timer.add("decode", decode)
            start = time.perf_counter()
            recorder.step(frame)
            seconds[index] += decode + time.perf_counter() - start
    return [recorder.result(spent) for recorder, spent in zip(recorders, seconds)]
