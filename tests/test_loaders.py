"""URDF / MJCF loaders: parsing, conventions, hardening and error messages."""

from __future__ import annotations

import os
import time
import warnings

import numpy as np
import pytest
import jax.numpy as jnp

import cstorm as cs
from cstorm.model.builder import rpy_to_matrix
from cstorm.model.info import describe
from cstorm.model.urdf import load_urdf

INERTIAL = '<inertial><mass value="{m}"/><inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>'


def link(name, m=1.0, i=0.01, extra=""):
    return f'<link name="{name}">{INERTIAL.format(m=m, i=i) if m is not None else ""}{extra}</link>'


def joint(name, parent, child, type="revolute", extra='<axis xyz="0 0 1"/>'):
    return f'<joint name="{name}" type="{type}"><parent link="{parent}"/><child link="{child}"/>{extra}</joint>'


def urdf(*parts, name="r"):
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n' + "\n".join(parts) + "\n</robot>\n"


@pytest.fixture
def write(tmp_path):
    def w(text, name="robot.urdf"):
        p = tmp_path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
        return str(p)

    return w


def two_link(**kw):
    return urdf(link("base"), link("l1"), joint("j1", "base", "l1", **kw))


# ----------------------------------------------------------------------------- hardening
def test_entity_bomb_is_rejected_not_expanded(write):
    lol = ['<!ENTITY lol0 "lol">'] + [f'<!ENTITY lol{k} "{("&lol" + str(k - 1) + ";") * 10}">' for k in range(1, 10)]
    text = ('<?xml version="1.0"?>\n<!DOCTYPE robot [\n' + "\n".join(lol) + "\n]>\n"
            '<robot name="&lol9;">' + link("base") + "</robot>")
    p = write(text)
    t = time.time()
    with pytest.raises(cs.ModelError, match=r"robot\.urdf:2: DOCTYPE declarations are not allowed"):
        load_urdf(p)
    assert time.time() - t < 1.0  # refused before any expansion (10^9 "lol"s otherwise)


def test_external_entity_is_rejected(write):
    text = ('<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY x SYSTEM "file:///etc/passwd">]>\n'
            '<robot name="r"><link name="&x;"/></robot>')
    with pytest.raises(cs.ModelError, match="DOCTYPE declarations are not allowed") as e:
        load_urdf(write(text))
    assert "root:" not in str(e.value)


def test_undeclared_entity_is_an_error(write):
    with pytest.raises(cs.ModelError, match=r"robot\.urdf:2: malformed XML: undefined entity"):
        load_urdf(write('<?xml version="1.0"?>\n<robot name="&x;"/>'))


def test_malformed_xml_names_line(write):
    text = two_link().replace("</link>", "</lnk>", 2)
    with pytest.raises(cs.ModelError, match=r"robot\.urdf:3: malformed XML: mismatched tag \(line 3, column"):
        load_urdf(write(text))


