"""Messages of pulsejet_sim.ros.messages: the atomic command, the mantle Marker from arrays."""

from pulsejet_sim.core.model_io import Command
from pulsejet_sim.ros import messages
import pytest


def test_a_command_naming_some_actuators_parses_back_to_exactly_those():
    cmd = Command(pump_flow_m3_s=2.5e-3, valve_opening=0.0, cable_force_n=7.0)
    msg = messages.command_message(cmd, 1.25, fields=('pump_flow_m3_s', 'valve_opening'))
    assert messages.command_values(msg) == (1.25, {'pump_flow_m3_s': 2.5e-3, 'valve_opening': 0.0})
    _, every = messages.command_values(messages.command_message(cmd, 1.25))
    assert every == {'pump_flow_m3_s': 2.5e-3, 'valve_opening': 0.0, 'cable_force_n': 7.0}


@pytest.mark.parametrize('fields', [(), ('pump_flow_m3_s', 'pump_flow_m3_s'), ('thrust_n',)])
def test_a_command_with_bad_fields_is_refused_naming_them(fields):
    with pytest.raises(ValueError, match=r'fields .* rejected; allowed: distinct names from'):
        messages.command_message(Command(), 0.0, fields=fields)


def revolved_by_hand(r_m, z_m, segments):
    """Return the mantle's triangles point by point (the loop the array version replaced)."""
    import math

    ring = [
        [
            (z, r * math.cos(2 * math.pi * k / segments), r * math.sin(2 * math.pi * k / segments))
            for k in range(segments + 1)
        ]
        for r, z in zip(r_m, z_m)
    ]
    points = []
    for lower, upper in zip(ring, ring[1:]):
        for k in range(segments):
            points += [lower[k], upper[k], upper[k + 1], lower[k], upper[k + 1], lower[k + 1]]
    return points


@pytest.mark.parametrize('frame', ['base_link', 'robot1/base_link', 'b'])
@pytest.mark.parametrize('nodes', [2, 3, 41])
def test_the_marker_serialised_from_arrays_is_the_message_rclpy_serialises(frame, nodes):
    import numpy as np
    from rclpy.serialization import deserialize_message, serialize_message
    from visualization_msgs.msg import Marker

    s = np.linspace(0.0, 1.0, nodes)
    r_m, z_m = 0.03 * np.sin(np.pi * s) + 0.004, 0.06 * (0.5 - s)
    segments = messages.MANTLE_MARKER_SEGMENTS
    expected = revolved_by_hand(r_m, z_m, segments)
    expected = np.array(expected)
    assert np.allclose(messages.mantle_vertices(r_m, z_m, segments), expected, rtol=0, atol=1e-15)
    data = messages.mantle_marker_cdr(r_m, z_m, 12.345, frame)
    back = deserialize_message(data, Marker)
    # the message rclpy serialises, field for field (rclpy leaves padding bytes unset)
    built = messages.mantle_marker(r_m, z_m, 12.345, frame)
    assert back == deserialize_message(serialize_message(built), Marker)
    assert len(data) == len(serialize_message(built))
    assert back.header.frame_id == frame and back.type == Marker.TRIANGLE_LIST
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (12, 345_000_000)
    points = np.array([(p.x, p.y, p.z) for p in back.points])
    assert np.allclose(points, expected, rtol=0, atol=1e-15)
    assert back.color.a == pytest.approx(0.8) and back.pose.orientation.w == 1.0
