"""
Gymnasium environments over the ROS-free engine (no ROS import anywhere here).

Registered ids (``import pulsejet_sim.envs`` registers them)::

    pulsejet/LumpedPumpValve-v0  one lumped robot (paper 001), action (pump flow m^3/s, valve 0..1)
    pulsejet/ShellCable-v0       one shell cable robot (paper 000), action (cable force N)

and the vector environments: ``LumpedPumpValveVectorEnv`` (N lumped robots advanced by one numba
call per control period) and ``make_shell_vector_env`` (shell robots in worker processes through
gymnasium's AsyncVectorEnv).
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry
from pulsejet_sim.envs.lumped_env import LumpedPumpValveEnv
from pulsejet_sim.envs.shell_env import make_shell_vector_env, ShellCableEnv
from pulsejet_sim.envs.vector import LumpedPumpValveVectorEnv

LUMPED_ID = 'pulsejet/LumpedPumpValve-v0'
SHELL_ID = 'pulsejet/ShellCable-v0'

if LUMPED_ID not in registry:
    register(
        id=LUMPED_ID,
        entry_point='pulsejet_sim.envs.lumped_env:LumpedPumpValveEnv',
        vector_entry_point='pulsejet_sim.envs.vector:LumpedPumpValveVectorEnv',
    )
if SHELL_ID not in registry:
    register(id=SHELL_ID, entry_point='pulsejet_sim.envs.shell_env:ShellCableEnv')

__all__ = [
    'LumpedPumpValveEnv',
    'LumpedPumpValveVectorEnv',
    'ShellCableEnv',
    'make_shell_vector_env',
    'LUMPED_ID',
    'SHELL_ID',
]
