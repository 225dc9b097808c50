"""
The model protocol: what the engine asks of a physics model, and nothing more.

A model is immutable after `from_scene` (MuJoCo's model/data split): the mutable run lives in a
state vector the engine owns (engine.simulation.Simulation). Both models of pulsejet
(models.lumped.model.LumpedModel and models.shell.model.ShellModel) satisfy it;
test/test_model_protocol.py checks their methods against it, name by name and parameter by
parameter. A new model satisfies it and registers a builder in models.MODEL_BUILDERS.
"""

from __future__ import annotations

from typing import Any, Mapping, Protocol, runtime_checkable

import numpy as np
from pulsejet_sim.core.model_io import Command, Observation


@runtime_checkable
class Model(Protocol):
    """A physics model the engine steps; every quantity in SI units."""

    #: physics step, s
    dt_s: float

    @classmethod
    def from_scene(cls, scene: Mapping[str, Any]) -> 'Model':
        """Build the model a scene's data describes (ModelError names a bad key)."""

    def initial_state(self) -> np.ndarray:
        """Return a new state vector at t = 0."""

    def advance(self, state: np.ndarray, time_s: float, n_steps: int, command: Command) -> int:
        """
        Advance `state` in place by n_steps steps of dt_s from time_s, holding command.

        Returns the steps taken; raises core.model_io.SimulationBlowUp with the time of the last
        good state (the state is left there).
        """

    def observe(self, state: np.ndarray, time_s: float, command: Command) -> Observation:
        """Return what the sensors of the robot would read in `state`."""

    def energy_ledger(self, state: np.ndarray) -> dict[str, float]:
        """Return the energy ledger since t = 0, J (keys in docs/theory)."""

    def profile(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Return the mantle's meridian (r_m, z_m), or None for a model without one."""

    def stable_step_s(self, state: np.ndarray) -> float:
        """Return the largest step, s, the model's integrator is stable with in `state`."""
