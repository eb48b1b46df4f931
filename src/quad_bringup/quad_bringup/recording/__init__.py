"""Recording: the rosbag2 bag writer (no rclpy) and its node, with the node's console script."""
