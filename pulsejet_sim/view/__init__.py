"""Live views of a run without ROS (`pulsejet view`: the Foxglove WebSocket protocol)."""
