"""The ROS-free engine: the live session (pacing, held commands, watchdog, health) that sim_node,
the offline runner and the tests drive."""
