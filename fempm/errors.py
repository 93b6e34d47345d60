"""The exceptions fempm raises: each names the field or the cause in its message."""


class FempmError(Exception):
    """Base class of every error fempm raises on purpose."""


class InputError(FempmError, ValueError):
    """A value given by the user (argument, scene key, CLI flag) is not acceptable."""


class ParticleOutsideGridError(FempmError):
    """A particle is outside the background grid (or has a non-finite position)."""


class SimulationDiverged(FempmError):
    """The run cannot go on; ``time``, ``step`` and ``cause`` say when and why."""

    def __init__(self, time: float, step: int, cause: str):
        super().__init__(f"stopped at t = {time:.6g} s (step {step}): {cause}")
        self.time, self.step, self.cause = time, step, cause
