"""The exceptions fempm raises: each names the field or the cause in its message."""


class FempmError(Exception):
    """Base class of every error fempm raises on purpose."""


class InputError(FempmError, ValueError):
    """A value given by the user (argument, scene key, CLI flag) is not acceptable."""


class ParticleOutsideGridError(FempmError):
    """A particle is outside the background grid (or has a non-finite position)."""
