"""The project's one error family: catch `PrsmError` for all of them, or one member.

Every message names what was wrong (the field or input), the value, and what is allowed, in
one line, so a command-line tool can print it as it is and exit with status 2. `DriveLoopWarning` is the
one warning category of its own: a setting that runs, but not as a user would mean it to.
"""

from __future__ import annotations


class PrsmError(Exception):
    """Base of every error this project raises on purpose."""


class ParamError(PrsmError, ValueError):
    """A parameter value, name or file was refused; the message says which and what is allowed."""


class InputError(PrsmError, ValueError):
    """A step or run input was refused (non-finite, wrong shape or type); the state is unchanged."""


class ModelError(PrsmError, RuntimeError):
    """A model could not be built or advanced for valid-looking parameters (e.g. no thread contact found)."""


class NonFiniteStateError(ModelError):
    """A step or run produced a non-finite state; the state before it is kept.

    Attributes
    ----------
    time_s : float
        Simulation time of the first non-finite state, s.
    """

    def __init__(self, message: str, time_s: float) -> None:
        super().__init__(message)
        self.time_s = time_s


class DriveLoopWarning(UserWarning):
    """The drive's sampled loop, as configured, does not settle on the inertia it drives: it will ring."""
