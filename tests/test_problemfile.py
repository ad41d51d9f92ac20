"""TOML problem files (cstorm.io.problemfile): the shipped example builds the same problem
as the acrobot example (dynamics, initial guess, plan), an environment/contact file
builds per-pair contact parameters, overrides, and bad input: every error names the
file, the table/key and what is wrong. Nothing is compiled (problem construction only
traces); tests/test_cli.py solves the example."""

from __future__ import annotations

import os

import numpy as np
import pytest

import cstorm as cs
from cstorm.io.problemfile import ProblemFileError, apply_overrides, load_problem, load_problem_text

EXAMPLE = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, "examples", "acrobot.toml"))
TEXT = open(EXAMPLE).read()


@pytest.fixture(scope="module")
def example():
    return load_problem(EXAMPLE)


def test_example_file_is_the_acrobot_problem(example):
    from cstorm.examples.acrobot import acrobot_model

    p = example
    assert p.name == "acrobot_swing_up" and p.active == ("elbow",) and p.n_vars == 11 and (p.n_eq, p.n_ineq) == (2, 0)
    assert p.t_final == 3.0 and p.dt == 0.02 and p.spline.n_ctrl == 16 and p.rest_end and p.qa_final.tolist() == [0.0]
    ref = acrobot_model()
    q, v = np.array([0.3, -0.7]), np.array([0.5, 1.1])
    np.testing.assert_allclose(cs.mass_matrix(p.model, q), cs.mass_matrix(ref, q), atol=1e-14)
    np.testing.assert_allclose(cs.rnea(p.model, q, v, v), cs.rnea(ref, q, v, v), atol=1e-13)
    assert p.solve_options["method"] == "slsqp" and p.solve_options["max_iter"] == 300
    assert p.solve_options["continuation"]["target"][-1] == pytest.approx(np.pi)
    assert [c["type"] for c in p.success_criteria] == ["final_q", "final_v", "constraint_violation"]
    # the guess samples 0.3 sin(pi t) sin^2(pi t / 3), like the shipped example's guess
    ex = cs.examples.acrobot(t_final=3.0, n_ctrl=16, dt=0.02)
    assert np.max(np.abs(p.x0 - ex.x0)) < 0.01


def test_environment_contact_pairs_and_costs(tmp_path):
    text = """
name = "tumbler_step"
[robot]
name = "tumbler"
[environment]
pairs = [["*", "ground"], ["legs", "step"]]
[[environment.obstacle]]
type = "ground"
[[environment.obstacle]]
type = "step"
height = 0.05
x = 0.4
[contact]
stiffness = 5000.0
damping = 100.0
d_on = 0.01
d_off = 0.0
friction = 0.5
[[contact.pair]]
geom = "arms"
obstacle = "*"
friction = 0.9
[motion]
active = ["hip", "shoulder"]
t_final = 0.2
dt = 0.01
n_ctrl = 6
q0 = { root_z = 0.476 }
params = { w = 2.0 }
[[cost]]
type = "torque_squared"
weight = "w"
[[cost]]
type = "com_target"
target = [0.1, 0.0, 0.3]
axes = [0, 2]
[[constraint]]
type = "torque_limits"
stage = 1
[[constraint]]
type = "joint_limits"
joints = ["hip"]
velocity = false
[solver]
schedule = [{ params = { w = 1.0 }, level = 0 }, { level = 1 }]
[[criterion]]
type = "displacement"
joint = "root_x"
min = 0.1
"""
    f = tmp_path / "t.toml"
    f.write_text(text)
    p = load_problem(f)
    assert p.env.names == ("ground", "step") and p.env.pairs == (("*", "ground"), ("legs", "step"))
    assert set(p.contact) == {("arms", "*"), ("*", "*")}
    assert float(p.contact[("arms", "*")].friction) == 0.9 and float(p.contact[("arms", "*")].stiffness) == 5000.0
    assert float(p.contact[("*", "*")].friction) == 0.5
    assert p.q0.tolist() == [0.0, 0.476, 0.0, 0.0, 0.0]
    assert [type(c).__name__ for c in p.costs] == ["TorqueSquared", "CoMTarget"] and p.costs[0].weight == "w"
    assert [c.stage for c in p.constraints] == [1, 0] and p.n_levels == 2
    assert p.solve_options["schedule"] == [dict(params={"w": 1.0}, level=0), dict(params={}, level=1)]


def test_overrides():
    p = load_problem_text(TEXT, EXAMPLE, {"motion.dt": 0.05, "cost.0.weight": 2.0, "solver.max_iter": 7,
                                          "motion.initial_guess": {}})
    assert p.dt == 0.05 and p.costs[0].weight == 2.0 and p.solve_options["max_iter"] == 7
    with pytest.raises(ProblemFileError, match="'cost.3' needs an index < 1|needs an index < 1"):
        load_problem_text(TEXT, EXAMPLE, {"cost.3.weight": 1.0})
    p5 = load_problem_text(TEXT, EXAMPLE, {"motion.shooting": 5})
    assert p5.shooting == 5 and p5.n_vars == p.n_vars + 2 * 4 and load_problem_text(TEXT, EXAMPLE).shooting == 1
    with pytest.raises(ProblemFileError, match="shooting=7 must divide the number of steps"):
        load_problem_text(TEXT, EXAMPLE, {"motion.shooting": 7})
    with pytest.raises(ProblemFileError, match=r"'motion.dt' is a value, not a table"):
        apply_overrides({"motion": {"dt": 1.0}}, {"motion.dt.x": 1}, "f.toml")