# ----------------------------------------------------------------------------- errors name things
@pytest.mark.parametrize(
    "text, pattern",
    [
        (urdf(link("base"), link("l1", m=-1.0), joint("j1", "base", "l1")), r"link 'l1': mass must be finite and >= 0"),
        (urdf(link("base"), '<link name="l1"><inertial><mass value="1"/><inertia ixx="0.01" iyy="-0.01" izz="0.01" '
              'ixy="0" ixz="0" iyz="0"/></inertial></link>', joint("j1", "base", "l1")),
         r"body 'l1': inertia is not positive semi-definite"),
        (two_link(type="screw"), r"robot\.urdf:5: <joint> of joint 'j1': unknown joint type 'screw'"),
        (two_link(type="planar"), r"<joint> of joint 'j1': joint type 'planar' is not supported"),
        (urdf(link("base"), link("l1"), joint("j1", "bse", "l1")), r"<parent> of joint 'j1': parent link 'bse' does not exist"),
        (urdf(link("base"), link("l1"), joint("j1", "base", "l2")), r"<child> of joint 'j1': child link 'l2' does not exist"),
        (urdf(link("a"), link("b"), joint("j1", "a", "b"), joint("j2", "b", "a")), r"no root link: the joints form a cycle"),
        (urdf(link("a"), link("b"), link("c"), joint("j1", "a", "b")), r"several root links \['a', 'c'\]"),
        (urdf(link("a"), link("b"), link("c"), joint("j1", "a", "b"), joint("j2", "c", "b")),
         r"link 'b' already has parent joint 'j1'"),
        (urdf(link("base"), link("l1", m=None), joint("j1", "base", "l1")),
         r"joint 'j1' moves a subtree with no mass or no inertia about its axis \(body 'l1'\)"),
        (urdf(link("base"), link("l1"), '<joint name="j1"><parent link="base"/><child link="l1"/></joint>'),
         r"robot\.urdf:5: <joint> of joint 'j1': missing required attribute 'type'"),
        (urdf(link("base"), link("l1"), joint("j1", "base", "l1", extra='<axis xyz="0 0"/>')),
         r"<axis> of joint 'j1': attribute xyz='0 0' must have 3 numbers"),
        (urdf(link("base"), link("l1"), joint("j1", "base", "l1", extra='<limit lower="1" upper="0" effort="1" velocity="1"/>')),
         r"<limit> of joint 'j1': lower limit 1.0 exceeds upper limit 0.0"),
        (urdf(link("base"), '<link name="l1"><inertial><mass value="1"/></inertial></link>', joint("j1", "base", "l1")),
         r"<inertial> of link 'l1': has no <inertia>"),
        (urdf(link("base"), link("l1", extra='<collision><geometry><box size="1 1"/></geometry></collision>'),
              joint("j1", "base", "l1")), r"<box> \(collision 'l1_collision0' of link 'l1'\): attribute size='1 1'"),
        (urdf(link("base"), link("base")), r"link 'base' is defined twice"),
        ('<?xml version="1.0"?><robt name="x"/>', r"the root element of a URDF must be <robot>"),
        (urdf(link("base"), link("l1"), joint("j1", "base", "l1", extra='<axis xyz="0 0 0"/>')),
         r"<axis> of joint 'j1': axis must be non-zero"),
        (urdf(link("base"), link("l1", i="nan"), joint("j1", "base", "l1")),
         r"<inertia> of link 'l1': attribute ixx='nan' must be finite"),
        (urdf(link("base"), link("l1", m=0.0, i=0.0), joint("j1", "base", "l1")),
         r"joint 'j1' moves a subtree with no mass or no inertia about its axis"),
    ],
    ids=["negative_mass", "indefinite", "unknown_type", "planar", "dangling_parent", "dangling_child",
         "cycle", "two_roots", "two_parents", "massless_subtree", "missing_type", "bad_axis", "bad_limits",
         "no_inertia", "bad_box", "duplicate_link", "not_robot", "zero_axis", "nan_inertia", "zero_mass"],
)
def test_urdf_errors_name_file_and_element(write, text, pattern):
    p = write(text)
    with pytest.raises(cs.ModelError, match=pattern) as e:
        load_urdf(p)
    assert p in str(e.value)


def test_missing_file():
    with pytest.raises(cs.ModelError, match="nope.urdf: cannot read URDF file"):
        load_urdf("/nonexistent/nope.urdf")


def _inertial_link(name, m, ixx, iyy, izz, ixy=0.0, ixz=0.0, iyz=0.0):
    return (f'<link name="{name}"><inertial><mass value="{m}"/><inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" '
            f'ixy="{ixy}" ixz="{ixz}" iyz="{iyz}"/></inertial></link>')


def _fixed(name, parent, child, xyz="0 0 0"):
    return joint(name, parent, child, type="fixed", extra=f'<origin xyz="{xyz}"/>')


def test_triangle_inequality_warns_by_default_and_strict_refuses(write):
    """Implausible but computable (PR2's sensor mount: [0.001, 0.001, 0.01]): one warning
    per body naming it and the margin; inertia_check='strict' refuses it."""
    p = write(urdf(link("base"), _inertial_link("l1", 1, 0.001, 0.001, 0.01), joint("j1", "base", "l1")))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        model = load_urdf(p)
    msgs = [str(x.message) for x in w if issubclass(x.category, cs.ModelWarning)]
    assert len(msgs) == 1 and "body 'l1'" in msgs[0] and "triangle inequality" in msgs[0] and "by 0.008" in msgs[0]
    np.testing.assert_allclose(model.inertia[0], np.diag([0.001, 0.001, 0.01]))  # loaded as is
    for check in ("warn", "lenient"):
        with pytest.warns(cs.ModelWarning, match="triangle inequality"):
            load_urdf(p, inertia_check=check)
    with pytest.raises(cs.ModelError, match=r"robot\.urdf: body 'l1': implausible inertia: .*triangle inequality"):
        load_urdf(p, inertia_check="strict")
    with pytest.raises(cs.ModelError, match="inertia_check must be one of"):
        load_urdf(p, inertia_check="loose")


