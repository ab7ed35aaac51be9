"""File formats GL-DT reads and writes (MOTChallenge text, rosbag2 MCAP, ...)."""
