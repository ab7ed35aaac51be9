"""GL-DT core: every algorithm of the GL-DT perception stack, free of ROS and torch.

The same code runs offline (video, folder of frames, bag) and inside the ROS 2 nodes of
``gldt_ros``, which are thin adapters over it. Importing this package must stay cheap and
must never import ``rclpy`` or ``torch``; heavy modules are imported where they are used.
"""

__version__ = "0.1.0"
