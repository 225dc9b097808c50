"""
ROS 2 adapters: the nodes, their parameters, messages, recording, replay and the test harness.

Only this folder (and pulsejet_ctrl) imports rclpy; the physics (`pulsejet_sim.models`), the
engine (`pulsejet_sim.engine`) and the offline tools beside them run without ROS.
"""
