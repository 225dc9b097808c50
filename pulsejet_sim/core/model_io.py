"""Types shared by every model: commands in, observations out, and the errors. No ROS here."""

from __future__ import annotations

from dataclasses import dataclass, fields
import math
import numbers


class ModelError(ValueError):
    """
    A model or scene parameter that cannot be simulated.

    The message names the value and what is allowed.
    """


class SimulationBlowUp(RuntimeError):
    """
    The state became non-finite or left its physical bounds.

    The physics stopped at the last good step.
    """

    def __init__(self, message: str, time_s: float):
        super().__init__(message)
        self.time_s = time_s


class CommandError(ValueError):
    """A command value outside what the actuator accepts."""


@dataclass(frozen=True)
class Command:
    """Actuation command held constant over a batch of physics steps."""

    pump_flow_m3_s: float = (
        0.0  # volume flow the pump pushes into the cavity through the bow inlet
    )
    valve_opening: float = 1.0  # 0 shut .. 1 fully open stern nozzle
    cable_force_n: float = (
        0.0  # cable pull on the mantle (shell model); the lumped model ignores it
    )

    # allowed ranges, checked by validate(): (low, high)
    LIMITS = {
        'pump_flow_m3_s': (0.0, 0.05),
        'valve_opening': (0.0, 1.0),
        'cable_force_n': (0.0, 1000.0),
    }

    def validate(self, limits: dict | None = None) -> 'Command':
        """
        Return this command with every value a float in its range (self when it already is one).

        Otherwise CommandError naming the first bad value and the allowed range (NaN, inf, text,
        booleans, None and out-of-range values are refused). ``limits``: the ranges of a model's
        actuators (``Simulation.command_limits``), by default ``LIMITS``.
        """
        limits = limits or self.LIMITS
        values = {}
        for f in fields(self):
            low, high = limits[f.name]
            values[f.name] = check_command_value(f.name, getattr(self, f.name), low, high)
        if all(type(getattr(self, k)) is float for k in values):
            return self
        return Command(**values)


def check_command_value(name: str, value: float, low: float, high: float) -> float:
    """Return value as float, or raise CommandError naming the value and the allowed range."""
    if isinstance(value, (bool, str, bytes)) or not isinstance(value, numbers.Real):
        raise CommandError(
            f'{name}={value!r} is not a number; allowed: a finite value in [{low}, {high}]'
        )
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise CommandError(
            f'{name}={value!r} is not a number; allowed: a finite value in [{low}, {high}]'
        ) from None
    if not math.isfinite(v) or v < low or v > high:
        raise CommandError(
            f'{name}={value!r} rejected; allowed: a finite value in [{low}, {high}]'
        )
    if name == 'valve_opening' and 0.0 < v < VALVE_MIN_OPENING:
        # below the valve's seat the model cannot hold the flow (see VALVE_MIN_OPENING)
        raise CommandError(
            f'{name}={value!r} rejected; allowed: 0 (shut) or a finite value in '
            f'[{VALVE_MIN_OPENING:g}, {high}]'
        )
    return v


# The valve's seat: the smallest opening other than 0 (shut) that the valve holds, as a fraction of
# the nozzle area. A command may ask for 0 or an opening in [VALVE_MIN_OPENING, 1]; a closing valve
# that would pass below it seals, a shut one cracks open to it. Below it the orifice loss
# (1/opening - 1)^2 makes the lumped model's nozzle flow too stiff for its fixed step: without the
# seat, held openings of 0.1 % faulted at the largest pump flows and most runs at 0.03 % or less
# faulted, and a valve closing from 0.5 + 1e-5 faulted in 20 of 21 pump_cycle runs because its
# stroke left it at 1e-5 for one step (benchmarks/validation/valve_seat_probe.py,
# benchmarks/results/valve_seat.md). At 0.15 % no held opening faults at the shipped step, 1e-4 s
# (a larger step faults at larger openings: docs/theory/lumped.md, Numerics); it is below the
# shipped scenes' stroke per step (2e-3, which rounding leaves at 0.0019999999999991 at the end of
# a stroke from 1), so their fixed-step motion is unchanged bit for bit (a seat at 0.2 % sealed
# them one step early).
VALVE_MIN_OPENING = 1.5e-3


@dataclass(frozen=True)
class Observation:
    """What the simulator publishes at one instant (SI units)."""

    time_s: float
    position_m: float  # vehicle axial position, forward +
    velocity_m_s: float
    acceleration_m_s2: float
    mantle_radius_m: float  # shell: radius at mid-meridian; lumped model: minor semi-axis b
    volume_m3: float  # fluid volume in the cavity
    fluid_mass_kg: float
    thrust_n: float  # jet momentum thrust on the vehicle, forward +
    added_mass_force_n: float  # -dm_x/dt * U, forward +
    drag_n: float  # drag on the vehicle, forward + (negative while swimming forward)
    jet_speed_m_s: float  # outflow speed relative to the nozzle (negative while water flows in)
    cavity_pressure_pa: float  # gauge pressure at the nozzle inlet
    pump_flow_m3_s: float  # actual pump flow (the pump has a spin-up lag)
    valve_opening: float  # actual valve opening (the valve has a stroke lag)
