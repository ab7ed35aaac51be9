"""Default topic names of the graph; every one can be remapped with ``--ros-args -r``.

All but ``/diagnostics`` are relative, so a graph started in namespace ``cam_left`` reads
``/cam_left/camera/image_raw`` and publishes ``/cam_left/gldt/tracks``: one graph per camera.
In the root namespace they are the usual ``/camera/...`` and ``/gldt/...``.
"""

IMAGE_RAW = "camera/image_raw"
IMAGE_COMPRESSED = "camera/image_raw/compressed"
CAMERA_INFO = "camera/camera_info"
FRAME_TICKS = "gldt/frame_ticks"
SCHEDULER_STATE = "gldt/scheduler/state"
SCHEDULER_LATEST = "gldt/scheduler/latest"
TRACK_PREDICTIONS = "gldt/track_predictions"
ROIS = "gldt/rois"
FRAME_PAIRS = "gldt/frame_pairs"
ROI_CROPS = "gldt/roi_crops"
DETECTIONS = "gldt/detections"
TRACKS = "gldt/tracks"
TRACK_MARKERS = "gldt/track_markers"
DEBUG_IMAGE = "gldt/debug_image"
GROUND_TRUTH = "gldt/ground_truth"
DIAGNOSTICS = "/diagnostics"
