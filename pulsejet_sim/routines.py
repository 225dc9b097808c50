"""
Actuation routines: pure, deterministic state machines that map time to a Command.

Actuation routines: pure, deterministic state machines that map time (and what they measure) to
a Command. The controller node and the offline runner drive the same objects.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from pulsejet_sim.core.model_io import Command, ModelError
from pulsejet_sim.core.schema import check_section, Choice, Number
from pulsejet_sim.models import cable_pulse

PUMP_VALVE_SPEC = {
    'kind': Choice('pump_valve', ('pump_valve',)),
    'inflate_s': Number(2.0, 0.0, 1e4, unit='s'),
    'target_volume_m3': Number(0.0, 0.0, 10.0, unit='m^3 (0: inflate for inflate_s)'),
    'pump_flow_m3_s': Number(2.5e-3, 0.0, Command.LIMITS['pump_flow_m3_s'][1], unit='m^3/s'),
    'hold_s': Number(0.2, 0.0, 1e4, unit='s'),
    'jet_s': Number(1.8, 0.0, 1e6, unit='s'),
    'valve_opening': Number(1.0, 0.0, 1.0, low_open=True, unit=''),
    'cycles': Number(0, 0, 1e9, unit='(0: forever)'),
    'start_delay_s': Number(0.0, 0.0, 1e6, unit='s'),
}

INFLATE, HOLD, JET, IDLE, DONE = 'inflate', 'hold', 'jet', 'idle', 'done'


@dataclass
class PumpValveRoutine:
    """
    Inflate, hold, jet, repeat: the pump/valve routine.

    Inflate (pump on, valve shut) for a time or to a target volume, hold (both off, valve shut),
    jet (valve open), repeat. Phases advance on the time it is given, so the same routine gives the
    same commands live (sim time from /clock) and offline.
    """

    inflate_s: float = 2.0
    target_volume_m3: float = 0.0
    pump_flow_m3_s: float = 2.5e-3
    hold_s: float = 0.2
    jet_s: float = 1.8
    valve_opening: float = 1.0
    cycles: int = 0
    start_delay_s: float = 0.0

    def __post_init__(self):
        self.cycles = int(self.cycles)
        self.reset()

    @classmethod
    def from_config(cls, config: Mapping[str, Any] | None) -> 'PumpValveRoutine':
        """Build from a scene's `routine` mapping; raises ModelError naming a bad key or value."""
        values = check_section('routine', config or {}, PUMP_VALVE_SPEC)
        values.pop('kind')
        return cls(**values)

    def reset(self) -> None:
        self.phase = IDLE if self.start_delay_s > 0 else INFLATE
        self.phase_start_s = 0.0 if self.start_delay_s <= 0 else None
        self.cycle = 0

    @property
    def period_s(self) -> float:
        return self.inflate_s + self.hold_s + self.jet_s

    def _enter(self, phase: str, time_s: float) -> None:
        self.phase = phase
        self.phase_start_s = time_s

    def command(self, time_s: float, volume_m3: float | None = None) -> Command:
        """
        Return the command to hold from time_s on.

        volume_m3 (the measured fluid volume) ends the inflation when target_volume_m3 > 0.
        """
        # several phases may end within one call when the caller's rate is coarse
        for _ in range(8):
            if self.phase == IDLE:
                if time_s < self.start_delay_s:
                    return Command(0.0, 0.0, 0.0)
                self._enter(INFLATE, self.start_delay_s)
            elif self.phase == INFLATE:
                elapsed = time_s - self.phase_start_s
                if self.target_volume_m3 > 0.0:
                    done = volume_m3 is not None and volume_m3 >= self.target_volume_m3
                    # a time limit still ends an inflation that cannot reach its target
                    done = done or (self.inflate_s > 0 and elapsed >= self.inflate_s)
                else:
                    done = elapsed >= self.inflate_s
                if not done:
                    return Command(self.pump_flow_m3_s, 0.0, 0.0)
                self._enter(
                    HOLD,
                    time_s if self.target_volume_m3 > 0 else self.phase_start_s + self.inflate_s,
                )
            elif self.phase == HOLD:
                if time_s - self.phase_start_s < self.hold_s:
                    return Command(0.0, 0.0, 0.0)
                self._enter(JET, self.phase_start_s + self.hold_s)
            elif self.phase == JET:
                if time_s - self.phase_start_s < self.jet_s:
                    return Command(0.0, self.valve_opening, 0.0)
                self.cycle += 1
                if self.cycles and self.cycle >= self.cycles:
                    self._enter(DONE, self.phase_start_s + self.jet_s)
                else:
                    self._enter(INFLATE, self.phase_start_s + self.jet_s)
            else:  # DONE: valve left open so the shell rests unstrained
                return Command(0.0, self.valve_opening, 0.0)
        return Command(0.0, self.valve_opening, 0.0)


