"""Progress bars on stderr for phases of known length (the fidelity check's
re-simulations, the animation's frames), drawn with tqdm.

Off by default, so library calls print nothing; the ``cstorm`` command turns them on
(``--quiet`` keeps them off). Where on, a bar is drawn only when stderr is a terminal.
"""

from __future__ import annotations

import contextlib
import sys

__all__ = ["enable", "bar"]

_ENABLED = False


def enable(on: bool = True):
    """Turn the bars of `bar` on or off for this process."""
    global _ENABLED
    _ENABLED = bool(on)


class _NoBar:
    def update(self, n=1):
        pass


@contextlib.contextmanager
def bar(total: int, desc: str):
    """A context manager giving an object with ``update(n=1)``: a tqdm bar of ``total``
    steps labelled ``desc`` on stderr when bars are on and stderr is a terminal, else
    an object that draws nothing."""
    if not _ENABLED:
        yield _NoBar()
        return
    from tqdm import tqdm

    b = tqdm(total=int(total), desc=desc, file=sys.stderr, disable=None, leave=False, dynamic_ncols=True)
    try:
        yield b
    finally:
        b.close()
