"""
Offline studies on top of the engine.

Runs to MCAP, sweeps, fits, optimisation, re-simulation and validation against measured robots;
no ROS.
"""
