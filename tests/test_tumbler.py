"""The shipped tumbler sequence (issue 6): structure, nominal postures, solve plans, the
default guesses' rollouts, the per-stage trust region; the full solves are slow (see the
module docstring of `cstorm.examples.tumbler`, Status, for what is solved)."""

from __future__ import annotations

import importlib

import jax.numpy as jnp
import numpy as np
import pytest

import cstorm as cs

T = importlib.import_module("cstorm.examples.tumbler")  # the module (cs.examples.tumbler is the factory)


@pytest.fixture(scope="module")
def model():
    return cs.robots.tumbler(feet=True)


def test_sequence_structure():
    seq = cs.examples.tumbler()
    assert isinstance(seq, cs.MotionSequence)
    assert [s.name for s in seq.segments] == list(T.SEGMENTS)
    for s in seq.segments:
        assert s.active == ("hip", "shoulder")
        assert s.success_criteria
    labels = cs.contact_labels(seq.segments[0].model, seq.segments[0].env)
    assert {g for g, _, _ in labels} == {"torso", "legs", "arms", "foot", "palm"}
    # in the sequence the roll's joints end as in ROLL_END (the standing plan's start), by
    # construction; the passive base ends wherever the roll takes it
    roll = seq.segments[1]
    np.testing.assert_allclose(roll.qa_final, T.ROLL_END[0][3:])
    np.testing.assert_allclose(roll.va_final, T.ROLL_END[1][3:])
    assert T.tumbler_segment("roll").qa_final is None
    with pytest.raises(ValueError, match="roll_end"):
        T.tumbler_segment("roll", roll_end="pinned")


@pytest.mark.parametrize("posture", ["start_q", "handstand_q"])
def test_nominal_postures_are_at_rest(model, posture):
    """Held still, the start posture (on the foot) and the handstand (on the palm) stay
    put: they are statically stable rest states of the contact model at the height the
    example computes (no drop, no drift)."""
    env, contact = T.env_contact()
    q0 = getattr(T, posture)(model)
    tr = cs.simulate.simulate(model, q0, t_final=0.5, dt=4e-3, active=("hip", "shoulder"), env=env, contact=contact)
    q, v = np.asarray(tr.q), np.asarray(tr.v)
    # rests near the computed sink; on the compliant, lightly damped contact the tall body
    # rocks by a few mrad (period ~1.2 s) where its CoM is off the support's centre (arms
    # down), without drifting away
    assert np.max(np.abs(q[:, 1] - q0[1])) < 1e-3  # m
    assert np.max(np.abs(q[:, 0] - q0[0])) < 1e-2  # m
    assert np.max(np.abs(q[:, 2] - q0[2])) < 2e-2  # rad
    assert np.max(np.abs(v)) < 0.1  # no fall


@pytest.mark.parametrize("name", ["handstand", "standing", "start"])
def test_rest_plans_end_tight_enough_for_the_criteria(name):
    """The at-rest segments' solve plans: the pitch ramp (level 0) then the rest ramp
    (level 1) whose last stage is at least as tight as the success criteria (final base
    velocities `REST_TOL`, pitch 1e-3 or 0.05 rad, torque limits unrelaxed), and the problem's
    parameters default to that last stage (a plain solve with every constraint is the
    real problem)."""
    seq = cs.examples.tumbler()
    p = seq.segments[T.SEGMENTS.index(name)]
    plan = p.solve_options["schedule"]
    assert {s["level"] for s in plan} <= set(range(p.n_levels))
    last = plan[-1]
    assert last["level"] == p.n_levels - 1
    assert last["params"]["vtol"] <= T.REST_TOL and last["params"]["tau_factor"] == 1.0
    crit = p.success_criteria.spec
    assert all(c["tol"] >= last["params"]["vtol"] for c in crit if c["type"] == "final_v")
    assert last["params"]["ptol"] <= 1e-3
    for k in ("vtol", "tau_factor", "ptol"):
        assert float(p.params[k]) == pytest.approx(last["params"][k])
    target = np.pi if name == "handstand" else 2 * np.pi
    assert last["params"]["pitch"] == pytest.approx(target)
    assert float(p.params["pitch"]) == pytest.approx(target)
    tols = [s["params"]["vtol"] for s in plan if s["level"] == 1]
    assert tols == sorted(tols, reverse=True)


