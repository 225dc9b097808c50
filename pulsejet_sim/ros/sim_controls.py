"""
sim_node's inputs as a client drives them: command topics, control and parameter services.

`SimControls` holds one client node's command publishers (one per command topic), the clients of
the pulsejet/pause, step and reset services and of the parameter services of any node (created on
first use), and builds the requests; waiting for the answers is the caller's (it spins).
"""

from __future__ import annotations

import time

from pulsejet_sim.core import topics as names

SIM_NODE_NAME = '/sim_node'


class SimControls:
    """Command publishers and service clients of one client node."""

    def __init__(self, node, qos):
        from rcl_interfaces.srv import GetParameters, SetParameters
        from std_msgs.msg import Float64
        from std_srvs.srv import SetBool, Trigger

        self.node = node
        self.publishers = {
            field: node.create_publisher(Float64, topic, qos)
            for topic, field in names.COMMAND_FIELDS.items()
        }
        self.clients = {
            'pause': node.create_client(SetBool, names.SERVICE_PAUSE),
            'step': node.create_client(Trigger, names.SERVICE_STEP),
            'reset': node.create_client(Trigger, names.SERVICE_RESET),
            f'{SIM_NODE_NAME}/set_parameters': node.create_client(
                SetParameters, f'{SIM_NODE_NAME}/set_parameters'
            ),
            f'{SIM_NODE_NAME}/get_parameters': node.create_client(
                GetParameters, f'{SIM_NODE_NAME}/get_parameters'
            ),
        }

    def connected(self) -> bool:
        """Return whether every service answers and every command topic has a subscriber."""
        return all(c.service_is_ready() for c in list(self.clients.values())) and all(
            p.get_subscription_count() > 0 for p in self.publishers.values()
        )

    def publish(
        self,
        pump_flow_m3_s: float | None = None,
        valve_opening: float | None = None,
        cable_force_n: float | None = None,
    ) -> float:
        """Publish the given commands (each on its topic); returns the wall time of publication."""
        from std_msgs.msg import Float64

        for field, value in (
            ('valve_opening', valve_opening),
            ('pump_flow_m3_s', pump_flow_m3_s),
            ('cable_force_n', cable_force_n),
        ):
            if value is not None:
                self.publishers[field].publish(Float64(data=float(value)))
        return time.monotonic()

    def parameter_client(self, node_name: str, service: str) -> str:
        """Return the key of the client of `node_name`'s set_parameters / get_parameters."""
        from rcl_interfaces.srv import GetParameters, SetParameters

        key = f'{node_name}/{service}'
        if key not in self.clients:
            kind = SetParameters if service == 'set_parameters' else GetParameters
            self.clients[key] = self.node.create_client(kind, key)
        return key

    @staticmethod
    def pause_request(paused: bool):
        from std_srvs.srv import SetBool

        return SetBool.Request(data=paused)

    @staticmethod
    def trigger_request():
        from std_srvs.srv import Trigger

        return Trigger.Request()

    @staticmethod
    def set_parameters_request(values: dict):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        return SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        )

    @staticmethod
    def get_parameters_request(names_: tuple[str, ...]):
        from rcl_interfaces.srv import GetParameters

        return GetParameters.Request(names=list(names_))