def _err(text, match):
    with pytest.raises(ProblemFileError) as e:
        load_problem_text(text, EXAMPLE)
    msg = str(e.value)
    assert msg.startswith(EXAMPLE + ": "), msg
    assert match in msg, msg
    return msg


@pytest.mark.parametrize("old, new, match", [
    ("t_final = 3.0", "t_final = -3.0", "[motion] t_final: must be > 0, got -3.0"),
    ("dt = 0.02", "dtt = 0.02", "[motion]: unknown key(s) ['dtt']"),
    ("n_ctrl = 16", "n_ctrl = 16.5", "[motion] n_ctrl: expected an integer, got 16.5"),
    ('joint = "shoulder"\nq = "target"', 'joint = "wrist"\nq = "target"',
     "[[constraint]] #1 (terminal_state) joint: no joint(s) named ['wrist']"),
    ('q = "target"', 'q = "goal"', "[[constraint]] #1 (terminal_state) q: 'goal' is not a number and not a parameter"),
    ('file = "acrobot.urdf"', 'file = "nope.urdf"', "[robot] file: 'nope.urdf' not found"),
    ('type = "torque_squared"', 'type = "torque_cubed"', "[[cost]] #1 type: must be one of"),
    ("continuation = { target", "continuation = { goal", "[solver] continuation.goal: not a parameter"),
    ('method = "slsqp"', 'method = "newton"', "[solver] method: must be one of ['slsqp', 'trust-constr', 'ipopt']"),
    ("[robot]", "[robots]", "top level: unknown key(s) ['robots']"),
    ('type = "final_v"', 'type = "final_w"', "[[criterion]] #2: unknown criterion type 'final_w'"),
    ("active = [\"elbow\"]", "active = [\"shoulder\", \"elbow\"]", "q_final_active: missing values for active joints"),
])
def test_bad_files_name_table_and_key(old, new, match):
    assert old in TEXT
    _err(TEXT.replace(old, new, 1), match)


def test_bad_toml_syntax_and_missing_tables(tmp_path):
    _err("name = \n", "not valid TOML")
    _err('name = "x"\n[motion]\nactive = ["elbow"]\n', "top level: missing table [robot]")
    _err('[robot]\nname = "tumbler"\n[environment]\n[[environment.obstacle]]\ntype = "ground"\n'
         '[motion]\nactive = ["hip"]\nt_final = 1.0\ndt = 0.1\nn_ctrl = 6\n', "[environment] needs a [contact] table")
    with pytest.raises(ProblemFileError, match="cannot read the problem file"):
        load_problem(tmp_path / "absent.toml")


def test_robot_package_dirs_and_strict(tmp_path):
    """[robot] package_dirs (relative to the file) resolves package:// meshes; strict = true
    (or the command line's strict) refuses an implausible inertia the default loads with
    a warning."""
    trimesh = pytest.importorskip("trimesh")
    mesh_dir = tmp_path / "pkgs" / "acro" / "meshes"
    mesh_dir.mkdir(parents=True)
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(str(mesh_dir / "tip.stl"))
    urdf = open(os.path.join(os.path.dirname(EXAMPLE), "acrobot.urdf")).read()
    urdf = urdf.replace('<geometry><capsule radius="0.04" length="1.0"/></geometry>\n    </collision>\n  </link>\n</robot>',
                        '<geometry><capsule radius="0.04" length="1.0"/></geometry>\n    </collision>\n'
                        '    <collision><geometry><mesh filename="package://acro/meshes/tip.stl"/></geometry></collision>'
                        '\n  </link>\n</robot>')
    assert "package://acro" in urdf
    (tmp_path / "robot").mkdir()
    (tmp_path / "robot" / "acrobot.urdf").write_text(urdf)
    text = TEXT.replace('file = "acrobot.urdf"', 'file = "robot/acrobot.urdf"\npackage_dirs = ["pkgs"]')
    (tmp_path / "p.toml").write_text(text)
    p = load_problem(str(tmp_path / "p.toml"))
    assert sum(isinstance(g, cs.ConvexMesh) for g in p.model.geoms) == 1
    (tmp_path / "robot" / "acrobot.urdf").write_text(urdf.replace('izz="8.33333333333333e-8"', 'izz="0.3"', 1))
    with pytest.warns(cs.ModelWarning, match="body 'link1': implausible inertia"):
        load_problem(str(tmp_path / "p.toml"))
    with pytest.raises(ProblemFileError, match=r"p\.toml: \[robot\]: .*acrobot\.urdf: body 'link1': implausible "
                                               r"inertia"):
        load_problem(str(tmp_path / "p.toml"), strict=True)
    (tmp_path / "s.toml").write_text(text.replace('package_dirs = ["pkgs"]', 'package_dirs = "pkgs"\nstrict = true'))
    with pytest.raises(ProblemFileError, match="implausible inertia"):
        load_problem(str(tmp_path / "s.toml"))
    (tmp_path / "b.toml").write_text(text.replace('["pkgs"]', '["nowhere"]'))
    with pytest.raises(ProblemFileError, match=r"\[robot\] package_dirs: .*nowhere' is not a directory"):
        load_problem(str(tmp_path / "b.toml"))
