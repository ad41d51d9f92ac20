"""The command line: info, demo, solve, animate, exit codes and --json."""

import json
import os

import pytest

from cstorm.cli import main
from helpers import one_json, run_cli

EXAMPLE = os.path.join(os.path.dirname(__file__), os.pardir, "examples", "acrobot.toml")

def test_info_json(capsys):
    assert main(["info", "tumbler", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["nv"] == 5 and out["total_mass"] == pytest.approx(3.0)
    assert [b["joint"] for b in out["bodies"]] == ["root_x", "root_z", "root_pitch", "hip", "shoulder"]


def test_info_text_lists_shapes(capsys):
    assert main(["info", "tumbler"]) == 0
    text = capsys.readouterr().out
    assert "capsule r=0.04 length=0.3" in text and "joint 'hip': revolute" in text


def test_bad_model_exits_2(capsys):
    assert main(["info", "no_such_robot.urdf", "--json"]) == 2
    out = json.loads(capsys.readouterr().out)
    assert out["success"] is False and "no_such_robot.urdf" in out["message"]


def test_info_of_a_shipped_problem_and_a_problem_file(capsys):
    """`cstorm info acrobot` names the robot of the shipped problem, as `cstorm solve
    acrobot` solves it; a TOML problem file names its robot too."""
    assert main(["info", "acrobot", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [b["joint"] for b in out["bodies"]] == ["shoulder", "elbow"]
    assert main(["info", EXAMPLE]) == 0
    assert "joint 'elbow': revolute" in capsys.readouterr().out
    assert main(["info", "no_such_thing", "--json"]) == 2
    msg = json.loads(capsys.readouterr().out)["message"]
    assert "shipped robot" in msg and "shipped problem" in msg and "acrobot" in msg


_LINK = ('<link name="{n}"><inertial><mass value="1"/><inertia ixx="{i}" iyy="{i}" izz="{z}" ixy="0" ixz="0" '
         'iyz="0"/></inertial>{extra}</link>')


def _urdf(l1_extra="", izz=0.01):
    return ('<?xml version="1.0"?>\n<robot name="r">' + _LINK.format(n="base", i=0.01, z=0.01, extra="")
            + _LINK.format(n="l1", i=0.001, z=izz, extra=l1_extra)
            + '<joint name="j1" type="continuous"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/></joint>'
            '</robot>')


def test_info_strict_and_warnings(tmp_path):
    """An implausible inertia: loaded, one warning on stderr (exit 0); --strict: exit 2 with
    one JSON object naming file and body, no traceback. A cycle: exit 2 naming the joints."""
    p = tmp_path / "r.urdf"
    p.write_text(_urdf(izz=0.01))
    rc, stdout, stderr = run_cli(["info", str(p), "--json"])
    assert rc == 0 and one_json(stdout)["nv"] == 1
    assert "cstorm info: warning:" in stderr and "body 'l1': implausible inertia" in stderr
    rc, stdout, stderr = run_cli(["info", str(p), "--strict", "--json"])
    r = one_json(stdout)
    assert rc == 2 and r["error"] == "ModelError" and f"{p}: body 'l1': implausible inertia" in r["message"]
    assert "Traceback" not in stderr
    p.write_text(_urdf().replace('<child link="l1"/>', '<child link="base"/>'))
    rc, stdout, stderr = run_cli(["info", str(p), "--json"])
    assert rc == 2 and "'base'" in one_json(stdout)["message"]
    assert "Traceback" not in stderr


def test_info_package_dirs(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    for pkg, ext in (("pa", (0.2, 0.2, 0.2)), ("pb", (0.4, 0.4, 0.4))):
        d = tmp_path / "roots" / pkg / "meshes"
        d.mkdir(parents=True)
        trimesh.creation.box(extents=ext).export(str(d / "m.stl"))
    col = ('<collision><geometry><mesh filename="package://pa/meshes/m.stl"/></geometry></collision>'
           '<collision><geometry><mesh filename="package://pb/meshes/m.stl"/></geometry></collision>')
    p = tmp_path / "robot" / "r.urdf"
    p.parent.mkdir()
    p.write_text(_urdf(l1_extra=col, izz=0.0015))
    rc, stdout, stderr = run_cli(["info", str(p), "--json"])
    assert rc == 0 and one_json(stdout)["geoms"] == [] and "package://pa/meshes/m.stl (link 'l1': not found)" in stderr
    rc, stdout, stderr = run_cli(["info", str(p), "--json", "--package-dir", str(tmp_path / "roots" / "pa"),
                               "--package-dir", str(tmp_path / "roots")])
    assert rc == 0 and len(one_json(stdout)["geoms"]) == 2 and "warning" not in stderr
    rc, stdout, _ = run_cli(["info", str(p), "--json", "--package-dir", str(tmp_path / "nowhere")])
    assert rc == 2 and "--package-dir" in one_json(stdout)["message"]


# ---------------------------------------------------------------------------------------
# cstorm solve / animate on the shipped TOML example (one solve, shared by the tests;
# later calls of `main` for the same problem reuse its compiled functions)
# ---------------------------------------------------------------------------------------

import numpy as np

import cstorm as cs
from cstorm.cli import commands as cli

EXAMPLE = os.path.join(os.path.dirname(__file__), os.pardir, "examples", "acrobot.toml")
# fast settings: swing up to 3/4 pi instead of pi (two continuation stages, ~50 iterations)
HALF = ["--set", "motion.params.target=2.356194490192345",
        "--set", "solver.continuation.target=[1.5707963267948966, 2.356194490192345]"]


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    out = tmp_path_factory.mktemp("acrobot_toml")
    rc, stdout, stderr = run_cli(["solve", EXAMPLE, "--out", str(out), "--json", *HALF])
    return rc, stdout, out


def test_solve_toml_json_exit_0(solved):
    rc, stdout, out = solved
    s = one_json(stdout)
    assert rc == 0 and s["success"] is True and s["solver_success"] is True, s["message"]
    assert s["problem"] == "acrobot_swing_up" and s["out"] == os.path.abspath(out)
    assert set(s["criteria"]) == {"final_q[shoulder]", "final_v[shoulder]", "constraint_violation"}
    assert all(c["ok"] for c in s["criteria"].values())
    # fidelity: RK4 at dt/4 and DOP853 reproduce the final shoulder angle (measured 2e-4 deg)
    f = s["fidelity"]
    assert f["ok"] and f["flags"] == [] and f["angle_deg"] < 0.05 and f["position_m"] is None
    assert [c["name"] for c in f["checks"]] == ["fine", "dop853"] and f["checks"][0]["dt"] == pytest.approx(0.005)


def test_summary_and_files(solved):
    rc, stdout, out = solved
    files = sorted(os.listdir(out))
    assert files == [".cstorm-manifest.json", "animation.gif", "joints.png", "paths.png", "solution.npz",
                     "summary.json", "torques.png", "trajectory.csv"]  # no checkpoint left after a finished run
    assert json.loads((out / ".cstorm-manifest.json").read_text())["files"] == files[1:]
    files = files[1:]
    for f in files:
        assert os.path.getsize(out / f) > 5000, f
    s = json.loads((out / "summary.json").read_text())
    for k in ("problem", "success", "message", "cost", "constraint_violation", "iterations", "wall_time_s",
              "compile_time_s", "fidelity", "segments", "provenance", "criteria"):
        assert k in s, k
    assert s["cost"] > 0 and s["iterations"] > 10 and s["constraint_violation"] < 1e-6
    seg = s["segments"]
    assert len(seg) == 1 and {k: seg[0][k] for k in ("cost", "iterations")} == {k: s[k] for k in ("cost",
                                                                                                  "iterations")}
    pv = s["provenance"]
    assert pv["cstorm_version"] == cs.__version__ and len(pv["problem_hash"]) == 16
    assert pv["solver_options"]["method"] == "slsqp" and pv["solver_options"]["max_iter"] == 300
    assert pv["source"]["kind"] == "toml"
    assert pv["source"]["overrides"]["motion.params.target"] == pytest.approx(2.356, abs=1e-3)
    sol = cs.load_solution(out / "solution.npz")
    assert sol.success and abs(sol.trajectory["q"][-1][0] - 3 * np.pi / 4) < 1e-3
    assert sol.info["source"] == pv["source"]
    header = (out / "trajectory.csv").read_text().splitlines()[0]
    assert header == "t,segment,q_shoulder,q_elbow,v_shoulder,v_elbow,tau_shoulder,tau_elbow"


def test_animate_rerenders_from_dir_and_npz(solved, tmp_path):
    rc, stdout, out = solved
    rc, stdout, _ = run_cli(["animate", str(out), "--out", str(tmp_path / "a"), "--json"])
    r = one_json(stdout)
    assert rc == 0 and r["files"] == ["animation.gif", "joints.png", "paths.png", "torques.png"]
    for f in r["files"]:
        assert os.path.getsize(tmp_path / "a" / f) > 5000
    rc, stdout, _ = run_cli(["animate", str(out / "solution.npz"), "--out", str(tmp_path / "b"), "--no-animation",
                          "--csv", "--json"])
    assert rc == 0 and one_json(stdout)["files"] == ["joints.png", "paths.png", "torques.png", "trajectory.csv"]
    assert (tmp_path / "b" / "trajectory.csv").read_text() == (out / "trajectory.csv").read_text()
    # a solution that does not record its source cannot be re-rendered: exit 2, clear message
    sol = cs.load_solution(out / "solution.npz")
    sol.info = {}
    sol.save(tmp_path / "bare.npz")
    rc, stdout, _ = run_cli(["animate", str(tmp_path / "bare.npz"), "--json"])
    assert rc == 2 and "rebuild" in one_json(stdout)["message"]


def test_failed_solve_exits_1(solved, tmp_path):
    rc, stdout, _ = run_cli(["solve", EXAMPLE, *HALF, "--max-iter", "1", "--no-fidelity", "--no-animation",
                          "--out", str(tmp_path), "--json"])
    s = one_json(stdout)
    assert rc == 1 and s["success"] is False and s["iterations"] == 2  # one per continuation stage
    assert s["fidelity"] is None and not s["criteria"]["final_q[shoulder]"]["ok"]
    assert (tmp_path / "summary.json").exists() and not (tmp_path / "animation.gif").exists()


@pytest.mark.parametrize("argv, words", [
    (["solve", "no_such_problem"], ["unknown problem", "acrobot"]),
    (["solve", "missing.toml"], ["missing.toml", "not found"]),
    (["solve", "acrobot", "--max-iter", "many"], ["--max-iter", "invalid int"]),
    (["solve", "acrobot", "--set", "t_final"], ["--set", "KEY=VALUE"]),
    (["animate", "nowhere"], ["no solution"]),
])
def test_bad_input_exits_2_with_one_json_object(argv, words):
    rc, stdout, stderr = run_cli(argv + ["--json"])
    r = one_json(stdout)
    assert rc == 2 and r["success"] is False
    for w in words:
        assert w in r["message"], r["message"]
    assert "error" in stderr


def test_bad_problem_file_names_file_table_and_key(tmp_path):
    text = open(EXAMPLE).read().replace("t_final = 3.0", "t_final = -3.0").replace(
        'file = "acrobot.urdf"', f'file = "{os.path.abspath(os.path.join(os.path.dirname(EXAMPLE), "acrobot.urdf"))}"')
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    rc, stdout, _ = run_cli(["solve", str(bad), "--json"])
    assert rc == 2 and one_json(stdout)["message"] == f"{bad}: [motion] t_final: must be > 0, got -3.0"


def test_sequence_outputs_and_segment(solved, tmp_path, monkeypatch):
    """A two-segment sequence of the (compiled) acrobot problem, registered as an example:
    one continuous output, per-segment summary and fidelity; --segment solves one."""
    from cstorm import examples

    p, _ = cli.resolve_problem(EXAMPLE, cli._parse_set(HALF[1::2]))
    monkeypatch.setitem(examples.registry(), "twoseg", lambda: cs.MotionSequence([p, p], name="twoseg"))
    rc, stdout, _ = run_cli(["solve", "twoseg", "--max-iter", "1", "--out", str(tmp_path / "seq"), "--json"])
    s = one_json(stdout)
    assert rc == 1 and s["problem"] == "twoseg" and len(s["segments"]) == 2
    assert [g["iterations"] for g in s["segments"]] == [2, 2] and s["iterations"] == 4
    assert len(s["fidelity"]["segments"]) == 2 and all(len(g["checks"]) == 2 for g in s["fidelity"]["segments"])
    assert s["segments"][1]["fidelity"]["segment"] == "acrobot_swing_up"
    data = np.loadtxt(tmp_path / "seq" / "trajectory.csv", delimiter=",", skiprows=1)
    assert data.shape[0] == 2 * p.n_steps + 1 and data[-1, 0] == pytest.approx(6.0)
    assert list(np.unique(data[:, 1])) == [0.0, 1.0]
    rc, stdout, _ = run_cli(["animate", str(tmp_path / "seq"), "--no-animation", "--json"])
    assert rc == 0
    # one segment, from its own nominal start (q0, v0 of the segment)
    rc, stdout, _ = run_cli(["solve", "twoseg", "--segment", "1", "--max-iter", "1", "--no-fidelity", "--no-animation",
                          "--out", str(tmp_path / "one"), "--json"])
    s = one_json(stdout)
    assert rc == 1 and len(s["segments"]) == 1 and s["provenance"]["source"]["segment"] == "1"
    sol = cs.load_solution(tmp_path / "one" / "solution.npz")
    np.testing.assert_allclose(sol.trajectory["q"][0], p.q0)
    rc, stdout, _ = run_cli(["solve", "twoseg", "--segment", "roll", "--json"])
    assert rc == 2 and "no segment 'roll'" in one_json(stdout)["message"]


def test_demo_path_with_a_stand_in_problem(solved, tmp_path, monkeypatch):
    """`cstorm demo` writes the demo robot's description and then runs `cstorm solve` on
    the demo problem (the tumbler sequence). CI runs that path with --guess on this
    module's compiled acrobot as a stand-in (the tumbler's four segments alone would
    compile for minutes on a 2-core machine); test_demo_solves_the_tumbler_sequence (slow)
    runs the real demo."""
    from cstorm import examples
    from cstorm.viz import demo as viz_demo

    assert viz_demo.DEMO_PROBLEM == "tumbler" and "tumbler" in cs.examples.names()
    p, _ = cli.resolve_problem(EXAMPLE, cli._parse_set(HALF[1::2]))
    monkeypatch.setitem(examples.registry(), "standin", lambda: p)
    monkeypatch.setattr(viz_demo, "DEMO_PROBLEM", "standin")
    rc, stdout, stderr = run_cli(["demo", "--out", str(tmp_path), "--guess", "--json"])
    s = one_json(stdout)
    assert rc == 1 and s["success"] is False  # --guess: not solved, exit 1 as for `cstorm solve --guess`
    assert s["provenance"]["source"] == {"kind": "example", "name": "standin", "kwargs": {}}
    assert s["provenance"]["command"][:2] == ["cstorm", "demo"]
    assert "joint 'elbow': revolute" in (tmp_path / "acrobot_info.txt").read_text()
    for f in ("summary.json", "solution.npz", "trajectory.csv", "joints.png", "paths.png", "animation.gif"):
        assert f in s["files"] and os.path.getsize(tmp_path / f) > 1000, f


@pytest.mark.slow
def test_demo_solves_the_tumbler_sequence(tmp_path):
    """The real main demo (what `bash scripts/demo.sh` runs): the tumbler's four segments
    solved chained, every segment's success criteria met (~11 min on a 2-core machine)."""
    rc, stdout, _ = run_cli(["demo", "--out", str(tmp_path), "--json"])
    s = one_json(stdout)
    assert rc == 0 and s["success"] and s["problem"] == "tumbler", s["message"]
    assert [g["problem"] for g in s["segments"]] == ["handstand", "roll", "standing", "start"]
    assert all(c["ok"] for c in s["criteria"].values()) and s["fidelity"]["ok"]
    assert "joint 'shoulder': revolute" in (tmp_path / "tumbler_info.txt").read_text()
    for f in ("summary.json", "solution.npz", "trajectory.csv", "contacts.png", "paths.png", "animation.gif"):
        assert os.path.getsize(tmp_path / f) > 1000, f
