"""Multiple shooting (``MotionProblem(shooting=K)``) on the acrobot.

- With its nodes on the single-shooting rollout (`shoot_nodes`), the K-interval problem
  has exactly the single-shooting objective and constraints, zero continuity defects and
  the same stitched trajectory.
- Its exact Jacobian (nodes included) matches central finite differences, also at
  nodes off the rollout (defects nonzero).
- It solves the swing-up to a continuous motion (defects <= 1e-6; a single-shooting
  re-simulation of its controls lands where it says).
- Bad ``shooting`` values and partly active joints are refused with a clear message.

One K = 5 problem (module fixture) is shared, so its functions compile once.
"""

from __future__ import annotations

import numpy as np
import pytest
import jax.numpy as jnp

from cstorm import examples
from cstorm.examples.acrobot import acrobot_model
from cstorm.errors import ProblemError
from cstorm.optimize import MotionProblem, check_gradients, solve

FAST = dict(t_final=3.0, n_ctrl=16, dt=0.02)
K = 5


@pytest.fixture(scope="module")
def single():
    return examples.get("acrobot")(**FAST)


@pytest.fixture(scope="module")
def multi():
    return examples.get("acrobot")(**FAST, shooting=K)


def test_layout_and_continuity_terms(single, multi):
    nvp = 1  # the shoulder
    assert multi.n_vars == single.n_vars + 2 * nvp * (K - 1)
    assert multi.n_eq == single.n_eq + 2 * nvp * (K - 1)
    kind, sl, stage, label = multi.term_slices[-1]
    assert (kind, stage, label) == ("eq", 0, "shooting continuity") and sl.stop == multi.n_eq
    assert multi.describe()["shooting"] == K and "shooting" not in single.describe()
    assert multi.hash() != single.hash()


def test_nodes_on_the_rollout_reproduce_single_shooting(single, multi):
    d1, dk = single.data(), multi.data()
    x = multi.shoot_nodes(multi.x0, dk)
    np.testing.assert_array_equal(x[:single.n_vars], single.x0)
    f1, e1, i1, _ = (np.asarray(a) for a in single.compiled("fun")(jnp.asarray(single.x0), d1))
    fk, ek, ik, div = (np.asarray(a) for a in multi.compiled("fun")(jnp.asarray(x), dk))
    assert not div
    # measured: identical to the last bit or two (the intervals restart from the recorded
    # state, the same floating-point numbers)
    np.testing.assert_allclose(fk, f1, rtol=1e-12)
    np.testing.assert_allclose(ek[:single.n_eq], e1, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ek[single.n_eq:], 0.0, atol=1e-12)
    np.testing.assert_allclose(ik, i1, atol=1e-12)
    t1 = single.compiled("trajectory")(jnp.asarray(single.x0), d1)
    tk = multi.compiled("trajectory")(jnp.asarray(x), dk)
    assert tk["q"].shape == t1["q"].shape == (single.n_steps + 1, 2)
    for key in ("q", "v", "a", "tau"):
        np.testing.assert_allclose(np.asarray(tk[key]), np.asarray(t1[key]), rtol=1e-10, atol=1e-10)


def test_jacobian_matches_central_differences_off_the_rollout(multi):
    rng = np.random.default_rng(3)
    x = multi.shoot_nodes(multi.x0) + 0.05 * rng.standard_normal(multi.n_vars)  # defects nonzero
    rep = check_gradients(multi, x=x)
    # measured: objective 4e-10 .. 6e-10 relative; the worst entry anywhere is off by
    # 1.7e-10 absolute (Jacobian entries are O(1): the continuity rows hold +-1), which is
    # central differences' rounding noise (eps_mach |c| / h ~ 1e-10), 1.4e-5 relative
    # only on entries of size ~1e-5
    assert all(p["objective_rel_error"] < 1e-7 for p in rep["points"]), rep["points"]
    assert rep["max_abs_error"] < 1e-8 and rep["max_rel_error"] < 1e-3, rep["points"]


def test_multiple_shooting_solves_the_swing_up(multi):
    s = solve(multi, max_iter=300)
    assert s.success, s.message
    assert s.constraint_violation <= 1e-6
    qT, vT = s.trajectory["q"][-1], s.trajectory["v"][-1]
    assert abs(qT[0] - np.pi) < 1e-5 and abs(vT[0]) < 1e-5
    # the stitched trajectory is one motion: re-simulate the controls by single shooting
    single = examples.get("acrobot")(**FAST)
    tr = single.compiled("trajectory")(jnp.asarray(s.x[:single.n_vars]), single.data())
    np.testing.assert_allclose(np.asarray(tr["q"]), s.trajectory["q"], atol=1e-5)


def test_bad_shooting_is_refused():
    m = acrobot_model()
    with pytest.raises(ProblemError, match="must divide the number of steps"):
        MotionProblem(m, ["elbow"], 1.0, 8, 0.1, np.zeros(2), shooting=3)
    with pytest.raises(ProblemError, match="positive integer"):
        MotionProblem(m, ["elbow"], 1.0, 8, 0.1, np.zeros(2), shooting=0)


def test_variable_groups_partition_x(multi):
    g = multi.variable_groups()
    allidx = np.concatenate([g[k] for k in ("spline", "initial_q", "initial_v", "node_q", "node_v")])
    np.testing.assert_array_equal(np.sort(allidx), np.arange(multi.n_vars))
    assert len(g["node_q"]) == len(g["node_v"]) == K - 1 and len(g["spline"]) == multi.n_spline_vars


def test_trust_constr_with_unbounded_node_variables(multi):
    """trust-constr takes the nodes' infinite bounds (only the splines are boxed)."""
    s = solve(multi, method="trust-constr", max_iter=3)
    assert np.all(np.isfinite(s.x)) and s.iterations >= 1
