"""
The parameters of controller_node as data, importable without ROS.

controller_node declares these (`pulsejet_ctrl.controller_node`); the reference tables of the docs
(`pulsejet_sim.reference`) read them too, which is why they live here and not beside the node: the
reference tables then read no module of `pulsejet_ctrl` but its routines. The node's own
parameters are fixed; the routine's come from the routine's scene spec (`pulsejet_sim.routines`:
default, range and unit of each field), with the scene's `routine:` values as defaults.
"""

from __future__ import annotations

from pulsejet_sim import routines as _routines
from pulsejet_sim.core.schema import Choice
from pulsejet_sim.ros.node_params import ParamSpec
from pulsejet_sim.scene import DEFAULT_SCENE

#: routine field -> description (ranges and defaults come from the routine's spec)
ROUTINE_FIELDS = {
    'inflate_s': 's of pump inflation per cycle',
    'target_volume_m3': 'inflate until this cavity volume instead (0 = use inflate_s), m^3',
    'pump_flow_m3_s': 'pump flow while inflating, m^3/s',
    'hold_s': 's with pump off and valve shut before the jet',
    'jet_s': 's with the valve open (jetting)',
    'valve_opening': 'valve opening while jetting, 0..1',
    'cycles': 'number of cycles (0 = forever)',
    'start_delay_s': 's of simulated time before the first cycle',
    'pulse': 'shape of the rise and release: half_cosine or triangle (straight lines)',
    'amplitude_n': 'peak cable pull, N',
    'frequency_hz': 'cable pulls per second of simulated time, Hz',
    'contraction_s': 's of the rise of the pull (see pulse)',
    'release_s': 's of the release of the pull (see pulse)',
}
INTEGER_FIELDS = ('cycles',)
#: routine kind -> field -> pulsejet_sim.core.schema.Number (default, range)
ROUTINE_SPECS = {'pump_valve': _routines.PUMP_VALVE_SPEC, 'cable': _routines.CABLE_SPEC}

#: the node's own parameters, declared before the routine's
NODE_PARAMETERS = (
    ParamSpec(
        'scene',
        DEFAULT_SCENE,
        'scene whose routine block gives the default parameters',
        read_only=True,
        allowed='a scene name under config/ or a YAML file path',
    ),
    ParamSpec('rate_hz', 50.0, 'command rate in simulated time (Hz); live', 1e-3, 10000.0),
    ParamSpec(
        'closed_loop',
        False,
        'answer every state with one atomic command stamped at its time '
        '(for sim_node pacing closed_loop)',
        read_only=True,
    ),
)


def routine_parameters(kind: str, scene_routine: dict) -> list[ParamSpec]:
    """
    Return the read-only parameters of a routine of `kind`, defaults from `scene_routine`.

    They define the routine's state machine (restart the node to change them). A double given as
    an integer (`inflate_s:=2`) is declared as the double (node_params.declare says so); the
    routine checks the values too.
    """
    specs = []
    for name, number in ROUTINE_SPECS[kind].items():
        if name == 'kind':
            continue
        if isinstance(number, Choice):  # a word, e.g. the cable's pulse shape
            default = scene_routine.get(name, number.default)
            specs.append(
                ParamSpec(
                    name,
                    default,
                    ROUTINE_FIELDS.get(name, name),
                    choices=number.choices,
                    read_only=True,
                )
            )
            continue
        kind_of = int if name in INTEGER_FIELDS else float
        description = ROUTINE_FIELDS.get(name, f'{name} ({number.unit})')
        if number.low_open:
            description += f' (> {number.low:g})'
        default = scene_routine.get(name, number.default)
        specs.append(
            ParamSpec(name, kind_of(default), description, number.low, number.high, read_only=True)
        )
    return specs
