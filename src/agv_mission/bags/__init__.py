"""ROS bags out and in: every run as a ROS 2 bag, and offline mapping from recorded bags."""
