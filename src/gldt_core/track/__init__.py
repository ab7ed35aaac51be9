"""Multi-object tracking: JPTrack (JCMA + PMR, the paper's tracker) and the ByteTrack baseline.

``tracker.update(dets, t)`` takes an ``(N, 5)`` array ``[x1, y1, x2, y2, score]`` in pixels at
``t`` seconds and returns ``(M, 6)`` ``[x1, y1, x2, y2, track_id, score]``; ``tracker.tracks``
exposes :class:`Track` objects (state, velocity, covariance, ...), ``tracker.predict(t)`` the
Kalman-predicted boxes without changing state, ``tracker.reset()`` starts over with id 1.
"""

from gldt_core.track.bytetrack import ByteTrack, ByteTrackConfig
from gldt_core.track.jptrack import JPTrack, JPTrackConfig
from gldt_core.track.state import Track, TrackState

__all__ = ["ByteTrack", "ByteTrackConfig", "JPTrack", "JPTrackConfig", "Track", "TrackState"]
