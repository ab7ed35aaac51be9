"""GL-DT ROS 2 node graph: thin rclpy adapters over :mod:`gldt_core`.

Topic layout (see README for the diagram)::

    /camera/image_raw[/compressed] -> frame_pair_buffer -> /gldt/frame_ticks -> mode_scheduler
    mode_scheduler -> /gldt/scheduler/state -> frame_pair_buffer
    frame_pair_buffer -> /gldt/frame_pairs (resized pair)  -> global_detector -> /gldt/detections
    frame_pair_buffer -> /gldt/roi_crops   (300x300 crops) -> local_detector  -> /gldt/detections
    /gldt/detections -> jptrack_tracker -> /gldt/tracks -> mode_scheduler (ROI predictions)

Full-resolution images never leave ``frame_pair_buffer``: the global detector gets the pair
already resized to its input size, the local detector gets only the ROI crops.
"""
