"""What a person looks at: overlays of tracks, mode and ROIs on frames (:mod:`.overlay`), the
overlay video and run plot of ``gldt run --render/--plot`` (:mod:`.render`)."""
