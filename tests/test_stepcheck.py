"""`cs.check_time_step`: the time step against the integrator's stability limit of the
linearized passive dynamics (src/cstorm/analysis/timestep.py).

(a) the tumbler standing on its foot: RK4 at 4 ms is past the limit of the friction's
    viscous mode (found by simulation: 3 ms agrees with 0.25 ms, 4 ms does not), 2 ms is
    inside; (b) closed forms: a damped slider (eigenvalues, RK4 and semi-implicit Euler
    limits) and a free body spinning about its intermediate axis (tangent space);
(c) `cstorm solve` records the check in summary.json and warns on stderr."""

import contextlib
import importlib
import io
import json
import math
import os

import numpy as np
import pytest

import cstorm as cs
from cstorm.cli import commands as cli
from cstorm.analysis.timestep import RK4_REAL_LIMIT, rk4_factor

T = importlib.import_module("cstorm.examples.tumbler")


# ---------------------------------------------------------------------------------------
# (a) the tumbler
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tumbler4():
    p = T.tumbler_segment("start", dt=4e-3)
    return p, cs.check_time_step(p)


def test_tumbler_at_4ms_is_flagged(tumbler4):
    p, r = tumbler4
    assert r["ok"] is False and r["integrator"] == "rk4" and r["dt"] == pytest.approx(4e-3)
    # measured 3.754 ms (a mode of rate 742 1/s at t = 1.84 s of the guess, arms down)
    assert 3e-3 < r["dt_limit"] < 4e-3
    lam = complex(r["worst_lambda"]["real"], r["worst_lambda"]["imag"])
    assert lam.real < -600 and abs(lam.imag) < 1e-6 * abs(lam)  # a damper, not an oscillation
    assert r["dt_limit"] == pytest.approx(RK4_REAL_LIMIT / abs(lam), rel=1e-9)
    assert r["amplification"] == pytest.approx(rk4_factor(lam * p.dt), rel=1e-12) and r["amplification"] > 1.1
    assert r["worst_lambda_dt"]["real"] == pytest.approx(lam.real * p.dt)
    assert r["dof"] == "root_pitch" and r["dof_shares"]["root_pitch"] > 0.9
    assert r["where"].startswith("along the initial guess") and r["rollout"] == "ok" and r["n_states"] == 201
    assert 0 < r["t"] <= p.t_final and r["max_abs_lambda"] >= abs(lam)
    for w in ("dt = 4 ms", "RK4", "root_pitch", "1.5 mu N / v_max", "use dt <= 3.7 ms"):
        assert w in r["message"], r["message"]
    json.dumps(r)  # JSON-able


def test_tumbler_start_and_end_postures(tumbler4):
    """The initial state alone (arms overhead) allows 4.84 ms; standing with the arms down
    (`start_q`, where the segment goes) 3.77 ms: the guess is what finds the limit."""
    p, _ = tumbler4
    r0 = cs.check_time_step(p, along="start")
    assert r0["ok"] is True and r0["n_states"] == 1 and 4.7e-3 < r0["dt_limit"] < 5e-3
    r1 = cs.check_time_step(p, q=T.start_q(p.model))
    assert r1["ok"] is False and 3.7e-3 < r1["dt_limit"] < 3.85e-3 and r1["where"] == "at the given state"
    assert r1["dof"] == "root_pitch"
    # the same states judged at 2 ms and 3.7 ms (inside), semi-implicit Euler at 4 ms (outside)
    assert cs.check_time_step(p, q=T.start_q(p.model), dt=3.7e-3)["ok"] is True
    e = cs.check_time_step(p, q=T.start_q(p.model), integrator="euler")
    assert e["ok"] is False and e["integrator"] == "euler" and e["dt_limit"] < r1["dt_limit"]


def test_tumbler_at_2ms_is_ok():
    p = T.tumbler_segment("start", dt=2e-3)
    r = cs.check_time_step(p)
    assert r["ok"] is True and 3e-3 < r["dt_limit"] < 4e-3 and r["amplification"] < 1
    assert "within RK4's stability limit" in r["message"]


@pytest.mark.slow
def test_tumbler_limit_matches_simulation(tumbler4):
    """From `start_q` the linearization's limit (3.77 ms) separates steps that agree with
    0.25 ms (3% inside) from steps that do not (3% past): the measured instability."""
    p, _ = tumbler4
    q = T.start_q(p.model)
    lim = cs.check_time_step(p, q=q)["dt_limit"]
    env, contact = T.env_contact()
    vT = {dt: cs.simulate.simulate(p.model, q, np.zeros(5), t_final=2.0, dt=dt, active=("hip", "shoulder"), env=env,
                                   contact=contact).v[-1, :3] for dt in (2.5e-4, 0.97 * lim, 1.03 * lim)}
    ref = vT[2.5e-4]
    assert np.max(np.abs(vT[0.97 * lim] - ref)) < 1e-5
    assert np.max(np.abs(vT[1.03 * lim] - ref)) > 1e-2


