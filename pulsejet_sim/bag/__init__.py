"""
MCAP recordings in the rosbag2 layout: writer, reader and repair of a damaged file.

The writer needs the ROS .msg files; the reader needs neither rclpy nor the ROS packages: it
decodes with the definitions stored in the file.
"""

from pulsejet_sim.bag.reader import (
    bag_info,
    BagInfo,
    BagMessage,
    BagReadError,
    find_topic,
    iter_bag,
    load_series,
    read_bag,
    read_metadata,
)
from pulsejet_sim.bag.records import FORMAT_VERSION
from pulsejet_sim.bag.repair import repair, repair_file, RepairResult
from pulsejet_sim.bag.writer import BagError, BagWriter, install_signal_handlers, qos_profiles_yaml

__all__ = [
    'FORMAT_VERSION',
    'BagError',
    'BagInfo',
    'BagMessage',
    'BagReadError',
    'BagWriter',
    'RepairResult',
    'bag_info',
    'find_topic',
    'install_signal_handlers',
    'iter_bag',
    'load_series',
    'qos_profiles_yaml',
    'read_bag',
    'read_metadata',
    'repair',
    'repair_file',
]