def test_link_judged_by_its_merged_body(write):
    """A link that is not a rigid body's inertia on its own but is fixed to a heavier one:
    a placeholder (mass 1e-6, every entry 1e-6: moments [~0, ~0, 3e-6]) is a note; a
    non-negligible one (PR2's sensor mount inside the head) is one warning for the body,
    naming the link; strict refuses the latter, not the former."""
    heavy = _inertial_link("trunk", 20.0, 0.5, 0.6, 0.7)
    placeholder = _inertial_link("base", 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6)
    p = write(urdf(placeholder, heavy, _fixed("fb", "base", "trunk", "0.1 0 0"), link("l1"),
                   joint("j1", "trunk", "l1", type="continuous")))
    for check in ("warn", "strict"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            model = load_urdf(p, floating_base="free", inertia_check=check)
        assert any("link 'base'" in n and "placeholder" in n for n in model.notes), model.notes
    pin = pytest.importorskip("pinocchio")
    pm = pin.buildModelFromUrdf(p, pin.JointModelFreeFlyer())
    I = pm.inertias[1]  # the merged root body, in Pinocchio's root frame = cstorm's
    np.testing.assert_allclose(model.mass[0], I.mass, rtol=1e-15)
    np.testing.assert_allclose(model.com[0], I.lever, atol=1e-15)
    np.testing.assert_allclose(model.inertia[0], I.inertia, atol=1e-15)

    mount = _inertial_link("mount", 0.05, 0.001, 0.001, 0.01)
    p = write(urdf(heavy, mount, _fixed("fm", "trunk", "mount", "0 0 0.2"), link("l1"), joint("j1", "trunk", "l1")))
    with pytest.warns(cs.ModelWarning, match=r"body 'trunk' \(2 links merged by fixed joints\): implausible inertia: "
                                             r"link 'mount' on its own .*I3 exceeds I1 \+ I2 by 0\.008.*merged body's "
                                             r"inertia is physical"):
        load_urdf(p, floating_base="free")
    with pytest.raises(cs.ModelError, match="link 'mount' on its own"):
        load_urdf(p, floating_base="free", inertia_check="strict")


def test_indefinite_link_on_a_physical_body_warns(write):
    """TIAGo's antenna: [-3.5e-8, 3.5e-8, 9.1e-8] on its own, welded to a 43 kg base:
    loaded with a warning naming it (strict: an error); the same link as a body of its
    own is refused."""
    antenna = _inertial_link("antenna", 1e-6, 0.0, 0.0, 9.1e-8, ixy=3.5e-8)
    heavy = _inertial_link("base", 43.0, 0.7, 2.0, 2.1)
    p = write(urdf(heavy, antenna, _fixed("fa", "base", "antenna", "0.1 0.1 0.3"), link("l1"),
                   joint("j1", "base", "l1")))
    with pytest.warns(cs.ModelWarning, match=r"body 'base' .*link 'antenna' on its own is indefinite"):
        model = load_urdf(p, floating_base="free")
    assert model.nv == 7
    with pytest.raises(cs.ModelError, match="link 'antenna' on its own is indefinite"):
        load_urdf(p, floating_base="free", inertia_check="strict")
    p = write(urdf(heavy, antenna, joint("ja", "base", "antenna"), link("l1"), joint("j1", "base", "l1")))
    with pytest.raises(cs.ModelError, match=r"body 'antenna': inertia is not positive semi-definite"):
        load_urdf(p)
    # welded to the world (fixed base): not part of the dynamics, a note
    p = write(urdf(heavy, antenna, _fixed("fa", "base", "antenna"), link("l1"), joint("j1", "base", "l1")))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = load_urdf(p)
    assert any("'antenna' is welded to the world" in n for n in model.notes)


def test_indefinite_merged_body_is_refused(write):
    """A link whose negative moment is not outweighed by the body it is fixed to: the
    merged body is indefinite, an error naming the body and the link (any inertia_check)."""
    bad = _inertial_link("bad", 1.0, 0.01, -0.05, 0.05)
    p = write(urdf(link("base"), link("l1"), joint("j1", "base", "l1"), bad, _fixed("fb", "l1", "bad")))
    for check in ("warn", "strict"):
        with pytest.raises(cs.ModelError, match=r"body 'l1'.*links \['l1', 'bad'\]: inertia is not positive "
                                                r"semi-definite .*indefinite links: link 'bad'"):
            load_urdf(p, inertia_check=check)


def test_rounding_noise_is_clipped_with_a_note(write):
    """A point mass with rounding noise in its inertia (iCub's legs: [-6e-21, 8e-22, 1.1e-18]
    beside ~0.1 kg m^2 elsewhere) and a body with a -1e-12 relative moment: clipped, noted."""
    p = write(urdf(link("base"), _inertial_link("l1", 1.0, 0.1, 0.2, 0.25), joint("j1", "base", "l1"),
                   _inertial_link("l2", 1.26, -6e-21, 8e-22, 1.1e-18), joint("j2", "l1", "l2", extra=
                   '<origin xyz="0.3 0 0"/><axis xyz="0 1 0"/>'),
                   _inertial_link("l3", 1.0, 0.1, 0.1, -1e-13), joint("j3", "l2", "l3", extra='<origin xyz="0 0 -0.2"/><axis xyz="0 1 0"/>')))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = load_urdf(p)
    for b in (1, 2):
        assert np.linalg.eigvalsh(np.asarray(model.inertia[b])).min() >= 0
        assert any(f"body '{model.body_names[b]}': principal moment" in n and "clipped to 0" in n for n in model.notes)
    assert describe(model).count("note:") == len(model.notes)


def test_inertia_errors_of_links(write):
    """What no body can survive is refused on the link itself, whatever it is fixed to."""
    heavy = _inertial_link("base", 43.0, 0.7, 2.0, 2.1)
    for bad, pattern in [(link("x", m=-1.0), r"link 'x': mass must be finite and >= 0"),
                         (_inertial_link("x", "nan", 1, 1, 1), r"attribute value='nan' must be finite"),
                         (_inertial_link("x", 1, "inf", 1, 1), r"attribute ixx='inf' must be finite")]:
        p = write(urdf(heavy, bad, _fixed("f", "base", "x"), link("l1"), joint("j1", "base", "l1")))
        with pytest.raises(cs.ModelError, match=pattern):
            load_urdf(p, floating_base="free")
    b = cs.ModelBuilder("asym")
    with pytest.raises(cs.ModelError, match="link 'a': inertia matrix is not symmetric"):
        b.add_link("a", 1.0, inertia=[[1, 0.1, 0], [0, 1, 0], [0, 0, 1]])


# ----------------------------------------------------------------------------- parsing
def test_urdf_contents(write):
    rpy = (0.3, -0.2, 0.5)
    text = urdf(
        link("base", extra='<collision><origin xyz="0 0 -0.1"/><geometry><box size="0.2 0.4 0.6"/></geometry></collision>'),
        '<link name="l1"><inertial><origin xyz="0.1 0.2 0.3" rpy="%g %g %g"/><mass value="2"/>'
        '<inertia ixx="0.02" iyy="0.03" izz="0.04" ixy="0" ixz="0" iyz="0"/></inertial>'
        '<collision name="c"><origin xyz="0 0 0.5" rpy="0 1.5707963267948966 0"/><geometry><cylinder radius="0.05" length="0.4"/></geometry></collision>'
        '<collision><geometry><sphere radius="0.07"/></geometry></collision>'
        '<collision><geometry><capsule radius="0.03" length="0.2"/></geometry></collision>'
        '<visual><geometry><mesh filename="package://nowhere/x.stl"/></geometry></visual></link>' % rpy,
        link("l2"),
        joint("j1", "base", "l1", extra='<origin xyz="0 0 1" rpy="0 0 0.1"/><limit lower="-1" upper="2" effort="30" velocity="4"/>'
              '<dynamics damping="0.5" friction="0.1"/>'),
        joint("j2", "l1", "l2", type="continuous", extra=""),
        link("tool", m=None), joint("tool_joint", "l2", "tool", type="fixed", extra='<origin xyz="0.2 0 0"/>'),
    )
    model = load_urdf(write(text))
    assert model.joint_names == ("j1", "j2") and model.body_names == ("l1", "l2")
    R = rpy_to_matrix(rpy)
    np.testing.assert_allclose(model.inertia[0], R @ np.diag([0.02, 0.03, 0.04]) @ R.T, atol=1e-15)
    np.testing.assert_allclose(model.com[0], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(model.axis[1], [1.0, 0.0, 0.0])  # URDF default axis
    np.testing.assert_allclose(model.joint_p[0], [0, 0, 1])
    assert (float(model.q_lower[0]), float(model.q_upper[0])) == (-1.0, 2.0)
    assert not np.isfinite(model.q_lower[1])  # continuous
    assert float(model.effort_limit[0]) == 30 and float(model.velocity_limit[0]) == 4
    assert float(model.damping[0]) == 0.5
    kinds = dict(zip(model.geom_names, model.geoms))
    np.testing.assert_allclose(kinds["base_collision0"].half_extents, [0.1, 0.2, 0.3])
    assert model.geom_bodies[model.geom_names.index("base_collision0")] == -1  # fixed to the world
    c = kinds["c"]
    assert isinstance(c, cs.Cylinder) and float(c.length) == 0.4 and float(c.radius) == 0.05
    np.testing.assert_allclose(model.geom_poses[model.geom_names.index("c")][:3, 3], [0, 0, 0.5])
    assert isinstance(kinds["l1_collision1"], cs.Sphere) and isinstance(kinds["l1_collision2"], cs.Capsule)
    assert "tool" in model.frame_names
    np.testing.assert_allclose(cs.frame_pose(model, jnp.zeros(2), "base"), np.eye(4))  # welded to the world
    b, T = model.frame_pose("tool")
    assert b == 1 and np.allclose(T[:3, 3], [0.2, 0, 0])
    text = describe(model)
    for s in ("'j1': revolute", "q[1:2]", "range [-1, 2]", "damping 0.5", "effort limit 30", "box half_extents",
              "cylinder r=0.05", "frame 'tool'", "world (fixed):"):
        assert s in text, s


def test_floating_bases(write):
    text = urdf(link("base"), link("l1"), joint("j1", "base", "l1"))
    free = load_urdf(write(text), floating_base="free")
    assert free.joint_names == ("root", "j1") and (free.nq, free.nv) == (8, 7)
    planar = load_urdf(write(text), floating_base="planar")
    assert planar.joint_names == ("root_x", "root_z", "root_pitch", "j1")
    floating = urdf(link("world", m=None), link("base"), joint("fb", "world", "base", type="floating", extra=""))
    m = load_urdf(write(floating))
    assert m.joint_names == ("fb",) and m.nq == 7


def test_mimic_joints_warn(write):
    text = urdf(link("base"), link("a"), link("b"), joint("ja", "base", "a"),
                joint("jb", "base", "b", extra='<axis xyz="0 0 1"/><mimic joint="ja"/>'))
    with pytest.warns(UserWarning, match=r"<mimic> is not modelled; joints \['jb'\]"):
        assert load_urdf(write(text)).nv == 2


# ----------------------------------------------------------------------------- meshes
def _mesh_urdf(filename, scale=None):
    s = f' scale="{scale}"' if scale else ""
    return urdf(link("base"), link("l1", extra=f'<collision><geometry><mesh filename="{filename}"{s}/></geometry></collision>'),
                joint("j1", "base", "l1"))


@pytest.fixture
def stl_box(tmp_path):
    trimesh = pytest.importorskip("trimesh", reason="meshes need the optional trimesh package")
    d = tmp_path / "pkgs" / "mypkg" / "meshes"
    d.mkdir(parents=True)
    trimesh.creation.box(extents=(0.2, 0.4, 0.6)).export(str(d / "box.stl"))
    return tmp_path


def _mesh_extent(model):
    (g,) = [g for g in model.geoms if isinstance(g, cs.ConvexMesh)]
    v = np.asarray(g.vertices)
    return v.max(axis=0) - v.min(axis=0)


def test_package_paths(stl_box, write):
    pkgs = str(stl_box / "pkgs")
    p = write(_mesh_urdf("package://mypkg/meshes/box.stl", scale="2 1 0.5"), "robots/r.urdf")
    np.testing.assert_allclose(_mesh_extent(load_urdf(p, package_dirs={"mypkg": pkgs + "/mypkg"})), [0.4, 0.4, 0.3])
    np.testing.assert_allclose(_mesh_extent(load_urdf(p, package_dirs=[pkgs])), [0.4, 0.4, 0.3])
    # found through the URDF's ancestors (ROS layout: <pkg>/urdf/robot.urdf)
    p2 = write(_mesh_urdf("package://mypkg/meshes/box.stl"), "pkgs/mypkg/urdf/r.urdf")
    np.testing.assert_allclose(_mesh_extent(load_urdf(p2)), [0.2, 0.4, 0.6])
    # relative to the URDF
    p3 = write(_mesh_urdf("meshes/box.stl"), "pkgs/mypkg/r.urdf")
    np.testing.assert_allclose(_mesh_extent(load_urdf(p3)), [0.2, 0.4, 0.6])


def test_package_uri_resolution_order(stl_box, write, monkeypatch, tmp_path):
    """``package://`` through package_dirs, ROS_PACKAGE_PATH, and the directories around
    the file (a sibling package folder); ``package:///path`` (TALOS full_v2's form) below a
    package root or an ancestor of the file."""
    pkgs = str(stl_box / "pkgs")
    other = tmp_path / "elsewhere" / "urdf"
    other.mkdir(parents=True)
    p = str(other / "r.urdf")
    with open(p, "w") as f:
        f.write(_mesh_urdf("package://mypkg/meshes/box.stl"))
    with pytest.warns(cs.ModelWarning, match=r"package://mypkg/meshes/box.stl \(link 'l1': not found\)"):
        assert load_urdf(p).n_geoms == 0
    monkeypatch.setenv("ROS_PACKAGE_PATH", os.pathsep.join(["/nonexistent", pkgs]))
    np.testing.assert_allclose(_mesh_extent(load_urdf(p)), [0.2, 0.4, 0.6])
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    # a sibling package of the URDF's package: <root>/robots/r.urdf, <root>/mypkg/meshes
    p2 = write(_mesh_urdf("package://mypkg/meshes/box.stl", scale="1 1 2"), "pkgs/robots/r.urdf")
    np.testing.assert_allclose(_mesh_extent(load_urdf(p2)), [0.2, 0.4, 1.2])
    # package:///<path below a package root>
    p3 = write(_mesh_urdf("package:///mypkg/meshes/box.stl"), "pkgs/mypkg/urdf/r3.urdf")
    np.testing.assert_allclose(_mesh_extent(load_urdf(p3)), [0.2, 0.4, 0.6])
    with open(p, "w") as f:
        f.write(_mesh_urdf("package:///mypkg/meshes/box.stl"))
    np.testing.assert_allclose(_mesh_extent(load_urdf(p, package_dirs=[pkgs])), [0.2, 0.4, 0.6])
    with pytest.warns(cs.ModelWarning, match=r"package://mypkg \(link 'l1': malformed package URI"):
        load_urdf(write(_mesh_urdf("package://mypkg"), "pkgs/r4.urdf"))


def test_missing_mesh_keeps_other_geometry(write):
    two = urdf(link("base"), link("l1", extra='<collision><geometry><mesh filename="package://nope/a.stl"/></geometry>'
                                              '</collision><collision><geometry><sphere radius="0.1"/></geometry>'
                                              '</collision>'), joint("j1", "base", "l1"))
    with pytest.warns(cs.ModelWarning, match=r"package://nope/a.stl \(link 'l1': not found\)"):
        model = load_urdf(write(two))
    assert model.geom_names == ("l1_collision1",) and isinstance(model.geoms[0], cs.Sphere)


@pytest.mark.parametrize("filename", ["package:///../../../../etc/passwd", "package://mypkg/../../../../etc/passwd", "../../etc/passwd", "/etc/passwd",
                                      "file:///etc/passwd"])
def test_mesh_paths_escaping_roots_are_errors(stl_box, write, filename):
    p = write(_mesh_urdf(filename), "pkgs/mypkg/urdf/r.urdf")
    with pytest.raises(cs.ModelError, match=r"<mesh> \(collision 'l1_collision0' of link 'l1'\): mesh (path|file)"):
        load_urdf(p, package_dirs={"mypkg": str(stl_box / "pkgs" / "mypkg")})


def test_symlink_escape_is_an_error(stl_box, write):
    d = stl_box / "pkgs" / "mypkg" / "meshes"
    os.symlink("/etc/hostname", d / "evil.stl")
    p = write(_mesh_urdf("package://mypkg/meshes/evil.stl"), "r.urdf")
    with pytest.raises(cs.ModelError, match="outside"):
        load_urdf(p, package_dirs={"mypkg": str(stl_box / "pkgs" / "mypkg")})


def test_missing_mesh_and_missing_trimesh_warn(write, monkeypatch):
    p = write(_mesh_urdf("package://unknown/x.stl"))
    with pytest.warns(cs.ModelWarning, match=r"not found or not loadable.*package://unknown/x.stl \(link 'l1': not found\)"):
        assert load_urdf(p).n_geoms == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_urdf(p, load_meshes=False).n_geoms == 0

    import cstorm.model.urdf as U

    def no_trimesh(*a, **k):
        raise ImportError("no trimesh")

    monkeypatch.setattr(U, "mesh_hull_vertices", no_trimesh)
    two = urdf(link("base"), *[link(n, extra='<collision><geometry><mesh filename="m.stl"/></geometry></collision>')
                               for n in ("a", "b")], joint("ja", "base", "a"), joint("jb", "base", "b"))
    p = write(two)
    write("solid x\nendsolid x\n", "m.stl")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        load_urdf(p)
    msgs = [str(x.message) for x in w]
    assert len(msgs) == 1 and "skipped on links ['a', 'b']" in msgs[0] and "trimesh" in msgs[0]


# ----------------------------------------------------------------------------- MJCF
mujoco = None


def _mujoco():
    return pytest.importorskip("mujoco", reason="load_mjcf needs MuJoCo")


def test_mjcf_compile_error_is_wrapped(tmp_path):
    _mujoco()
    from cstorm.model.mjcf import load_mjcf

    p = tmp_path / "bad.xml"
    p.write_text('<mujoco>\n<worldbody>\n<body><joint type="screw"/></body></worldbody></mujoco>')
    with pytest.raises(cs.ModelError, match=r"bad\.xml: MuJoCo could not compile the MJCF model: .*screw"):
        load_mjcf(str(p))
    with pytest.raises(cs.ModelError, match=r"<MJCF string>:1: malformed XML: no element found"):
        load_mjcf("<mujoco><worldbody><body><geom type='sphere' size='-1'/></body></worldbody>")
    with pytest.raises(cs.ModelError, match=r"nope\.xml: MJCF file not found"):
        load_mjcf(str(tmp_path / "nope.xml"))


MJCF = """
<mujoco model="t">
  <option gravity="0 0 -5"/>
  <worldbody>
    <geom name="ground" type="plane" size="5 5 0.1"/>
    <body name="a" pos="0.1 0.2 1" quat="0.9 0.1 0.3 0.2">
      <joint name="hx" type="hinge" axis="1 0 0" pos="0 0 0.2" ref="0.3" damping="0.4" armature="0.05"/>
      <joint name="sy" type="slide" axis="0 1 1" ref="-0.2" stiffness="3" springref="0.1" range="-1 1"/>
      <joint name="hz" type="hinge" axis="0 0.6 0.8" pos="0.1 0 0"/>
      <geom name="ga" type="capsule" fromto="0 0 0 0 0 -0.4" size="0.05"/>
      <site name="tip" pos="0 0 -0.4"/>
      <body name="b" pos="0 0 -0.4">
        <joint name="ball" type="ball" pos="0 0.05 0"/>
        <geom name="gb" type="box" size="0.1 0.05 0.02" pos="0.1 0 0" mass="0.7"/>
        <body name="welded" pos="0.2 0 0"><geom type="sphere" size="0.03"/></body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="hx" gear="2" ctrlrange="-5 5" ctrllimited="true"/></actuator>
</mujoco>
"""


def test_mjcf_chain_ref_anchor_and_ball_match_mujoco():
    mujoco = _mujoco()
    from cstorm.model.mjcf import load_mjcf, qvel_from_v

    model = load_mjcf(MJCF)
    m = mujoco.MjModel.from_xml_string(MJCF)
    assert model.joint_names == ("hx", "sy", "hz", "ball")
    assert model.body_names == ("a/hx", "a/sy", "a", "b")
    np.testing.assert_allclose(model.gravity, [0, 0, -5])
    assert float(model.effort_limit[0]) == 10.0
    assert float(model.stiffness[1]) == 3 and float(model.spring_ref[1]) == pytest.approx(0.1)
    assert (float(model.q_lower[1]), float(model.q_upper[1])) == (-1.0, 1.0)
    assert model.geom_bodies[model.geom_names.index("ground")] == -1
    assert "tip" in model.frame_names and "welded/origin" in model.frame_names
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    for _ in range(3):
        q = model.random_q(rng)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        fk = np.asarray(cs.forward_kinematics(model, jnp.asarray(q)))
        for name in ("a", "b", "welded"):
            bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
            b, T = model.frame_pose(name + "/origin")
            W = fk[b] @ np.asarray(T)
            np.testing.assert_allclose(W[:3, 3], d.xpos[bid], atol=1e-12)
            np.testing.assert_allclose(W[:3, :3], d.xmat[bid].reshape(3, 3), atol=1e-12)
        sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tip")
        b, T = model.frame_pose("tip")
        np.testing.assert_allclose((fk[b] @ np.asarray(T))[:3, 3], d.site_xpos[sid], atol=1e-12)
        v = rng.normal(size=model.nv)
        d.qvel[:] = qvel_from_v(model, q, v)
        mujoco.mj_forward(m, d)
        Mf = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, Mf)
        np.testing.assert_allclose(cs.mass_matrix(model, jnp.asarray(q)), Mf, atol=1e-12)
        np.testing.assert_allclose(cs.passive_forces(model, jnp.asarray(q), jnp.asarray(v)), d.qfrc_passive, atol=1e-12)
    assert "'hx': revolute" in describe(model) and "ball" in describe(model)


def test_mjcf_unsupported_elements_warn_or_refuse():
    """Tendons, equality constraints and the rest are reported (what is ignored and what
    that changes); strict=True refuses them."""
    _mujoco()
    from cstorm.model.mjcf import load_mjcf

    xml = MJCF.replace("</worldbody>", "</worldbody>\n<tendon><fixed name='coupler'><joint joint='hx' coef='1'/>"
                       "<joint joint='hz' coef='-1'/></fixed></tendon>\n<equality><joint name='tie' joint1='hx' "
                       "joint2='hz'/></equality>").replace('<option gravity="0 0 -5"/>',
                                                          '<option gravity="0 0 -5" viscosity="0.1"/>')
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        model = load_mjcf(xml)
    (msg,) = [str(x.message) for x in w if issubclass(x.category, cs.ModelWarning)]
    for s in ("<tendon> ['coupler']", "<equality> ['tie (joint)']", "constraints are not enforced",
              "fluid forces are not modelled", "strict=True refuses it"):
        assert s in msg, s
    assert model.nv == 6
    with pytest.raises(cs.ModelError, match=r"<MJCF string>: elements cstorm does not model \(strict=True\): "
                                            r"<tendon> \['coupler'\]"):
        load_mjcf(xml, strict=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_mjcf(MJCF, strict=True)  # nothing ignored: no warning, no error


def test_mjcf_asset_paths_are_confined(tmp_path):
    """A mesh or include outside the model's directory is refused (as URDF meshes are),
    before MuJoCo reads it."""
    _mujoco()
    trimesh = pytest.importorskip("trimesh")
    from cstorm.model.mjcf import load_mjcf

    outside = tmp_path / "outside"
    outside.mkdir()
    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(str(outside / "box.stl"))
    d = tmp_path / "model"
    d.mkdir()
    body = ("<worldbody><body><joint type='hinge'/><geom type='mesh' mesh='m'/></body></worldbody></mujoco>")
    cases = {"rel.xml": "<mujoco><asset><mesh name='m' file='../outside/box.stl'/></asset>" + body,
             "abs.xml": f"<mujoco><asset><mesh name='m' file='{outside / 'box.stl'}'/></asset>" + body,
             "meshdir.xml": "<mujoco><compiler meshdir='../outside'/><asset><mesh name='m' file='box.stl'/></asset>"
                            + body,
             "include.xml": "<mujoco><include file='../outside/x.xml'/></mujoco>"}
    for name, text in cases.items():
        (d / name).write_text(text)
        with pytest.raises(cs.ModelError, match=rf"{name}:1: <(mesh|include) file=.*outside the model's directory"):
            load_mjcf(str(d / name))
    os.symlink(outside / "box.stl", d / "link.stl")
    (d / "sym.xml").write_text("<mujoco><asset><mesh name='m' file='link.stl'/></asset>" + body)
    with pytest.raises(cs.ModelError, match="outside the model's directory"):
        load_mjcf(str(d / "sym.xml"))
    assert load_mjcf(str(d / "sym.xml"), asset_dirs=[str(outside)]).nv == 1
    (d / "box.stl").write_bytes((outside / "box.stl").read_bytes())
    (d / "ok.xml").write_text("<mujoco><asset><mesh name='m' file='box.stl'/></asset>" + body)
    assert load_mjcf(str(d / "ok.xml")).n_geoms == 1
    (d / "dtd.xml").write_text('<?xml version="1.0"?>\n<!DOCTYPE m [<!ENTITY x SYSTEM "file:///etc/passwd">]>\n'
                               "<mujoco/>")
    with pytest.raises(cs.ModelError, match=r"dtd\.xml:2: DOCTYPE declarations are not allowed"):
        load_mjcf(str(d / "dtd.xml"))


def test_mjcf_accepts_compiled_model():
    mujoco = _mujoco()
    from cstorm.model.mjcf import load_mjcf

    model = load_mjcf(mujoco.MjModel.from_xml_string(MJCF))
    assert model.nq == 1 + 1 + 1 + 4


# ----------------------------------------------------------------------------- big and deep trees
def _chain_urdf(n):
    parts = [link("l0")]
    for i in range(1, n):
        parts += [link(f"l{i}", m=0.1, i=1e-4),
                  joint(f"j{i}", f"l{i - 1}", f"l{i}", extra='<origin xyz="0 0 -0.1"/><axis xyz="0 1 0"/>')]
    return urdf(*parts, name="chain")


def test_deep_chain_loads_and_is_described(write):
    """3,000 links in a chain: no recursion limit in loading, checking or describing."""
    t = time.time()
    model = load_urdf(write(_chain_urdf(3000)))
    text = describe(model)
    assert model.nv == 2999 and "body 'l2999' (#2998, parent l2998)" in text and "[depth 2998]" in text
    assert time.time() - t < 60


def test_model_too_big_for_memory_is_refused_before_allocating(monkeypatch):
    import cstorm.model.builder as B

    monkeypatch.setattr(B, "_available_memory", lambda: 10 * 2**20)
    b = cs.ModelBuilder("chain")
    parent = None
    for i in range(1000):
        b.add_body(f"l{i}", parent, axis=(0, 1, 0), mass=0.1, com=(0, 0, -0.05), inertia=(1e-4, 1e-4, 1e-5))
        parent = f"l{i}"
    with pytest.raises(cs.ModelError, match=r"<builder>: the model has 1000 bodies and nv = 1000: its dense mass "
                                            r"matrix .* need ~0\.0 GiB, more than the 0\.0 GiB of memory available"):
        b.build()
    monkeypatch.undo()
    assert b.build().nv == 1000


def test_singular_and_indefinite_mass_matrix_are_named():
    """A joint moving nothing with inertia about its axis; two coincident parallel hinges
    moving one body (every diagonal entry positive, M singular)."""
    b = cs.ModelBuilder("s")
    b.add_body("a", None, axis=(0, 0, 1), mass=1.0, com=(0.3, 0, 0), inertia=(0.01, 0.01, 0.01))
    b.add_body("b", "a", axis=(1, 0, 0), mass=1.0, com=(0.3, 0, 0), inertia=(0, 0, 0))
    with pytest.raises(cs.ModelError, match=r"joint 'b' moves a subtree with no mass or no inertia about its axis "
                                            r"\(body 'b'\).*add armature"):
        b.build()
    b = cs.ModelBuilder("d")
    b.add_link("m0")
    b.add_body("a", "m0", axis=(0, 0, 1))
    b.add_body("b", "a", axis=(0, 0, 1), mass=1.0, com=(0.3, 0, 0), inertia=(0.01, 0.01, 0.01))
    with pytest.raises(cs.ModelError, match=r"not positive definite at the neutral configuration: joint 'a'"):
        b.build()
    b.joints["a"].armature = 0.1
    assert b.build().nv == 2
