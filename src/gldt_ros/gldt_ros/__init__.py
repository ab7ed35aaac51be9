"""GL-DT ROS 2 node graph: thin rclpy adapters over :mod:`gldt_core`.

Layout (each package imports only the ones above it; the warm spare and ``pipeline --in-process``
load the node modules by the names in interface/graph.py)::

    interface/  what the nodes and their users agree on: topic names, QoS, the parameter schema,
                message conversions, planner-facing track fields, the link reports, and the graph
                itself (graph.py: the node list and the shipped configuration files)
    runtime/    what every node process runs on: the node base class and main loop, the executor,
                heap trimming, DDS profile choice, stack dumps, bounded teardown, the warm spare
    nodes/      the graph's nodes, one module each (frame_pair_buffer, mode_scheduler,
                global_detector, local_detector, jptrack_tracker)
    launcher/   the ``pipeline`` command (``ros2 run gldt_ros pipeline``): starts and supervises
                the node processes, replays a bag into the graph and records its outputs
    bench/      benchmarks of the running graph (``python -m gldt_ros.bench.graph`` and others)
    examples/   a planner-side subscriber (``ros2 run gldt_ros threat_monitor``)

Topic flow (relative names, so one graph per camera namespace)::

    camera/image_raw[/compressed] -> frame_pair_buffer -> gldt/frame_ticks -> jptrack_tracker
    jptrack_tracker -> gldt/track_predictions -> mode_scheduler
    mode_scheduler -> gldt/scheduler/state -> frame_pair_buffer
    frame_pair_buffer -> gldt/frame_pairs (resized pair)  -> global_detector -> gldt/detections
    frame_pair_buffer -> gldt/roi_crops   (ROI crops)      -> local_detector  -> gldt/detections
    gldt/detections -> jptrack_tracker -> gldt/tracks (+ gldt/track_markers)
    gldt/detections -> mode_scheduler (LOCAL frames: detections per ROI)
    gldt/tracks -> frame_pair_buffer (the overlay on gldt/debug_image, while someone watches)

Full-resolution images never leave ``frame_pair_buffer``: the global detector gets the pair
already resized to its input size, the local detector gets only the ROI crops. Every node
reports on ``/diagnostics``.
"""