def _guess_rollout(p, q0=None, v0=None):
    """The rollout of ``p``'s initial guess as the solver starts it: the control points
    inside the joint limits (`variable_bounds`); from ``q0, v0`` (default ``p``'s start)."""
    from cstorm.optimize.bounds import variable_bounds

    x = np.clip(np.asarray(p.x0, float), *variable_bounds(p))
    tr = p.compiled("trajectory")(jnp.asarray(x), p.data(q0=q0, v0=v0))
    assert not bool(tr["diverged"])
    return tr


def test_handstand_guess_kicks_into_a_handstand(model):
    """The handstand's default guess (`HANDSTAND_KEYFRAMES`, a kick) rolled out from the
    start position, as the solver starts it: it swings the legs over the hands and ends
    on the hands near a handstand at T (measured at `HANDSTAND_DT`: pitch pi + 0.11, torso
    at the handstand height within 0.5 mm, base speeds <= 0.21; what makes the pitch
    stage a short one). Its hands land hard (2.5 cm into the compliant floor at the landing; the
    solution lands softer, see the slow solve test)."""
    p = T.tumbler_segment("handstand", model=model)
    assert p.t_final == T.HANDSTAND_T and p.spline.n_ctrl == T.HANDSTAND_N_CTRL
    tr = _guess_rollout(p)
    q, v = np.asarray(tr["q"]), np.asarray(tr["v"])
    assert abs(q[-1, 2] - np.pi) < 0.15 and abs(q[-1, 1] - T.handstand_q(model)[1]) < 2e-3
    assert np.max(np.abs(v[-1, :3])) < 0.3
    assert np.all(q[:, 2] > -0.2) and np.all(q[:, 2] < np.pi + 0.3)  # forward, never past the hands
    assert float(np.min(np.asarray(tr["contact"].d))) > -0.03


def test_standing_guess_comes_up_from_nearby_starts(model):
    """Standing's default guess (`STANDING_KEYFRAMES`), rolled out as the solver starts
    it from `ROLL_END` and from starts a chained roll may leave it (pitch rate x0.8 and
    x1.3, base 0.28 m further along x): every rollout ends on its feet within 0.1 rad of
    upright and pitching slower than 0.2 rad/s. This is what makes standing's solve
    independent of the last bits of the roll's end."""
    p = T.tumbler_segment("standing", model=model)
    qe, ve = T.ROLL_END
    for q0, v0 in ((qe, ve), (qe, ve * [1, 1, 0.8, 1, 1]), (qe, ve * [1, 1, 1.3, 1, 1]), (qe + [0.28, 0, 0, 0, 0], ve)):
        tr = _guess_rollout(p, q0, v0)
        q, v = np.asarray(tr["q"]), np.asarray(tr["v"])
        assert abs(q[-1, 2] - 2 * np.pi) < 0.1 and abs(v[-1, 2]) < 0.2, (v0, q[-1], v[-1])
        assert abs(q[-1, 1] - T.standing_q(model)[1]) < 5e-3  # on the feet, not lying


def test_start_guess_stays_on_its_feet(model):
    """The last segment's default guess (arms down, the hip counterbalancing) keeps the
    robot on its feet: the rollout ends near upright and slow (a guess that ends lying
    on the floor gives the terminal pitch no gradient), no contact point deeper than
    1 cm."""
    p, pitch = T.tumbler_segment("start", model=model), 2 * np.pi
    tr = p.compiled("trajectory")(jnp.asarray(p.x0), p.data())
    q, v = np.asarray(tr["q"]), np.asarray(tr["v"])
    assert not bool(tr["diverged"])
    assert np.all(np.abs(q[:, 2] - pitch) < 0.2)
    assert np.max(np.abs(v[-1, :3])) < 0.5
    assert float(np.min(np.asarray(tr["contact"].d))) > -0.01


def _check_segment_solve(name, **kw):
    from cstorm import report

    p = T.tumbler_segment(name, **kw)
    sol = cs.solve(p)
    assert sol.success, sol.message
    crit = report.evaluate_criteria(p.success_criteria, p.model, sol)  # a spec list or the rest criteria
    assert all(c["ok"] for c in crit.values()), crit
    fid = report.fidelity(p, sol)
    assert fid["ok"], fid["flags"]
    return p, sol, crit, fid


