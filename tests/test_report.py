"""Outputs of solved motions (cstorm.report, cstorm.viz): success criteria, atomic JSON,
x-z drawing geometry, and the files written for a small contact problem (the tumbler on
the ground, a short horizon) and a two-segment sequence of it: CSV columns, PNG plots,
the GIF animation, summary.json.

No solve here: the solutions are the problems' initial guesses (`report.solution_at`),
so the only compile is the contact problem's trajectory function (module fixture). The
fidelity re-simulation of a contact problem compiles two more rollouts and is marked
slow; tests/test_cli.py checks fidelity on the acrobot.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

import cstorm as cs
from cstorm import report
from cstorm.analysis.fidelity import deviation_flags
from cstorm.errors import InputError, ProblemError
from cstorm.optimize.solution import Solution
from cstorm.viz.motion import Motion
from cstorm.viz import planar


def _fake_solution(model, q, v, tau=None, params=None, violation=0.0):
    n = len(q)
    traj = dict(t=np.linspace(0, 1, n), q=np.asarray(q, float), v=np.asarray(v, float),
                a=np.zeros((n, model.nv)), tau=np.zeros((n, model.nv)) if tau is None else np.asarray(tau, float))
    return Solution(success=True, message="ok", cost=1.0, constraint_violation=violation, iterations=3,
                    x=np.zeros(2), trajectory=traj, params=params or {})


# ---------------------------------------------------------------------------------------
# criteria
# ---------------------------------------------------------------------------------------
def test_criteria_specs_evaluate_with_units_and_ops():
    m = cs.robots.tumbler()  # root_x, root_z, root_pitch, hip, shoulder
    q = np.zeros((3, 5))
    q[-1] = [0.35, 0.47, np.pi - 0.01, 0.2, -0.1]
    v = np.zeros((3, 5))
    v[-1, 2] = 0.02
    tau = np.zeros((3, 5))
    tau[1, 3] = -7.0
    sol = _fake_solution(m, q, v, tau, params={"pitch": np.pi}, violation=2e-7)
    spec = [dict(type="final_q", joint="root_pitch", target="pitch", tol=0.05),
            dict(type="final_v", joint="root_pitch", tol=0.01, name="pitch rate"),
            dict(type="displacement", joint="root_x", min=0.3),
            dict(type="periodic", joints=["hip", "shoulder"], tol=0.15),
            dict(type="constraint_violation", tol=1e-6),
            report.Criterion("max_abs", of="tau", joint="hip", max=6.0)]
    res = report.evaluate_criteria(spec, m, sol)
    assert res["final_q[root_pitch]"]["value"] == pytest.approx(0.01) and res["final_q[root_pitch]"]["ok"]
    assert res["pitch rate"] == dict(value=pytest.approx(0.02), tol=0.01, op="<=", ok=False)
    assert res["displacement[root_x]"] == dict(value=pytest.approx(0.35), tol=0.3, op=">=", ok=True)
    assert res["periodic"]["value"] == pytest.approx(0.2) and not res["periodic"]["ok"]
    assert res["constraint_violation"]["ok"]
    assert res["max_abs_tau[hip]"]["value"] == pytest.approx(7.0) and not res["max_abs_tau[hip]"]["ok"]
    json.dumps(res)  # JSON-able


def test_criteria_callable_and_bad_specs():
    m = cs.robots.tumbler()
    sol = _fake_solution(m, np.zeros((2, 5)), np.zeros((2, 5)))
    res = report.evaluate_criteria(lambda s: {"height": dict(value=np.float64(0.4), tol=0.3, ok=np.bool_(True))}, m,
                                   sol)
    assert res == {"height": dict(value=0.4, tol=0.3, ok=True)} and type(res["height"]["ok"]) is bool
    with pytest.raises(ProblemError, match="unknown criterion type 'final_x'"):
        report.evaluate_criteria([dict(type="final_x", joint="hip", tol=1)], m, sol)
    with pytest.raises(ProblemError, match="no joint named 'knee'"):
        report.evaluate_criteria([dict(type="final_q", joint="knee", target=0, tol=1)], m, sol)
    with pytest.raises(ProblemError, match="unknown keys \\['tolerance'\\]"):
        report.evaluate_criteria([dict(type="final_v", joint="hip", tolerance=1)], m, sol)
    with pytest.raises(ProblemError, match="exactly one of 'min' or 'max'"):
        report.evaluate_criteria([dict(type="displacement", joint="root_x")], m, sol)
    with pytest.raises(ProblemError, match="returned list"):
        report.evaluate_criteria(lambda s: [], m, sol)


# ---------------------------------------------------------------------------------------
# files and drawing geometry
# ---------------------------------------------------------------------------------------
def test_write_json_is_strict_and_atomic(tmp_path):
    p = tmp_path / "s.json"
    report.write_json(p, {"a": float("nan"), "b": np.float64(2.5), "c": np.arange(3), "d": [np.inf]})
    assert json.loads(p.read_text()) == {"a": None, "b": 2.5, "c": [0, 1, 2], "d": [None]}
    assert oct(os.stat(p).st_mode & 0o777) != oct(0o600)  # not mkstemp's private mode
    with pytest.raises(TypeError):
        report.write_json(p, {"x": object()})
    assert json.loads(p.read_text())["b"] == 2.5  # a failed write leaves the old file
    assert sorted(os.listdir(tmp_path)) == ["s.json"]  # and no temporary


def test_plane_polygon_ground_and_incline():
    poly, edge = planar.plane_polygon(cs.ground(0.1), (-1, 1), (-1, 1))
    assert np.allclose(sorted(poly[:, 1]), [-1, -1, 0.1, 0.1]) and np.allclose(edge[:, 1], 0.1)
    inc = cs.incline(math.radians(30))  # normal (sin 30, 0, cos 30): z <= -tan(30) x
    poly, edge = planar.plane_polygon(inc, (-1, 1), (-2, 2))
    n = np.array([math.sin(math.radians(30)), math.cos(math.radians(30))])
    assert np.all(poly @ n <= 1e-9) and np.allclose(edge @ n, 0.0)
    assert planar.plane_polygon(cs.ground(5.0), (-1, 1), (-2, -1))[0] is not None  # all solid
    assert planar.plane_polygon(cs.ground(-5.0), (-1, 1), (-2, 2))[0] is None  # below the view


def test_skeleton_of_the_acrobot_and_the_tumbler():
    from cstorm.examples.acrobot import acrobot_model

    m = acrobot_model()
    poses = np.asarray(cs.forward_kinematics(m, np.array([np.pi / 2, 0.0])))
    seg, joints, anchors = planar.skeleton(m, poses)
    # upper arm horizontal along +x? rotation about +y by pi/2 maps -z to -x
    assert np.allclose(anchors, [[0, 0]]) and np.allclose(joints, [[-1, 0]], atol=1e-12)
    assert np.allclose(seg[-1], [[-1, 0], [-2, 0]], atol=1e-12)  # link2 to its tip frame
    t = cs.robots.tumbler()
    seg, joints, anchors = planar.skeleton(t, np.asarray(cs.forward_kinematics(t, cs.robots.tumbler_standing_q())))
    assert len(anchors) == 0 and len(joints) == 2  # hip, shoulder; the planar base is not drawn as bones
    assert np.isclose(seg[:, :, 1].min(), 0.03)  # down to the feet frame (radius above the ground)


# ---------------------------------------------------------------------------------------
# a small contact problem: files
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def contact_problem():
    m = cs.robots.tumbler()
    q0 = cs.robots.tumbler_standing_q(m)
    q0[1] -= 0.004  # resting on the contact spring
    return cs.MotionProblem(m, ["hip", "shoulder"], 0.4, 8, 0.005, q0, env=cs.Environment([cs.ground()]),
                            contact=cs.ContactParams(5e3, 100.0, 0.01, 0.0, friction=0.8),
                            q_final_active={"hip": 1.0, "shoulder": 2.0}, rest_end=True, name="tiny",
                            success_criteria=[dict(type="final_q", joint="hip", target=1.0, tol=1e-9),
                                              dict(type="constraint_violation", tol=1e-6)])


@pytest.fixture(scope="module")
def contact_solution(contact_problem):
    return report.solution_at(contact_problem, evaluate=False)


def test_outputs_of_a_contact_problem(contact_problem, contact_solution, tmp_path, monkeypatch):
    p, s = contact_problem, contact_solution
    src = dict(kind="example", name="none", kwargs={})

    def broken(*a, **k):
        raise RuntimeError("simulated failure")

    monkeypatch.setattr(report, "fidelity", broken)  # a failing check is recorded, not fatal
    summary = report.write_outputs(p, s, tmp_path, source=src)
    assert summary["fidelity"] == dict(ok=False, flags=["fidelity check failed: RuntimeError: simulated failure"])
    assert summary["warnings"] == ["fidelity check failed: RuntimeError: simulated failure"]
    files = sorted(os.listdir(tmp_path))
    assert files == ["animation.gif", "contacts.png", "joints.png", "paths.png", "solution.npz", "summary.json",
                     "torques.png", "trajectory.csv"] == summary["files"]
    for f in files:
        assert os.path.getsize(tmp_path / f) > 2000, f
    # summary.json: strict JSON with the documented fields
    js = json.loads((tmp_path / "summary.json").read_text())
    for k in ("problem", "success", "solver_success", "message", "cost", "constraint_violation", "iterations",
              "wall_time_s", "compile_time_s", "fidelity", "segments", "provenance", "criteria"):
        assert k in js, k
    assert js["success"] is False and js["cost"] is None  # not solved; NaN cost -> null
    assert js["criteria"]["final_q[hip]"]["ok"] is True  # by construction of the spline
    assert js["criteria"]["constraint_violation"]["ok"] is False  # NaN violation fails
    assert len(js["segments"]) == 1 and js["segments"][0]["problem"] == "tiny"
    pv = js["provenance"]
    assert pv["cstorm_version"] == cs.__version__ and pv["problem_hash"] == p.hash() and pv["source"] == src
    # the solution keeps its source for `cstorm animate`, and its contact data
    loaded = cs.load_solution(tmp_path / "solution.npz")
    assert loaded.info["source"] == src
    mo = Motion.from_solution(p, loaded)
    assert mo.contact_names[0] == "torso_ground_0" and mo.contact["force"].shape == (p.n_steps + 1, 6, 3)
    # CSV: a header naming every column; contact normal forces per point
    header = (tmp_path / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["t", "segment", "q_root_x"] and "tau_hip" in header
    assert [h for h in header if h.startswith("N_")] == ["N_torso_ground_0", "N_torso_ground_1", "N_legs_ground_0",
                                                         "N_legs_ground_1", "N_arms_ground_0", "N_arms_ground_1"]
    data = np.loadtxt(tmp_path / "trajectory.csv", delimiter=",", skiprows=1)
    assert data.shape == (p.n_steps + 1, len(header))
    assert data[0, header.index("N_legs_ground_0")] > 10.0  # standing on the feet
    # GIF: ~25 frames per second of motion, 640x400, frames differ
    from PIL import Image

    with Image.open(tmp_path / "animation.gif") as im:
        assert im.size == (640, 400) and im.n_frames == 11
        im.seek(0)
        a = np.asarray(im.convert("RGB")).copy()
        im.seek(im.n_frames - 1)
        b = np.asarray(im.convert("RGB"))
        assert np.mean(np.any(a != b, axis=2)) > 0.002
        assert a.std() > 10  # not blank


def test_sequence_motion_is_continuous_and_labelled(contact_problem, contact_solution, tmp_path):
    p, s = contact_problem, contact_solution
    seq = cs.MotionSequence([p, p], name="twice")
    sol = Solution(**{**s.__dict__, "segments": [s.segments[0], s.segments[0]], "problem": "twice"})
    mo = Motion.from_solution(seq, sol)
    N = p.n_steps
    assert mo.t.shape == (2 * N + 1,) and mo.t[-1] == pytest.approx(0.8) and np.all(np.diff(mo.t) > 0)
    assert mo.segment_names == ("tiny", "tiny") and mo.segment_starts == (0.0, pytest.approx(0.4))
    assert list(np.bincount(mo.segment_index)) == [N + 1, N]
    assert mo.contact["d"].shape == (2 * N + 1, 6) and len(mo.contact_names) == 6
    files = report.render(mo, tmp_path, plots=False)
    assert files == ["animation.gif"]
    from PIL import Image

    with Image.open(tmp_path / "animation.gif") as im:
        assert im.n_frames == 21  # one continuous motion of 0.8 s at 25 fps
    # summary of a sequence: one entry per segment, criteria prefixed by segment
    summ = report.make_summary(seq, sol)
    assert len(summ["segments"]) == 2 and "tiny/final_q[hip]" in summ["criteria"]


def test_select_segment_and_sources(contact_problem):
    seq = cs.MotionSequence([contact_problem], name="one")
    assert report.select_segment(seq, "tiny") is contact_problem
    assert report.select_segment(seq, "0") is contact_problem
    with pytest.raises(InputError, match="no segment 'roll'"):
        report.select_segment(seq, "roll")
    with pytest.raises(InputError, match="not a sequence"):
        report.select_segment(contact_problem, "x")
    with pytest.raises(InputError, match="no usable source"):
        report.problem_from_source(None)
    with pytest.raises(InputError, match="unknown example problem 'nope'"):
        report.problem_from_source(dict(kind="example", name="nope"))


@pytest.mark.slow
def test_fidelity_of_a_contact_motion(contact_problem, contact_solution):
    # the initial guess of the tiny problem (standing on point contacts, folding, planned
    # at dt = 5 ms); measured: RK4 at dt/4 and DOP853 end 0.14 mm and 0.29 deg from the
    # plan, but 10.9 deg/s off in the pitch rate: 5 ms is past RK4's stability limit for
    # the friction's viscous mode there, which the velocity flag and `check_time_step`
    # both report
    f = report.fidelity(contact_problem, contact_solution)
    assert not f["ok"] and f["flags"] and all("angular velocity off by" in g for g in f["flags"]), f["flags"]
    assert f["angular_velocity_deg_s"] > 1.0
    assert [c["name"] for c in f["checks"]] == ["fine", "dop853"]
    assert f["position_m"] < 2e-3 and f["angle_deg"] < 1.0
    ts = cs.check_time_step(contact_problem, along=contact_solution)
    assert not ts["ok"] and ts["dt_limit"] < contact_problem.dt, ts["message"]
    fine, ref = f["checks"]
    assert abs(fine["angle_deg"] - ref["angle_deg"]) < 0.2 * ref["angle_deg"]  # both see the plan's own error
    assert f["checks"][1]["rhs_evaluations"] > 100


def test_gif_and_mp4_writers(tmp_path):
    from PIL import Image
    from cstorm.viz import animation

    frames = [np.full((40, 64, 3), 255, np.uint8) for _ in range(5)]
    for k, f in enumerate(frames):
        f[10:20, 5 + 10 * k:15 + 10 * k] = (220, 20, 60)  # a moving crimson square
    assert animation.write_gif(frames, tmp_path / "a.gif", fps=25.0) == "a.gif"
    with Image.open(tmp_path / "a.gif") as im:
        assert im.n_frames == 5 and im.info["duration"] == 40 and im.info["loop"] == 0
        im.seek(4)
        px = np.asarray(im.convert("RGB"))
        assert np.abs(px[15, 50].astype(int) - (220, 20, 60)).max() < 40 and px[15, 5].min() > 200
    # no ffmpeg (or a failing one): no MP4, no temporary left behind
    assert animation.write_mp4(frames, tmp_path / "a.mp4", 25.0, ffmpeg=str(tmp_path / "no-ffmpeg")) is None
    assert sorted(os.listdir(tmp_path)) == ["a.gif"]
    assert list(animation.frame_indices(np.linspace(0, 1, 1001), fps=25)) == list(range(0, 1001, 40))


@pytest.mark.slow
def test_fidelity_of_a_free_floating_body():
    """A free-floating, tumbling body with a swinging arm (no contact): the DOP853
    reference (quaternion kinematics in the right-hand side) and RK4 at dt/4 (Lie-group
    RK4) reproduce the plan; checks the free-joint paths of the fidelity check."""
    b = cs.ModelBuilder("spinner")
    b.add_link("base", mass=2.0, inertia=(0.05, 0.08, 0.11))
    b.add_link("arm", mass=0.5, com=(0.0, 0.0, 0.2), inertia=(0.01, 0.01, 0.001))
    b.add_joint("arm", "revolute", "base", "arm", xyz=(0.1, 0.0, 0.0), axis=(0.0, 0.6, 0.8))
    m = b.build(floating_base="free")
    q0 = np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    v0 = np.array([1.0, 2.0, 3.0, 0.5, 0.0, 4.0, 0.0])  # spinning, thrown up
    p = cs.MotionProblem(m, ["arm"], 0.5, 6, 0.01, q0, v0, q_final_active={"arm": 1.0}, name="spinner")
    s = report.solution_at(p, evaluate=False)
    f = report.fidelity(p, s)
    assert f["ok"], f["flags"]
    fine, ref = f["checks"]
    # measured: both 8e-8 m, 8e-6 deg, 2.5e-7 m/s from the plan (planned at dt = 10 ms)
    for c in (fine, ref):
        assert c["position_m"] < 1e-6 and c["angle_deg"] < 1e-4 and c["velocity_m_s"] < 1e-5
    zT = s.trajectory["q"][-1][2]
    assert zT == pytest.approx(1.0 + 4.0 * 0.5 - 0.5 * 9.81 * 0.25, abs=0.05)  # free flight of the CoM, roughly


def test_fidelity_flags_velocities_too():
    """A final passive velocity off by more than 1 cm/s or 1 deg/s is flagged like a
    position off by more than 1 cm (a landing "at rest" that only the planning step
    produced; see `cstorm.check_time_step`); each bound on its own."""
    ok = dict(position_m=1e-3, angle_deg=0.1, velocity_m_s=5e-3, angular_velocity_deg_s=0.5)
    assert deviation_flags(ok, 0.01, 2.0) == []
    for key, val, word in (("velocity_m_s", 0.024, "velocity off by 0.024 m/s"),
                           ("angular_velocity_deg_s", 14.0, "angular velocity off by 14 deg/s")):
        flags = deviation_flags({**ok, key: val}, 0.01, 2.0)
        assert len(flags) == 1 and word in flags[0], flags
    assert deviation_flags({**ok, "velocity_m_s": None}, 0.01, 2.0) == []  # a robot without such DoFs


def test_torque_check_reads_every_step():
    """`report.torque_check`: the active joints' torques against the effort limits on every
    step of the trajectory (an impact spike between the samples of a sampled torque
    constraint is what it is for); the tumbler's hip limit is 12 N m, the shoulder's 8."""
    import importlib

    prob = importlib.import_module("cstorm.examples.tumbler").tumbler_segment("start")  # built, not compiled
    m = prob.model
    tau = np.zeros((101, 5))
    tau[:, 3] = 5.0
    tau[37, 4] = -12.0  # one step at 1.5x the shoulder's limit
    tau[:, 0] = 100.0  # a passive DoF: not a motor, not checked
    sol = _fake_solution(m, np.zeros((101, 5)), np.zeros((101, 5)), tau)
    r = report.torque_check(prob, sol)
    assert r["ok"] is False and r["joint"] == "shoulder" and r["worst_ratio"] == pytest.approx(1.5)
    assert r["t"] == pytest.approx(0.37) and "1.50x" in r["message"]
    seg = r["segments"][0]
    assert seg["max_abs_tau"] == {"hip": 5.0, "shoulder": 12.0} and seg["ratio"]["hip"] == pytest.approx(5 / 12)
    tau[37, 4] = -8.0
    assert report.torque_check(prob, _fake_solution(m, np.zeros((101, 5)), np.zeros((101, 5)), tau))["ok"] is True
    json.dumps(r)