# ---------------------------------------------------------------------------------------
# (b) closed forms
# ---------------------------------------------------------------------------------------
def slider_problem(m, k, c, dt, name="slider"):
    """A passive slider (mass m, spring k, damper c; along x, gravity along z) and,
    on a separate branch, a small active arm: the slider's dynamics is exactly
    ``m x'' = -k x - c x'``."""
    b = cs.ModelBuilder(name)
    b.add_body("slider", None, "prismatic", axis=(1, 0, 0), mass=m, inertia=np.eye(3) * 1e-2, stiffness=k, damping=c)
    b.add_body("arm", None, "revolute", joint_name="elbow", axis=(0, 1, 0), xyz=(0, 0.5, 0), mass=0.1,
               com=(0.1, 0, 0), inertia=np.eye(3) * 1e-3)
    model = b.build()
    return cs.MotionProblem(model, ["elbow"], 1.0, 6, dt, np.zeros(2), q_final_active={"elbow": 0.5}, name=name)


def _roots_positive(coeffs):
    r = np.roots(coeffs)
    return np.sort(r[(abs(r.imag) < 1e-9 * abs(r)) & (r.real > 0)].real)


def _rk4_limit(lam):
    """Smallest h > 0 with |R(h lam)|^2 = 1: roots of a degree-8 polynomial in h."""
    r = np.array([lam ** j / math.factorial(j) for j in range(5)])  # R(h lam) = sum r_j h^j
    P = np.zeros(9)
    for j in range(5):
        for l in range(5):
            P[j + l] += (r[j] * np.conj(r[l])).real
    P[0] -= 1.0
    return _roots_positive(P[::-1])[0]


@pytest.mark.parametrize("m, k, c", [(1.0, 100.0, 50.0), (2.0, 800.0, 8.0)])  # over- and underdamped
def test_damped_slider_closed_form(m, k, c):
    p = slider_problem(m, k, c, 0.01)
    r = cs.check_time_step(p, along="start")
    disc = complex(c * c - 4 * k * m) ** 0.5
    lam = np.array([(-c + disc) / (2 * m), (-c - disc) / (2 * m)])
    got = np.array([complex(*z) for z in r["eigenvalues"]])
    np.testing.assert_allclose(np.sort_complex(got), np.sort_complex(lam), rtol=1e-8, atol=1e-8 * abs(lam).max())
    fast = lam[np.argmax(abs(lam))] if c * c > 4 * k * m else lam[np.argmax(lam.imag)]
    x_star = _roots_positive([1.0, -4.0, 12.0, -24.0])[0]  # R(-x) = 1
    assert x_star == pytest.approx(RK4_REAL_LIMIT, rel=1e-13)
    rk4 = x_star / abs(fast) if c * c > 4 * k * m else _rk4_limit(fast)
    assert r["dt_limit"] == pytest.approx(rk4, rel=1e-8)
    assert r["worst_lambda"]["real"] == pytest.approx(fast.real, rel=1e-8)
    assert abs(r["worst_lambda"]["imag"]) == pytest.approx(abs(fast.imag), rel=1e-8, abs=1e-8)
    assert r["dof"] == "slider" and r["dof_shares"] == {"slider": 1.0}
    # semi-implicit Euler, exact for one DoF: stable iff k h^2 + 2 c h - 4 m <= 0
    eu = cs.check_time_step(p, along="start", integrator="euler")
    assert eu["dt_limit"] == pytest.approx((math.sqrt(c * c + 4 * k * m) - c) / k, rel=1e-8)
    for res, lim, integ in ((r, rk4, "rk4"), (eu, eu["dt_limit"], "euler")):
        assert cs.check_time_step(p, along="start", integrator=integ, dt=0.99 * lim)["ok"] is True
        bad = cs.check_time_step(p, along="start", integrator=integ, dt=1.01 * lim)
        assert bad["ok"] is False and bad["amplification"] > 1 and "past" in bad["message"]
    assert "joint" in bad["message"]  # no contact: a joint spring or damper


def test_slider_along_guess_and_no_false_alarm():
    p = slider_problem(1.0, 100.0, 50.0, 0.01)
    r = cs.check_time_step(p)  # the guess moves only the decoupled arm
    assert r["ok"] is True and r["n_states"] == 201 and r["rollout"] == "ok" and r["n_unstable"] == 0
    assert r["dt_limit"] == pytest.approx(RK4_REAL_LIMIT * 2 / (50 + math.sqrt(2100)), rel=1e-8)
    g = cs.check_time_step(p, along={"q": np.zeros((3, 2)), "v": np.zeros((3, 2))}, dt=0.07)
    assert g["ok"] is False and g["where"] == "along the given trajectory" and g["n_unstable"] == 3
    assert g["t"] is None and g["unstable_s"] is None and g["rollout"] is None


