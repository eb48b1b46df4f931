"""Running the node graph: the graphs described once, the launch files' body, fly's options and run (start, watch, stop,
report), node processes and a fleet through ROS."""
