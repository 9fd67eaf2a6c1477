"""ROS 2 MCAP files: the profile's schema and QoS metadata, the recorder, offline runs to MCAP."""
