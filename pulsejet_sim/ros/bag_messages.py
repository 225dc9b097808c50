"""rclpy message objects into a recording: serialise with rclpy and write through BagWriter."""

from __future__ import annotations

from typing import Any

from pulsejet_sim.bag.writer import BagError, BagWriter, qualify_topic
from rclpy.serialization import serialize_message


def type_name_of(msg: Any) -> str:
    """'pkg/msg/Type' of an rclpy message instance (from its Python module path)."""
    module = type(msg).__module__.split('.')  # e.g. std_msgs.msg._float64
    if len(module) < 2:
        raise BagError(f'{type(msg).__name__} is not a generated ROS message class')
    return f'{module[0]}/{module[1]}/{type(msg).__name__}'


def write_message(writer: BagWriter, topic: str, msg: Any, log_time_ns: int) -> None:
    """Serialize an rclpy message and write it; a new topic is added with the message's type."""
    name = qualify_topic(topic)
    if name not in writer.topics:
        writer.add_topic(name, type_name_of(msg))
    writer.write(name, serialize_message(msg), log_time_ns)
