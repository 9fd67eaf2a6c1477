"""prsm_ros: the I/O side of prsm — ROS 2 node, MCAP recording, bag tools, Rerun (imports stay lazy)."""
