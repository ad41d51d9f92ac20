"""Output directories of the ``cstorm`` command: one run per directory.

A directory cstorm writes holds a manifest, ``.cstorm-manifest.json``: the command, the
cstorm version, when, and the files the run wrote. `prepare` accepts a new or empty
directory; a directory with a manifest only with ``force`` (its earlier run's files are
removed first, so none of them survives beside the new summary) or ``resume`` (the run
continues there); any other non-empty directory is refused.
"""

from __future__ import annotations

import fnmatch
import json
import os
import time

from ..errors import InputError
from ..io.files import write_json

MANIFEST = ".cstorm-manifest.json"
#: names cstorm writes into an output directory (removed by ``--force`` even when a
#: stopped run had not listed them in its manifest yet)
PATTERNS = ("summary.json", "solution.npz", "trajectory.csv", "*.png", "animation.gif", "animation.mp4",
            "checkpoint.npz*", "*_info.txt", ".tmp-*")


def read_manifest(out):
    """The manifest of ``out`` (a dict), or None when there is none."""
    try:
        with open(os.path.join(out, MANIFEST)) as f:
            m = json.load(f)
    except (OSError, ValueError):
        return None
    return m if isinstance(m, dict) and m.get("written_by") == "cstorm" else None


def prepare(out, *, force=False, resume=False, command=None, option="--out"):
    """Make ``out`` ready for a run and claim it with a manifest; raises `InputError`
    naming ``option`` and the directory when it can't be used: a file, not creatable,
    not writable, non-empty without a manifest, or holding an earlier run without
    ``force``/``resume``. Returns ``out``."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise InputError(f"{option} {out}: exists and is not a directory")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        raise InputError(f"{option} {out}: cannot create the directory: {e.strerror or e}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"{option} {out}: the directory is not writable")
    entries = sorted(os.listdir(out))
    man = read_manifest(out)
    if entries and man is None:
        shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
        raise InputError(f"{option} {out}: the directory is not empty ({shown}) and was not written by cstorm (no "
                         f"{MANIFEST}); give an empty or new directory")
    if man is not None and not resume:
        ours = [e for e in entries if e != MANIFEST]
        if ours and not force:
            shown = ", ".join(ours[:6]) + (", ..." if len(ours) > 6 else "")
            raise InputError(f"{option} {out}: holds the files of an earlier cstorm run ({shown}); --force replaces "
                             "them, --resume continues a stopped run, or give another directory")
        listed = set(man.get("files") or [])
        for e in ours:
            if e in listed or any(fnmatch.fnmatch(e, p) for p in PATTERNS):
                p = os.path.join(out, e)
                if os.path.isfile(p) or os.path.islink(p):
                    os.unlink(p)
    record(out, [], command=command, keep=bool(resume and man))
    return out


def record(out, files, *, command=None, keep=True):
    """Write the manifest of ``out`` listing ``files`` (names in ``out``); with ``keep``
    the files an existing manifest lists are kept in the list."""
    old = read_manifest(out) if keep else None
    names = sorted(set(files) | set((old or {}).get("files") or []))
    from .. import __version__

    write_json(os.path.join(out, MANIFEST), dict(
        written_by="cstorm", cstorm_version=__version__,
        command=command if command is not None else (old or {}).get("command"),
        updated=time.strftime("%Y-%m-%dT%H:%M:%S%z"), files=names))


def checkpoint_files(out):
    """The checkpoint files in ``out`` (``checkpoint.npz`` and a sequence's
    ``checkpoint.npz.seg<k>[.done].npz``)."""
    try:
        return sorted(e for e in os.listdir(out) if fnmatch.fnmatch(e, "checkpoint.npz*"))
    except OSError:
        return []
