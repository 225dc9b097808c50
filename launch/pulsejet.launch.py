"""
sim_node + controller_node + recorder with parameters from a params file (ROS installs only).

    ros2 launch pulsejet_sim pulsejet.launch.py [params_file:=/path/params.yaml]
                                                [namespace:=robot1]

The parameters come from `config/params/pulsejet.yaml` (installed to
share/pulsejet_sim/config/params), one block per node name, in the ros2 params-file layout.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory('pulsejet_sim')
    default_params = os.path.join(share, 'config', 'params', 'pulsejet.yaml')
    params = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'params_file',
                default_value=default_params,
                description='ros2 params file with sim_node, controller_node and recorder blocks',
            ),
            DeclareLaunchArgument(
                'namespace', default_value='', description='namespace of the three nodes'
            ),
            Node(
                package='pulsejet_sim',
                executable='sim_node',
                name='sim_node',
                namespace=namespace,
                parameters=[params],
                output='screen',
            ),
            Node(
                package='pulsejet_sim',
                executable='controller_node',
                name='controller_node',
                namespace=namespace,
                parameters=[params],
                output='screen',
            ),
            Node(
                package='pulsejet_sim',
                executable='recorder',
                name='recorder',
                namespace=namespace,
                parameters=[params],
                output='screen',
            ),
        ]
    )
