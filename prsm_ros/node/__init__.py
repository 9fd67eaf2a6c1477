"""The ROS 2 node: rclpy transport (`ros_node`) over pure-Python parts (parameters, pacing, diagnostics, commands) and `prsm_sim.Session`."""
