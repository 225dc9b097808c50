"""
sim_node + controller_node + recorder with parameters from a params file (ROS installs only).

    ros2 launch pulsejet_sim pulsejet.launch.py [namespace:=robot1]
        [params_file:=/path/params.yaml] [scene:=pump_cycle] [use_sim_time:=true|false]
        [record:=true|false] [output:=runs/run1.mcap]

The arguments:
  namespace     namespace of the three nodes (default none); the params file applies under it
  params_file   ros2 params file, blocks keyed /**/<node name> (default the installed
                config/params/pulsejet.yaml)
  scene         scene of sim_node and controller_node, over the params file's (default: the
                params file's)
  use_sim_time  true: controller_node follows sim_node's /clock; false: it runs in wall time
                (default: the node's own, true except with closed_loop); sim_node is the clock
                and the recorder stamps with the middleware's times, so neither takes it
  record        start the recorder (default true)
  output        the recording's MCAP path (default: runs/<UTC date-time>.mcap in the working
                directory)

With record:=true sim_node holds t = 0 until every topic it publishes has a subscriber
(`wait_for_topics: ['*']`, at most `wait_timeout_s`, 10 s by default), so the recording starts at
t = 0 on every topic, as `pulsejet resim` needs.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def nodes(context):
    """Return the three nodes, their parameters built from the arguments' values."""
    namespace = LaunchConfiguration('namespace')
    params = LaunchConfiguration('params_file')
    scene = LaunchConfiguration('scene').perform(context)
    recording = LaunchConfiguration('record').perform(context) == 'true'  # choices: true, false
    use_sim_time = LaunchConfiguration('use_sim_time').perform(context)
    if use_sim_time not in ('', 'true', 'false'):
        raise ValueError(
            f'launch argument use_sim_time={use_sim_time!r} rejected; allowed: true, false or '
            "empty (controller_node's own default)"
        )
    # a later entry wins over the params file: only the arguments given
    scene_override = [{'scene': scene}] if scene else []
    wait = [{'wait_for_topics': ['*']}] if recording else []
    started = [
        Node(
            package='pulsejet_sim',
            executable='sim_node',
            name='sim_node',
            namespace=namespace,
            parameters=[params, *scene_override, *wait],
            output='screen',
        ),
        Node(
            package='pulsejet_sim',
            executable='controller_node',
            name='controller_node',
            namespace=namespace,
            parameters=[
                params,
                *scene_override,
                *([{'use_sim_time': use_sim_time == 'true'}] if use_sim_time else []),
            ],
            output='screen',
        ),
    ]
    if recording:
        started.append(
            Node(
                package='pulsejet_sim',
                executable='recorder',
                name='recorder',
                namespace=namespace,
                parameters=[params, {'output': LaunchConfiguration('output')}],
                output='screen',
            )
        )
    return started


def generate_launch_description():
    share = get_package_share_directory('pulsejet_sim')
    default_params = os.path.join(share, 'config', 'params', 'pulsejet.yaml')
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'namespace', default_value='', description='namespace of the three nodes'
            ),
            DeclareLaunchArgument(
                'params_file',
                default_value=default_params,
                description='ros2 params file with /**/sim_node, /**/controller_node and '
                '/**/recorder blocks',
            ),
            DeclareLaunchArgument(
                'scene',
                default_value='',
                description="scene of sim_node and controller_node (empty: the params file's)",
            ),
            DeclareLaunchArgument(
                'use_sim_time',
                default_value='',
                description="true: controller_node follows sim_node's /clock; false: wall time; "
                'empty: its own default (true, false with closed_loop)',
            ),
            DeclareLaunchArgument(
                'record',
                default_value='true',
                choices=['true', 'false'],
                description='start the recorder; sim_node then holds t = 0 until it subscribed',
            ),
            DeclareLaunchArgument(
                'output',
                default_value='',
                description='MCAP path of the recording (empty: runs/<UTC date-time>.mcap)',
            ),
            OpaqueFunction(function=nodes),
        ]
    )
