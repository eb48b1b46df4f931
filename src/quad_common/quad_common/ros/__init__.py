"""quad_common's ROS 2 parts: message bytes (cdr), the lean executor (hot_path), rcl's serialized take and publish
(rcl_serialized), a node's main and parameter table, the lockstep followers, the domain probe and the tests' probe
graph. The rest of quad_common imports no rclpy."""
