"""The one stepping loop that sim_node, the offline runner, the tests and the benchmarks share."""

from __future__ import annotations

from pulsejet_sim.core.model_io import Command, Observation, SimulationBlowUp
from pulsejet_sim.core.protocol import Model


class Simulation:
    """Mutable state of one run of an immutable model (MuJoCo's model/data split)."""

    def __init__(self, model: Model, command: Command | None = None):
        self.model = model
        # the model's actuator ranges (e.g. a shell robot's cable rating) within Command.LIMITS
        self.command_limits = dict(getattr(model, 'command_limits', None) or Command.LIMITS)
        self.default_command = command or getattr(model, 'initial_command', Command())
        self.reset()

    def reset(self) -> Observation:
        """Back to the scene's initial state, time zero, ledger cleared."""
        self.initial_state = self.model.initial_state()
        forget = getattr(self.model, 'reset_workspace', None)
        if forget is not None:
            forget()  # a kept solver workspace (the shell's Newton) belongs to the old run
        self.state = self.initial_state.copy()
        self.steps = 0
        self.command = self.default_command
        self.fault: str | None = None
        return self.observe()

    @property
    def time_s(self) -> float:
        # integer step count times dt: no drift over long runs
        return self.steps * self.model.dt_s

    def step(self, n_steps: int, command: Command | None = None) -> Observation:
        """
        Advance n_steps physics steps holding `command`.

        Raises SimulationBlowUp (state kept at the last good step, further steps refused until
        reset).
        """
        if self.fault is not None:
            raise SimulationBlowUp(
                f'simulation is stopped after a fault: {self.fault}; reset to continue',
                self.time_s,
            )
        if command is not None and command is not self.command:
            # checked once per new command (CommandError names the bad value): a NaN or an
            # out-of-range value never reaches the physics, whoever calls
            self.command = command.validate(self.command_limits)
        if n_steps > 0:
            try:
                done = self.model.advance(self.state, self.time_s, n_steps, self.command)
            except SimulationBlowUp as err:
                self.steps = int(round(err.time_s / self.model.dt_s))
                self.fault = str(err)
                raise
            self.steps += done
        return self.observe()

    def observe(self) -> Observation:
        return self.model.observe(self.state, self.time_s, self.command)

    def energy_ledger(self) -> dict[str, float]:
        return self.model.energy_ledger(self.state)

    def profile(self):
        return self.model.profile(self.state)

    def stable_step_s(self) -> float:
        return self.model.stable_step_s(self.state)