def test_start_segment_solves_and_holds_still():
    """`cstorm solve tumbler --segment start` (standing, arms overhead -> arms down, at
    rest) from the default guess: the solve plan converges, every success criterion holds
    (pitch within 0.05 rad of upright, base velocities and accelerations at rest, and the
    `HOLD` test: 1 s with the joints locked, the pitch moves < 0.01 rad), and the motion
    re-simulated at dt/4 and with DOP853 ends where the plan does."""
    p, sol, crit, fid = _check_segment_solve("start")
    assert crit["holds still"]["value"] < T.HOLD["pitch_tol"]
    # the velocities of the plan are the dynamics' (not an artefact of the step; DESIGN:
    # the friction's viscous mode is what limits dt)
    assert fid["velocity_m_s"] < 1e-3 and fid["angular_velocity_deg_s"] < 0.1, fid


@pytest.mark.slow
def test_standing_segment_gets_up_from_the_roll():
    """`cstorm solve tumbler --segment standing` (slow; CI's fast variant of the tumbler
    is the start segment above, and the slow demo test solves the whole chained
    sequence): from the roll's measured end (`ROLL_END`: lying on the back, rolling at 1
    rad/s) up onto the feet at rest (pitch 2 pi within 1e-3, the hold test), from the
    `STANDING_KEYFRAMES` guess."""
    p, sol, crit, fid = _check_segment_solve("standing")
    assert abs(sol.trajectory["q"][-1][1] - T.standing_q(p.model)[1]) < 2e-3  # on its feet, not lying
    assert crit["holds still"]["value"] < T.HOLD["pitch_tol"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["roll", "handstand"])
def test_segment_solve_meets_criteria(name):
    """`cstorm solve tumbler --segment NAME` from the segment's nominal start: the solve
    plan converges from the default guess, every success criterion and the fidelity
    check hold."""
    _check_segment_solve(name)


def test_bridge_guess_keeps_feet_then_hands_on_the_floor(model):
    """The handstand's ``guess="bridge"`` (multiple shooting): its node states pivot about
    the planted feet, then about the planted hands, so the supporting contact points stay
    at the resting sink (the guess is geometrically contact-consistent); it starts at the
    start posture and ends at the nominal handstand; it needs ``shooting > 1``."""
    env, contact = T.env_contact()
    p = T.tumbler_segment("handstand", model=model, shooting=10, guess="bridge", t_final=2.0, n_ctrl=12)
    assert p.shooting == 10 and p.node_guess is not None and len(p.solve_options["schedule"]) == 1 + len(T.REST_RAMP)
    labels = cs.contact_labels(model, env)
    sink = T.start_q(model)[1] - (0.30 + 0.15 + 0.03)
    for t in np.linspace(0.0, 2.0, 11):
        q, v = p.node_guess(t)
        d = np.asarray(cs.contact_forces(model, env, contact, q, v).d)
        support = [i for i, lab in enumerate(labels) if lab[0] in (("foot", "legs") if t <= 0.8 else ("palm", "arms"))]
        assert np.min(d[support]) == pytest.approx(sink, abs=2e-3), (t, d)
        assert np.min(d) > sink - 2e-3  # nothing else below the floor
    np.testing.assert_allclose(p.node_guess(0.0)[0], T.start_q(model), atol=1e-12)
    np.testing.assert_allclose(p.node_guess(2.0)[0], T.handstand_q(model) + [0.2951, 0, 0, 0, 0], atol=1e-3)
    with pytest.raises(ValueError, match="bridge"):
        T.tumbler_segment("handstand", model=model, guess="bridge")


def test_rest_criteria_include_the_hold_test(model):
    """At-rest segments report the `HOLD` test: standing still (arms overhead) holds; the
    same posture tipping at 0.5 rad/s does not."""
    from types import SimpleNamespace

    p = T.tumbler_segment("standing", model=model, q0=T.standing_q(model), v0=np.zeros(5))
    q = T.standing_q(model)
    for w, ok in ((0.0, True), (0.5, False)):
        v = np.array([0.0, 0.0, w, 0.0, 0.0])
        sol = SimpleNamespace(trajectory=dict(q=np.stack([q, q]), v=np.stack([v, v])), constraint_violation=0.0,
                              params={})
        crit = p.success_criteria(sol)
        assert crit["holds still"]["ok"] is ok and crit["upright"]["ok"], crit
        assert crit["root_pitch at rest"]["ok"] is ok
