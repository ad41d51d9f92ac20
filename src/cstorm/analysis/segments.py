"""The segments of a problem or sequence and of its solution, and selecting one segment."""

from __future__ import annotations

from ..errors import InputError
from ..optimize.problem import MotionProblem
from ..optimize.sequence import MotionSequence

__all__ = ["problem_segments", "segment_solutions", "select_segment"]


def problem_segments(problem) -> list:
    """The `MotionProblem` segments of a problem or sequence (a list, one entry for a
    single problem)."""

    if isinstance(problem, MotionSequence):
        return list(problem.segments)
    if isinstance(problem, MotionProblem):
        return [problem]
    raise InputError(f"expected a MotionProblem or MotionSequence, got {type(problem).__name__}")


def segment_solutions(solution) -> list:
    """Per-segment `Solution` objects (the solution itself if it has no segments)."""
    return list(solution.segments) if solution.segments else [solution]


def select_segment(problem, name):
    """The segment named ``name`` (or with that 0-based index) of a `MotionSequence`.

    The returned `MotionProblem` starts from its own ``q0``/``v0``: the nominal start of
    that segment as its author set it (for the shipped sequences, the nominal end posture
    of the previous segment, at rest), not the end of a solved previous segment."""

    if not isinstance(problem, MotionSequence):
        raise InputError(f"--segment: problem {problem.name!r} is a single motion, not a sequence of segments")
    names = [s.name for s in problem.segments]
    if name in names:
        return problem.segments[names.index(name)]
    try:
        k = int(name)
    except (TypeError, ValueError):
        k = None
    if k is not None and 0 <= k < len(names):
        return problem.segments[k]
    raise InputError(f"--segment: sequence {problem.name!r} has no segment {name!r}; segments are {names}")
