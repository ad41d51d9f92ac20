"""Initial guesses (`cstorm.optimize.guesses`)."""

from __future__ import annotations

import numpy as np

from cstorm.optimize import keyframe_guess


def test_keyframe_guess_passes_through_its_keyframes_at_rest():
    """Each joint goes through its keyframe angles at the keyframe times, with zero slope
    there (smoothstep ramps), monotone between two keyframes; 400 samples over
    ``[0, t_final]``."""
    kf = ((0.0, (0.0, 1.0)), (0.25, (1.0, 1.0)), (1.0, (-0.5, 0.0)))
    g = keyframe_guess(kf, 2.0, ("a", "b"))
    assert set(g) == {"a", "b"}
    t, a = g["a"]
    assert t.shape == a.shape == (400,) and t[0] == 0.0 and t[-1] == 2.0
    for frac, vals in kf:
        i = int(np.argmin(np.abs(t - frac * 2.0)))
        assert abs(t[i] - frac * 2.0) < 2.0 / 399
        np.testing.assert_allclose(a[i], vals[0], atol=1e-3)
    np.testing.assert_allclose(g["b"][1][[0, -1]], [1.0, 0.0])
    seg = a[(t >= 0.5) & (t <= 2.0)]
    assert np.all(np.diff(seg) <= 1e-15)  # 1 -> -0.5, monotone
    k = int(np.argmin(np.abs(t - 0.5)))
    assert abs(a[k + 1] - a[k]) < 1e-4  # at rest at the keyframe
