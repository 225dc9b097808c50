"""
The interface of the pulsejet nodes in one place.

Topic, service and status names, types, field names and thresholds. No ROS import, so the ROS-free
engine and offline tools use the same names; `pulsejet_sim.ros.messages` builds the messages. Topic
names are relative (the node namespace applies), except `/clock` and `/diagnostics`.
"""

from __future__ import annotations

FRAME_ID = 'pulsejet/body'

TOPIC_MANTLE_RADIUS = 'pulsejet/mantle_radius'
TOPIC_VOLUME = 'pulsejet/volume'
TOPIC_VELOCITY = 'pulsejet/velocity'
TOPIC_THRUST = 'pulsejet/thrust'
TOPIC_ENERGY_LEDGER = 'pulsejet/energy_ledger'
TOPIC_FLUID_MASS = 'pulsejet/fluid_mass'
TOPIC_CLOCK = '/clock'
# nav_msgs/Odometry of the body along its swimming axis (REP 105: pose in the odom frame, twist in
# the body frame base_link; the frame names are sim_node parameters)
TOPIC_ODOMETRY = 'odom'
ODOM_FRAME_ID = 'odom'
BASE_FRAME_ID = 'base_link'
TOPIC_CMD_PUMP_FLOW = 'pulsejet/cmd/pump_flow'
TOPIC_CMD_VALVE = 'pulsejet/cmd/valve'
TOPIC_CMD_CABLE_FORCE = 'pulsejet/cmd/cable_force'
# Several actuators at the same step: JointState, names from APPLIED_COMMAND_NAMES (any subset),
# values in `position`; header.stamp = the simulation time of the state it answers (closed loop)
TOPIC_CMD_COMMAND = 'pulsejet/cmd/command'
TOPIC_DIAGNOSTICS = '/diagnostics'
SERVICE_PAUSE = 'pulsejet/pause'
SERVICE_STEP = 'pulsejet/step'
SERVICE_RESET = 'pulsejet/reset'
# The command the simulator actually held from the stamped simulation time on (after validation):
# what re-simulation replays step for step.
TOPIC_APPLIED_COMMAND = 'pulsejet/applied_command'
# Published transient local (latched, as /tf_static): a subscriber that matches late, such as a
# recorder that the publisher's writer discovers after the command held from t=0 went out, still
# gets the held command. The recorder subscribes with the durability its publishers offer; another
# subscriber that wants the history subscribes transient local too.
LATCHED_TOPICS = (TOPIC_APPLIED_COMMAND,)
# The mantle surface (the meridian revolved) as a visualization_msgs/Marker TRIANGLE_LIST for RViz
# and Foxglove, at the energy ledger's rate; not recorded by default (a view, not data)
TOPIC_MANTLE_MARKER = 'pulsejet/mantle_marker'
MANTLE_MARKER_SEGMENTS = 24
# The mantle's meridian in the body frame: x = axial position (m, forward +), y = radius (m).
TOPIC_MANTLE_PROFILE = 'pulsejet/mantle_profile'
APPLIED_COMMAND_NAMES = ('pump_flow_m3_s', 'valve_opening', 'cable_force_n')

# topic -> ROS type name, as in docs/ARCHITECTURE.md
TOPIC_TYPES: dict[str, str] = {
    TOPIC_MANTLE_RADIUS: 'std_msgs/msg/Float64',
    TOPIC_VOLUME: 'std_msgs/msg/Float64',
    TOPIC_VELOCITY: 'geometry_msgs/msg/TwistStamped',
    TOPIC_THRUST: 'geometry_msgs/msg/WrenchStamped',
    TOPIC_ENERGY_LEDGER: 'diagnostic_msgs/msg/DiagnosticArray',
    TOPIC_FLUID_MASS: 'std_msgs/msg/Float64',
    TOPIC_CLOCK: 'rosgraph_msgs/msg/Clock',
    TOPIC_ODOMETRY: 'nav_msgs/msg/Odometry',
    TOPIC_CMD_PUMP_FLOW: 'std_msgs/msg/Float64',
    TOPIC_CMD_VALVE: 'std_msgs/msg/Float64',
    TOPIC_CMD_CABLE_FORCE: 'std_msgs/msg/Float64',
    TOPIC_CMD_COMMAND: 'sensor_msgs/msg/JointState',
    TOPIC_APPLIED_COMMAND: 'sensor_msgs/msg/JointState',
    TOPIC_MANTLE_PROFILE: 'geometry_msgs/msg/PolygonStamped',
}
STATE_TOPICS = (
    TOPIC_MANTLE_RADIUS,
    TOPIC_VOLUME,
    TOPIC_VELOCITY,
    TOPIC_THRUST,
    TOPIC_FLUID_MASS,
    TOPIC_ODOMETRY,
    TOPIC_CLOCK,
)
COMMAND_TOPICS = (TOPIC_CMD_PUMP_FLOW, TOPIC_CMD_VALVE, TOPIC_CMD_CABLE_FORCE)
#: per-actuator command topic -> Command field
COMMAND_FIELDS = {
    TOPIC_CMD_PUMP_FLOW: 'pump_flow_m3_s',
    TOPIC_CMD_VALVE: 'valve_opening',
    TOPIC_CMD_CABLE_FORCE: 'cable_force_n',
}

LEDGER_STATUS_NAME = 'pulsejet energy ledger'
LEDGER_HARDWARE_ID = 'pulsejet'
LEDGER_WARN_RELATIVE = 0.05  # |closure_relative| above this -> WARN: energy books do not balance
