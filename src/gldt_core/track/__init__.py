"""Multi-object tracking: JPTrack (JCMA + PMR, the paper's tracker) and the ByteTrack baseline.

``tracker.update(dets, t)`` takes an ``(N, 5)`` array ``[x1, y1, x2, y2, score]`` in pixels at
``t`` seconds and returns ``(M, 6)`` ``[x1, y1, x2, y2, track_id, score]``; ``tracker.tracks``
exposes :class:`Track` objects (state, velocity, covariance, ...), ``tracker.predict(t)`` the
Kalman-predicted boxes without changing state, ``tracker.reset()`` starts over with id 1.

Modules, each importing only the ones listed before it:

* ``fastpath``: the one switch between evaluating a formula on numpy arrays or, for a few items,
  on Python floats, and the operations a formula may use either way;
* ``assignment``: :func:`~gldt_core.track.assignment.assign`, the one-to-one matcher every stage uses;
* ``boxes``: box formulas (corners and centres, IoU) and the input checks;
* ``kalman``: the constant-velocity Kalman filter, batched over tracks;
* ``pmr``: probability-driven memory recovery (eqs. 16-22), the mixture fit and its match score;
* ``state``: :class:`Track` and :class:`TrackState`, and the batched track update;
* ``jcma``: the joint cost of eqs. 9-15;
* ``birth``: optional track birth from persistent low-score detections;
* ``base``: the multi-stage association loop both trackers share;
* ``bytetrack``, ``jptrack``: the two trackers and their configs;
* ``class_evidence``: what each track is (drone, bird, airplane), from the detections it was matched with;
* ``looming``: time to collision from a Kalman filter on the inverse box size;
* ``planner_stream``: what ``/gldt/tracks`` holds each frame (every live track, ids without holes);
* ``runner``: runs a tracker over a MOT detection table (``gldt track``, the benchmark).
"""

from gldt_core.track.bytetrack import ByteTrack, ByteTrackConfig
from gldt_core.track.jptrack import JPTrack, JPTrackConfig
from gldt_core.track.state import Track, TrackState

__all__ = ["ByteTrack", "ByteTrackConfig", "JPTrack", "JPTrackConfig", "Track", "TrackState"]
