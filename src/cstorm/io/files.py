"""Atomic file writes and strict JSON.

`atomic_write` is the one way cstorm writes a file: the content goes to a temporary file
with a unique name in the destination's folder, is flushed to disk (``fsync``), moved
onto the destination (``os.replace``), and the folder's entry is flushed too. A reader
sees the old file or the new one, never a part, and a power cut after the call returns
loses neither. `write_json`, `write_text` and `atomic_savez` are built on it.
"""

from __future__ import annotations

import json
import math
import os
import tempfile

import numpy as np

__all__ = ["atomic_write", "atomic_savez", "write_json", "write_text", "json_safe"]


def atomic_write(path, write, suffix=""):
    """Call ``write(tmp_path)`` on a temporary path next to ``path`` (a unique name
    ``.tmp-*<suffix>`` in the same folder; ``suffix`` defaults to ``path``'s extension,
    for writers that pick a format by name), ``fsync`` it, move it onto ``path``
    (``os.replace``) and ``fsync`` the folder. The temporary is removed on any error or
    interruption. Returns ``path``."""
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=suffix or os.path.splitext(path)[1], dir=d)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        _fsync_path(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    _fsync_dir(d)
    return path


def atomic_savez(path, arrays: dict):
    """``np.savez(path, **arrays)`` through `atomic_write` (no pickle)."""
    def w(tmp):
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return atomic_write(path, w, ".npz")


def write_text(path, text: str):
    """Write ``text`` (UTF-8) through `atomic_write`."""
    def w(tmp):
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
    return atomic_write(path, w)


def _fsync_path(path):
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(d):
    """Flush a folder's entries (the rename); a no-op where folders can't be opened."""
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:  # pragma: no cover - e.g. Windows
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - some file systems refuse fsync on folders
        pass
    finally:
        os.close(fd)


def _umask():
    m = os.umask(0)
    os.umask(m)
    return m


def write_json(path, obj):
    """Write ``obj`` as indented JSON, atomically. NaN/inf become null (strict JSON)."""
    return write_text(path, json.dumps(json_safe(obj), indent=2, allow_nan=False) + "\n")


def json_safe(x):
    """``x`` with numpy values as Python values and NaN/inf as None (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, np.generic):
        return json_safe(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
