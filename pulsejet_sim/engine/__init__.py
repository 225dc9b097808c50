"""
The ROS-free engine: the live session (pacing, held commands, watchdog, health).

sim_node, the offline runner and the tests drive it.
"""
