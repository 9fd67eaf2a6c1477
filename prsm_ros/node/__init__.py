"""The ROS 2 node: rclpy plumbing (`ros_node`) over pure-Python parameters, command gate and stepping."""