CABLE_SPEC = {
    'kind': Choice('cable', ('cable',)),
    'amplitude_n': Number(8.0, 0.0, Command.LIMITS['cable_force_n'][1], unit='N'),
    'frequency_hz': Number(1.6, 0.0, 100.0, low_open=True, unit='Hz'),
    'contraction_s': Number(0.2, 0.0, 100.0, low_open=True, unit='s'),
    'release_s': Number(0.3, 0.0, 100.0, low_open=True, unit='s'),
    'start_delay_s': Number(0.0, 0.0, 1e6, unit='s'),
    'pulse': Choice('half_cosine', ('half_cosine', 'triangle')),
}


@dataclass
class CableRoutine:
    """
    Periodic cable pull: a rise, a release, slack.

    A half-cosine rise to amplitude_n over contraction_s, a half-cosine release over release_s,
    slack for the rest of the period; straight lines with pulse='triangle' (the shapes of the shell
    model's built-in routine, so live and offline runs pull alike).
    """

    amplitude_n: float = 8.0
    frequency_hz: float = 1.6
    contraction_s: float = 0.2
    release_s: float = 0.3
    start_delay_s: float = 0.0
    pulse: str = 'half_cosine'

    def __post_init__(self):
        if self.contraction_s + self.release_s > 1.0 / self.frequency_hz + 1e-12:
            raise ModelError(
                f'routine: contraction_s + release_s = {self.contraction_s + self.release_s:g} s'
                f' exceeds the period 1/frequency_hz = {1.0 / self.frequency_hz:g} s; allowed: at'
                ' most the period'
            )

    @classmethod
    def from_config(cls, config: Mapping[str, Any] | None) -> 'CableRoutine':
        values = check_section('routine', config or {}, CABLE_SPEC)
        values.pop('kind')
        return cls(**values)

    def reset(self) -> None:
        """Stateless: the pull is a function of time alone."""

    def activation(self, time_s: float) -> float:
        """Return the pull's activation in [0, 1]: models/cable_pulse.py, as in the kernels."""
        return cable_pulse.activation(
            float(time_s),
            float(self.start_delay_s),
            float(self.frequency_hz),
            float(self.contraction_s),
            float(self.release_s),
            self.pulse == 'triangle',
        )[0]

    def command(self, time_s: float, volume_m3: float | None = None) -> Command:
        return Command(0.0, 1.0, self.amplitude_n * self.activation(time_s))


ROUTINES = {'pump_valve': PumpValveRoutine, 'cable': CableRoutine}


def routine_from_scene(routine: Mapping[str, Any] | None):
    """Return the routine a scene asks for (None: hold the scene's initial command)."""
    if routine is None:
        return None
    kind = routine.get('kind', 'pump_valve')
    if kind not in ROUTINES:
        raise ModelError(
            f'routine.kind: {kind!r} is not known; allowed: one of {", ".join(ROUTINES)}'
        )
    return ROUTINES[kind].from_config(routine)
