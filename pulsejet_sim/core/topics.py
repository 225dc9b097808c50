"""
The interface of the pulsejet nodes in one place.

Topic, service and status names, types, field names and thresholds. No ROS import, so the ROS-free
engine and offline tools use the same names; `pulsejet_sim.ros.messages` builds the messages. Topic
names are relative (the node namespace applies), except `/clock`, `/diagnostics` and `/tf`.
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

# topic -> ROS type name of the topics the offline runner records too (docs/user/reference.md)
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

# The rest of the interface, for the reference tables (pulsejet_sim.reference writes
# docs/user/reference.md from these): topics sim_node publishes outside TOPIC_TYPES (views and
# health, not written by the offline runner), what each topic carries with its unit, and the
# services' types.
TOPIC_TF = '/tf'
VIEW_TOPIC_TYPES: dict[str, str] = {
    TOPIC_DIAGNOSTICS: 'diagnostic_msgs/msg/DiagnosticArray',
    TOPIC_MANTLE_MARKER: 'visualization_msgs/msg/Marker',
    TOPIC_TF: 'tf2_msgs/msg/TFMessage',
}
TOPIC_UNITS: dict[str, str] = {
    TOPIC_MANTLE_RADIUS: "m: the shell's radius at mid-meridian, the lumped model's minor "
                         'semi-axis b',
    TOPIC_VOLUME: 'm^3 of fluid in the cavity',
    TOPIC_FLUID_MASS: 'kg of fluid in the cavity',
    TOPIC_VELOCITY: 'm/s in twist.linear.x (forward +), body frame',
    TOPIC_THRUST: 'N in wrench.force.x (jet momentum thrust, forward +), body frame',
    TOPIC_ENERGY_LEDGER: 'J, one KeyValue per ledger key, at about 5 Hz',
    TOPIC_ODOMETRY: 'pose.position.x in m (odom frame), twist.linear.x in m/s (body frame)',
    TOPIC_CLOCK: 'simulation time (s)',
    TOPIC_MANTLE_PROFILE: 'the meridian, m: x axial (forward +), y radius; body frame',
    TOPIC_APPLIED_COMMAND: 'the command held from the stamp on: position = [m^3/s, 0..1, N] by '
                           'name; transient local',
    TOPIC_CMD_PUMP_FLOW: 'm^3/s into the cavity',
    TOPIC_CMD_VALVE: 'opening of the stern nozzle, 0 shut .. 1 open',
    TOPIC_CMD_CABLE_FORCE: 'N of cable pull (shell model)',
    TOPIC_CMD_COMMAND: 'several actuators at one step: names from pump_flow_m3_s, valve_opening, '
                       'cable_force_n, values in position; stamp = the state it answers',
    TOPIC_DIAGNOSTICS: 'sim_node health at about 1 Hz: real-time factor, physics time per step, '
                       'lag, stable-step margin, energy closure, command age, watchdog, fault',
    TOPIC_MANTLE_MARKER: 'the mantle surface (TRIANGLE_LIST, m), body frame, at the ledger rate '
                         'while subscribed',
    TOPIC_TF: 'odom -> body transform with every state (when tf2_msgs is installed)',
}
SERVICE_TYPES: dict[str, str] = {
    SERVICE_PAUSE: 'std_srvs/srv/SetBool',
    SERVICE_STEP: 'std_srvs/srv/Trigger',
    SERVICE_RESET: 'std_srvs/srv/Trigger',
}
SERVICE_MEANINGS: dict[str, str] = {
    SERVICE_PAUSE: 'data true pauses, false resumes (refused in lockstep pacing)',
    SERVICE_STEP: 'advances step_count physics steps while paused or in lockstep',
    SERVICE_RESET: "back to the scene's initial state; the clock returns to 0",
}
