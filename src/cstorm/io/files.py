"""Atomic file writes (a temporary file in the same folder, then ``os.replace``) and
strict JSON."""

from __future__ import annotations

import json
import math
import os
import tempfile

import numpy as np

__all__ = ["atomic_write", "write_json", "json_safe"]


def atomic_write(path, write, suffix=""):
    """Call ``write(tmp_path)`` on a temporary path next to ``path``, then move it onto
    ``path`` (``os.replace``); the temporary is removed on error."""
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=suffix or os.path.splitext(path)[1], dir=d)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _umask():
    m = os.umask(0)
    os.umask(m)
    return m


def write_json(path, obj):
    """Write ``obj`` as indented JSON, atomically. NaN/inf become null (strict JSON)."""
    text = json.dumps(json_safe(obj), indent=2, allow_nan=False)

    def w(tmp):
        with open(tmp, "w") as f:
            f.write(text + "\n")
    return atomic_write(path, w, ".json")


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
