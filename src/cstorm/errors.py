"""Exceptions raised by cstorm. Every message names the file, element, joint, body, shape
or argument at fault and what is wrong with it."""


class CstormError(Exception):
    """Base class of cstorm's errors."""


class ModelError(CstormError, ValueError):
    """A robot model (builder, URDF, MJCF) is malformed or non-physical."""


class ShapeError(CstormError, ValueError):
    """A collision shape or contact parameter is invalid."""


class InputError(CstormError, ValueError):
    """An argument of a top-level call has the wrong shape, dtype or value."""


class DivergenceError(CstormError, RuntimeError):
    """A simulation produced NaN/inf or left its bounds; the message says when and where."""


class ProblemError(CstormError, ValueError):
    """A motion problem is ill-posed (unknown joint names, inconsistent sizes, ...)."""


class ContactParamError(ShapeError):
    """A contact parameter (stiffness, damping, d_on, d_off, friction, v_max, eps) is
    invalid; the message names it. A subclass of `ShapeError`."""


class ModelWarning(UserWarning):
    """A robot model loaded, with something implausible or ignored; the message names the
    file, body, link or element and says what it changes."""


class TimeStepWarning(UserWarning):
    """A fixed-step rollout's ``dt`` is past its integrator's stability limit for a mode
    of the dynamics along the rollout (`cstorm.check_time_step`); the message says which
    mode and what step would do."""
