"""
Core vocabulary every layer shares.

Commands, observations, errors, the model protocol, topic names and input validation; imports
nothing else of pulsejet and no ROS.
"""