def test_free_body_intermediate_axis():
    """A free body (no gravity) spinning at w about its intermediate principal axis: the
    tangent-space linearization holds Euler's equations' rates +-w sqrt((I2-I1)(I3-I2)/(I1 I3))
    (the physical tumbling, growing: not flagged) next to the arm's."""
    I1, I2, I3, w = 0.01, 0.02, 0.025, 5.0
    b = cs.ModelBuilder("spinner", gravity=(0.0, 0.0, 0.0))
    b.add_body("body", None, "free", mass=1.0, inertia=np.diag([I1, I2, I3]))
    b.add_body("arm", None, "revolute", joint_name="elbow", axis=(0, 1, 0), mass=0.1, com=(0.1, 0, 0),
               inertia=np.eye(3) * 1e-3)
    model = b.build()
    q0 = np.array([0, 0, 0, 1.0, 0, 0, 0, 0.0])
    v0 = np.array([0, w, 0, 0, 0, 0, 0.0])  # body frame [omega; v]
    p = cs.MotionProblem(model, ["elbow"], 1.0, 6, 0.01, q0, v0)
    r = cs.check_time_step(p, q=q0, v=v0)
    lam = np.array([complex(*z) for z in r["eigenvalues"]])
    rate = w * math.sqrt((I2 - I1) * (I3 - I2) / (I1 * I3))
    for target in (rate, -rate):
        assert np.min(abs(lam - target)) < 1e-8 * rate, lam
    assert lam.size == 12 and r["ok"] is True
    assert len(r["dof_shares"]) == 6 and all(n.startswith("body_") for n in r["dof_shares"])


def test_bad_input():
    p = slider_problem(1.0, 100.0, 50.0, 0.01)
    with pytest.raises(cs.InputError, match="integrator"):
        cs.check_time_step(p, integrator="rk45")
    with pytest.raises(cs.InputError, match="along"):
        cs.check_time_step(p, along="everywhere")
    with pytest.raises(cs.InputError, match="MotionProblem"):
        cs.check_time_step(cs.MotionSequence([p, p]))


# ---------------------------------------------------------------------------------------
# (c) cstorm solve records it
# ---------------------------------------------------------------------------------------
def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(argv)
    return rc, out.getvalue(), err.getvalue()


def _one_json(stdout):
    lines = [ln for ln in stdout.splitlines() if ln.strip()]
    assert len(lines) == 1, stdout
    return json.loads(lines[0])


def test_cli_solve_records_time_step(tmp_path, monkeypatch):
    from cstorm import examples

    m, k, c = 1.0, 100.0, 50.0
    lim = RK4_REAL_LIMIT * 2 * m / (c + math.sqrt(c * c - 4 * k * m))  # 58 ms
    stiff = slider_problem(m, k, c, 0.0625, name="stiff")  # 16 steps, past the limit
    fine = slider_problem(m, k, c, 0.02, name="fine")
    monkeypatch.setattr(cli, "_PROBLEMS", {})  # the CLI's cache of built problems: keep ours out of other tests
    monkeypatch.setitem(examples.registry(), "stiff", lambda: stiff)
    monkeypatch.setitem(examples.registry(), "stiff_seq", lambda: cs.MotionSequence([fine, stiff], name="stiff_seq"))
    fast = ["--max-iter", "1", "--no-fidelity", "--no-animation", "--json"]
    rc, stdout, stderr = _run(["solve", "stiff", "--out", str(tmp_path / "one"), *fast])
    s = _one_json(stdout)
    ts = s["time_step"]
    assert ts["ok"] is False and ts["dt"] == pytest.approx(0.0625) and ts["dt_limit"] == pytest.approx(lim, rel=1e-8)
    assert ts["dof"] == "slider" and s["segments"][0]["time_step"] == ts
    assert ts["where"].startswith("along the initial guess") and ts["n_unstable"] == ts["n_states"] == 4 * 16 + 1
    # after the solve, the same check along the solution (its controls rolled out at dt/4)
    assert ts["solution"]["ok"] is False and ts["solution"]["where"].startswith("along the solution")
    assert ts["solution"]["dt_limit"] == pytest.approx(lim, rel=1e-8)
    assert any(w.startswith("time step: the initial guess: dt = 62.5 ms is past RK4's stability limit")
               for w in s["warnings"])
    assert any(w.startswith("time step: the solution: dt = 62.5 ms") for w in s["warnings"])
    assert "warning: stiff: the initial guess: dt = 62.5 ms is past RK4's stability limit (58.1 ms)" in stderr
    on_disk = json.loads((tmp_path / "one" / "summary.json").read_text())
    assert on_disk["time_step"] == ts
    # a sequence: per segment, and a top-level verdict
    rc, stdout, stderr = _run(["solve", "stiff_seq", "--out", str(tmp_path / "seq"), *fast])
    s = _one_json(stdout)
    ts = s["time_step"]
    assert ts["ok"] is False and ts["dt_limit"] == pytest.approx(lim, rel=1e-8)
    assert [g["segment"] for g in ts["segments"]] == ["fine", "stiff"]
    assert [g["time_step"]["ok"] for g in s["segments"]] == [True, False]
    assert [g["time_step"]["solution"]["ok"] for g in s["segments"]] == [True, False] and ts["solution_ok"] is False
    assert stderr.count("warning: stiff:") == 2 and "warning: fine:" not in stderr
    # --no-step-check: not run, not recorded
    rc, stdout, stderr = _run(["solve", "stiff", "--out", str(tmp_path / "off"), "--no-step-check", *fast])
    assert "time_step" not in _one_json(stdout) and "stability" not in stderr
