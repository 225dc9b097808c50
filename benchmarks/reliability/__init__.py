"""Reliability campaigns: live fuzz and soak of the nodes, and the table of every campaign."""
