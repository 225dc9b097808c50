"""pulsejet simulator."""
