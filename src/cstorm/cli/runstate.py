"""One run of the ``cstorm`` command: its phases (announced on stderr with the time
elapsed) and how it stops.

Stopping. SIGINT (Ctrl-C), SIGTERM and SIGHUP all stop a run the same way: in a phase
that can be cut short (loading and building the problem, checking the time step,
compiling and solving, the fidelity check, the success criteria, the pictures; all of
``info``, ``animate`` and ``check-gradients``) the signal raises KeyboardInterrupt there;
the solver returns its best iterate and the command writes ``summary.json`` (``success:
false``, ``stopped``), ``solution.npz`` and ``trajectory.csv``, prints one line and
exits with ``128 + signal`` (130, 143, 129). While files are being written the signal
is only noted, and the run stops once they are. A second signal ends the process at
once. Where the first one is not taken up within a few seconds because the process is
inside native code (XLA compiling), a watcher thread ends the process: before the
first iterate it writes a ``summary.json`` that says so; after it, the checkpoint on
disk is what ``--resume`` continues from.

``CSTORM_PAUSE_AT=PHASE[:SECONDS]`` makes the run wait (default 60 s) as PHASE starts
(``iterating``: after the first iteration); the tests use it to send a signal in a
given phase.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

#: exit code of a run stopped by each signal (128 + its number)
STOP_SIGNALS = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGHUP: 129}
#: phases where a signal raises KeyboardInterrupt (elsewhere it is noted)
INTERRUPTIBLE = {"starting", "checking the time step", "solving", "iterating", "checking the solution's time step",
                 "fidelity", "success criteria", "pictures", "animation"}
#: phases before any iterate exists (a stop there has nothing to save)
BEFORE_ITERATES = {"starting", "checking the time step", "solving"}
#: seconds the watcher waits for the main thread to take up a signal
GRACE_S = {True: 3.0, False: 20.0}


class Run:
    """Phases, progress lines and signal handling of one command run. ``quiet``
    silences the progress lines (warnings and errors still print)."""

    def __init__(self, cmd="solve", quiet=False):
        self.cmd = cmd
        self.quiet = bool(quiet)
        self.t0 = time.perf_counter()
        self.phase = "starting"
        self.signum = None
        self.has_iterate = False
        self.out = None
        self.problem_name = None
        self._taken = threading.Event()
        self._old = {}
        self._wake = None
        pause = os.environ.get("CSTORM_PAUSE_AT", "")
        name, _, secs = pause.partition(":")
        self._pause = (name, float(secs or 60.0)) if name else None

    # -- progress ------------------------------------------------------------------------
    def elapsed(self):
        return time.perf_counter() - self.t0

    def say(self, msg):
        """A progress line on stderr (not under ``--quiet``)."""
        if not self.quiet:
            print(f"cstorm: [{self.elapsed():6.1f} s] {msg}", file=sys.stderr, flush=True)

    def enter(self, phase, detail=""):
        """Start ``phase``: announce it (``"writing"`` only with a ``detail``); a signal
        noted earlier stops the run here when the phase can be cut short."""
        self.phase = phase
        if phase not in ("iterating", "writing") or detail:
            self.say(phase + (f": {detail}" if detail else ""))
        if self.signum is not None and phase in INTERRUPTIBLE:
            raise KeyboardInterrupt
        if self._pause and self._pause[0] == phase:
            print(f"cstorm: pausing {self._pause[1]:g} s at {phase} (CSTORM_PAUSE_AT)", file=sys.stderr, flush=True)
            time.sleep(self._pause[1])

    def callback(self, info):
        """The solver's per-iteration callback: notes that an iterate exists."""
        first = not self.has_iterate
        self.has_iterate = True
        if first:
            self.enter("iterating")
            self.phase = "solving"

    @property
    def stop_reason(self):
        return None if self.signum is None else signal.Signals(self.signum).name

    def exit_code(self):
        return STOP_SIGNALS.get(self.signum, 130)

    # -- signals -------------------------------------------------------------------------
    def install(self, watch=True):
        """Handle SIGINT, SIGTERM and SIGHUP (main thread only; elsewhere a no-op); with
        ``watch``, start the watcher thread (only when this process is the command)."""
        if threading.current_thread() is not threading.main_thread():
            return
        for s in STOP_SIGNALS:
            try:
                self._old[s] = signal.signal(s, self._handler)
            except (ValueError, OSError):  # pragma: no cover - a platform without the signal
                pass
        if watch:
            r, w = os.pipe()
            os.set_blocking(w, False)
            try:
                self._old_wakeup = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
            except ValueError:  # pragma: no cover
                os.close(r), os.close(w)
                return
            self._wake = (r, w)
            threading.Thread(target=self._watch, name="cstorm-stop-watcher", daemon=True).start()

    def restore(self):
        """Put back the handlers `install` replaced."""
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}
        if self._wake is not None:
            signal.set_wakeup_fd(self._old_wakeup)
            os.write(self._wake[1], b"\0")  # ends the watcher
            self._wake = None

    def _handler(self, signum, frame):
        if self.signum is not None:
            print(f"cstorm: {signal.Signals(signum).name} again: stopping at once", file=sys.stderr, flush=True)
            os._exit(STOP_SIGNALS.get(signum, 128 + signum))
        self.signum = signum
        self._taken.set()
        if self.phase in INTERRUPTIBLE:
            raise KeyboardInterrupt

    def _watch(self):
        r, _ = self._wake
        while True:
            try:
                data = os.read(r, 1)
            except OSError:  # pragma: no cover
                return
            if not data or data == b"\0":
                return
            sig = data[0]
            if sig not in STOP_SIGNALS:
                continue
            before = self.phase in BEFORE_ITERATES and not self.has_iterate
            if self._taken.wait(GRACE_S[before]):
                continue  # the main thread took it up
            name = signal.Signals(sig).name
            where = "while compiling" if before else f"during {self.phase}"
            if before and self.out:
                self.write_stub(name, where)
            what = ("no iterate yet: nothing else written" if before else
                    "the checkpoint holds the last iterate (--resume continues)")
            print(f"cstorm: stopped by {name} {where}; {what}", file=sys.stderr, flush=True)
            os._exit(STOP_SIGNALS[sig])

    def write_stub(self, name, where):
        """``summary.json`` of a run stopped before its first iterate."""
        from ..io.files import write_json

        try:
            write_json(os.path.join(self.out, "summary.json"), dict(
                problem=self.problem_name, success=False, solver_success=False,
                message=f"stopped by {name} {where}, before the first iterate",
                stopped=dict(reason=name, phase=self.phase), files=["summary.json"]))
        except OSError:  # pragma: no cover - the message still prints
            pass
