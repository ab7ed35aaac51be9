"""Everything GL-DT reads and writes.

Frame sources (:func:`gldt_core.io.sources.open_source`: videos, MOTChallenge folders, rosbag2
MCAP bags, ``synth:`` scenes, all yielding :class:`gldt_core.io.frame.Frame`), image payload
decoding (:mod:`.imaging`), MOTChallenge text (:mod:`.mot`), rosbag2 bags and graph recordings
(:mod:`.bag`, :mod:`.recording`), and the one MCAP reader and writer under both
(:mod:`.mcap_file`, with :mod:`.cdr` for the header stamp of a raw message).
"""
