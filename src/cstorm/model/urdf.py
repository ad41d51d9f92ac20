"""URDF loader: ``load_urdf(path) -> Model``.

Parses the file with a hardened XML parser (expat with DTDs refused: no entity
declarations, no entity expansion, no external entities) and describes the robot to a
`ModelBuilder`, which merges fixed joints, validates inertias and checks the tree.

What is read (URDF spec, http://wiki.ros.org/urdf/XML):

- ``<link>``: ``<inertial>`` (``<origin>`` of the inertial frame: its rotation turns the
  inertia tensor into the link frame; ``<mass>``; ``<inertia>`` about the CoM). A link
  without ``<inertial>`` is massless. ``<collision>`` shapes: ``box`` (``size`` = full
  extents, stored as half extents), ``sphere``, ``cylinder`` (axis z, ``length`` full),
  ``capsule`` (same convention), ``mesh`` (convex hull of the file's vertices, ``scale``
  honoured; needs the optional ``trimesh`` package, extra ``cstorm[mesh]``; without it
  meshes are skipped with one warning naming the links). ``<visual>`` is ignored.
- ``<joint>``: ``revolute``, ``continuous`` (both nq = nv = 1; cstorm stores the angle,
  not Pinocchio's (cos, sin)), ``prismatic``, ``fixed``, ``floating`` (a free joint);
  ``planar`` is refused. ``<origin>`` (parent link frame from joint frame), ``<axis>``
  (default (1, 0, 0), in the joint frame), ``<limit>`` (lower, upper, velocity, effort;
  lower/upper default to 0 as in the spec, velocity/effort to +inf; a revolute or
  prismatic joint without ``<limit>`` is unlimited), ``<dynamics damping>`` (friction
  is ignored). ``<mimic>`` is not modelled: a mimic joint becomes an
  independent DoF (one warning lists them), as in Pinocchio's default.

Mesh paths (see `_resolve_mesh`): ``package://pkg/rest`` is looked up in ``package_dirs``
(a dict ``{"pkg": dir}``, or a list of directories that hold package folders or are
one), then in ``ROS_PACKAGE_PATH``, then around the file (an ancestor of the URDF's
directory named ``pkg``, or holding a folder ``pkg``); ``package:///rest`` is ``rest``
below any of those roots. ``file://`` and absolute paths must lie below the URDF's
directory or one of ``mesh_dirs``; relative paths are taken below the URDF's directory
(then ``mesh_dirs``). A path that resolves (symlinks followed) outside the directory it
was looked up in is an error; a mesh that cannot be found or read (or a malformed URI)
is skipped with one `cstorm.ModelWarning` naming it, and the link keeps its other shapes.

Inertias are judged on the merged bodies (`cstorm.model.inertia`): rounding noise is
repaired with a note (``model.notes``), implausible but computable inertias load with one
warning per body (``inertia_check="strict"`` refuses them), what the dynamics cannot
survive is an error.

Every error is a `cstorm.ModelError` naming the file, and the line, element, joint or link.
"""

from __future__ import annotations

import os
import warnings
import xml.parsers.expat
import xml.etree.ElementTree as ET

import numpy as np

from ..errors import ModelError, ModelWarning
from ..geometry.shapes import Box, Capsule, ConvexMesh, Cylinder, Sphere
from .builder import ModelBuilder, rpy_to_matrix
from .model import Model

__all__ = ["load_urdf", "parse_xml"]


class _Refused(Exception):
    pass


def parse_xml(text: bytes | str, source: str):
    """Parse XML with DTDs refused. Returns ``(root Element, {element: line})``.

    Raises `ModelError` naming ``source`` and the line for malformed XML and for any
    DOCTYPE / ENTITY declaration (so no entity is ever expanded or fetched)."""
    if isinstance(text, str):
        text = text.encode("utf-8")
    builder = ET.TreeBuilder()
    lines: dict = {}
    p = xml.parsers.expat.ParserCreate()
    p.SetParamEntityParsing(xml.parsers.expat.XML_PARAM_ENTITY_PARSING_NEVER)

    def refuse(what):
        def handler(*args):
            raise _Refused(f"{source}:{p.CurrentLineNumber}: {what} are not allowed (DTDs and entities are refused "
                           "to prevent entity-expansion and external-entity attacks)")
        return handler

    p.StartDoctypeDeclHandler = refuse("DOCTYPE declarations")
    p.EntityDeclHandler = refuse("ENTITY declarations")
    p.UnparsedEntityDeclHandler = refuse("ENTITY declarations")
    p.ExternalEntityRefHandler = refuse("external entities")

    def start(tag, attrs):
        el = builder.start(tag, attrs)
        lines[el] = p.CurrentLineNumber

    p.StartElementHandler = start
    p.EndElementHandler = builder.end
    p.CharacterDataHandler = builder.data
    p.buffer_text = True
    try:
        p.Parse(text, True)
    except _Refused as e:
        raise ModelError(str(e)) from None
    except xml.parsers.expat.ExpatError as e:
        raise ModelError(f"{source}:{e.lineno}: malformed XML: {xml.parsers.expat.ErrorString(e.code)} "
                         f"(line {e.lineno}, column {e.offset})") from None
    return builder.close(), lines


class _Ctx:
    """Parsing context: file name and element line numbers, for error messages."""

    def __init__(self, source, lines):
        self.source, self.lines = source, lines

    def where(self, el, what=""):
        line = self.lines.get(el)
        loc = f"{self.source}:{line}" if line else self.source
        return f"{loc}: <{el.tag}>" + (f" {what}" if what else "")

    def err(self, el, msg, what=""):
        return ModelError(f"{self.where(el, what)}: {msg}")

    def attr(self, el, name, what="", required=True, default=None):
        v = el.get(name)
        if v is None:
            if required:
                raise self.err(el, f"missing required attribute {name!r}", what)
            return default
        return v

    def floats(self, el, name, n, what="", default=None):
        s = el.get(name)
        if s is None:
            if default is None:
                raise self.err(el, f"missing required attribute {name!r}", what)
            return np.asarray(default, dtype=float)
        try:
            vals = [float(x) for x in s.split()]
        except ValueError:
            raise self.err(el, f"attribute {name}={s!r} is not a list of numbers", what) from None
        if n is not None and len(vals) != n:
            raise self.err(el, f"attribute {name}={s!r} must have {n} numbers, got {len(vals)}", what)
        a = np.asarray(vals, dtype=float)
        if not np.all(np.isfinite(a)):
            raise self.err(el, f"attribute {name}={s!r} must be finite", what)
        return a

    def scalar(self, el, name, what="", default=None, allow_inf=False):
        s = el.get(name)
        if s is None:
            if default is None:
                raise self.err(el, f"missing required attribute {name!r}", what)
            return float(default)
        try:
            x = float(s)
        except ValueError:
            raise self.err(el, f"attribute {name}={s!r} is not a number", what) from None
        if np.isnan(x) or (not allow_inf and not np.isfinite(x)):
            raise self.err(el, f"attribute {name}={s!r} must be finite", what)
        return x

    def origin(self, parent, what=""):
        """(4, 4) pose from an optional <origin xyz rpy> child."""
        o = parent.find("origin")
        T = np.eye(4)
        if o is not None:
            T[:3, 3] = self.floats(o, "xyz", 3, what, default=(0.0, 0.0, 0.0))
            T[:3, :3] = rpy_to_matrix(self.floats(o, "rpy", 3, what, default=(0.0, 0.0, 0.0)))
        return T


# ------------------------------------------------------------------------ mesh paths
def _within(path, root):
    path, root = os.path.realpath(path), os.path.realpath(root)
    return path == root or path.startswith(root.rstrip(os.sep) + os.sep)


def _package_roots(package_dirs):
    """``[(root, pkg or None)]`` from ``package_dirs`` then ``ROS_PACKAGE_PATH``: a dict
    entry maps one package name to its directory; a list entry is a directory that holds
    package folders (or is one)."""
    roots: list[tuple[str, str | None]] = []
    if isinstance(package_dirs, dict):
        roots += [(os.fspath(d), pkg) for pkg, d in package_dirs.items()]
    elif isinstance(package_dirs, (str, os.PathLike)):
        roots.append((os.fspath(package_dirs), None))
    elif package_dirs is not None:
        roots += [(os.fspath(d), None) for d in package_dirs]
    roots += [(d, None) for d in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if d]
    return roots


def _resolve_mesh(filename, urdf_dir, package_dirs, mesh_dirs, ctx, el, what):
    """``(absolute path or None, why not found)``. Raises ModelError when the path escapes
    the directory it is looked up in (``..``, absolute parts, symlinks).

    ``package://pkg/rest``: ``<dir>/rest`` for ``package_dirs={"pkg": dir}``, then
    ``<root>/pkg/rest`` (or ``<root>/rest`` when root is named pkg) for each directory of
    a ``package_dirs`` list and of ``ROS_PACKAGE_PATH``, then for each directory ``d``
    around the file (the URDF's folder and its ancestors) ``d/rest`` when ``d`` is named
    pkg and ``d/pkg/rest``. ``package:///rest`` (no package name) is ``<root>/rest`` for
    the same roots and ancestors."""
    cands: list[tuple[str, str]] = []  # (candidate path, the root it must stay in)
    ancestors = []
    d = os.path.abspath(urdf_dir)
    while True:
        ancestors.append(d)
        parent = os.path.dirname(d)
        if parent == d:
            break
        d = parent
    if filename.startswith("package://"):
        rest = filename[len("package://"):]
        if rest.startswith("/"):  # package:///path: a path below a package root
            sub = rest.lstrip("/")
            if not sub:
                return None, "malformed package URI (no path)"
            for root, pkg in _package_roots(package_dirs):
                cands.append((os.path.join(root, sub), root))
            cands += [(os.path.join(a, sub), a) for a in ancestors]
        else:
            pkg, _, sub = rest.partition("/")
            if not sub:
                return None, "malformed package URI (no path after the package name)"
            for root, name in _package_roots(package_dirs):
                if name is not None:
                    if name == pkg:
                        cands.append((os.path.join(root, sub), root))
                    continue
                if os.path.basename(os.path.normpath(root)) == pkg:
                    cands.append((os.path.join(root, sub), root))
                cands.append((os.path.join(root, pkg, sub), os.path.join(root, pkg)))
            for a in ancestors:
                if os.path.basename(a) == pkg:
                    cands.append((os.path.join(a, sub), a))
                cands.append((os.path.join(a, pkg, sub), os.path.join(a, pkg)))
    else:
        path = filename[len("file://"):] if filename.startswith("file://") else filename
        roots = [urdf_dir] + [os.fspath(m) for m in (mesh_dirs or ())]
        if os.path.isabs(path):
            if not any(_within(path, r) for r in roots):
                raise ctx.err(el, f"mesh file {filename!r} lies outside the allowed directories {roots} "
                              "(pass its directory in mesh_dirs)", what)
            cands.append((path, os.path.dirname(path)))
        else:
            cands += [(os.path.join(r, path), r) for r in roots]
    for path, root in cands:
        if not _within(path, root):
            raise ctx.err(el, f"mesh path {filename!r} resolves to {os.path.realpath(path)!r}, outside "
                          f"{os.path.realpath(root)!r}", what)
    for path, _ in cands:
        if os.path.isfile(path):
            return os.path.realpath(path), ""
    return None, "not found"


def mesh_hull_vertices(path, scale=(1.0, 1.0, 1.0)):
    """(k, 3) vertices of the convex hull of a mesh file (STL/OBJ/DAE...), scaled.
    Needs ``trimesh``; raises ImportError without it."""
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except ImportError as e:  # a format plugin (pycollada for .dae) is missing, not trimesh itself
        raise RuntimeError(f"reading this format needs a package trimesh could not import ({e})") from None
    v = np.asarray(mesh.vertices, dtype=float) * np.asarray(scale, dtype=float)
    if len(v) >= 4:
        try:
            hull = trimesh.convex.convex_hull(v)
            v = np.asarray(hull.vertices, dtype=float)
        except Exception:  # degenerate (flat) meshes: keep the raw vertices, ConvexMesh rejects them
            pass
    return v


# ------------------------------------------------------------------------ loader
def load_urdf(path, floating_base: str | None = None, package_dirs=None, mesh_dirs=None,
              load_meshes: bool = True, inertia_check: str = "warn") -> Model:
    """Load a URDF file into a `Model`.

    Args:
        path: the ``.urdf`` file.
        floating_base: None (the root link is fixed to the world), ``"free"`` (a free
            joint named ``root``) or ``"planar"`` (``root_x``, ``root_z``, ``root_pitch``);
            see `ModelBuilder.build`.
        package_dirs: where ``package://`` mesh URIs point: ``{"pkg": "/dir/of/pkg"}`` or a
            list of directories holding package folders (searched before
            ``ROS_PACKAGE_PATH`` and the directories around the file).
        mesh_dirs: further directories that mesh files may lie in (besides the URDF's).
        load_meshes: False skips ``<mesh>`` collision geometry silently.
        inertia_check: ``"warn"`` (default; ``"lenient"`` is a synonym): a body whose
            inertia violates the triangle inequality, or holds an implausible link, loads
            with one `cstorm.ModelWarning` per body; ``"strict"``: a `ModelError`. What
            the dynamics cannot survive (indefinite bodies, negative mass, NaN) is an
            error either way; rounding noise is repaired with a note in ``model.notes``.
    Returns: the `Model`; collision shapes in ``model.geoms``.
    Raises: `cstorm.ModelError` naming the file and the element, joint or link at fault.
    """
    source = os.fspath(path)
    try:
        with open(source, "rb") as fh:
            text = fh.read()
    except OSError as e:
        raise ModelError(f"{source}: cannot read URDF file: {e.strerror or e}") from None
    root, lines = parse_xml(text, source)
    ctx = _Ctx(source, lines)
    if root.tag != "robot":
        raise ctx.err(root, "the root element of a URDF must be <robot>")
    urdf_dir = os.path.dirname(os.path.abspath(source))
    b = ModelBuilder(root.get("name", os.path.splitext(os.path.basename(source))[0]), source=source,
                     inertia_check=inertia_check)

    no_trimesh_links: list[str] = []
    missing_meshes: list[str] = []
    for link in root.findall("link"):
        name = ctx.attr(link, "name", "(a link)")
        what = f"of link {name!r}"
        mass, com, inertia = 0.0, np.zeros(3), np.zeros((3, 3))
        inertial = link.find("inertial")
        if inertial is not None:
            T = ctx.origin(inertial, what)
            m_el = inertial.find("mass")
            if m_el is None:
                raise ctx.err(inertial, "has no <mass>", what)
            mass = ctx.scalar(m_el, "value", what)
            i_el = inertial.find("inertia")
            if i_el is None:
                raise ctx.err(inertial, "has no <inertia>", what)
            ixx, ixy, ixz, iyy, iyz, izz = (ctx.scalar(i_el, k, what, default=(0.0 if k[1] != k[2] else None))
                                            for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
            I = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
            R = T[:3, :3]
            com, inertia = T[:3, 3], R @ I @ R.T
        if name in b.links:
            raise ctx.err(link, f"link {name!r} is defined twice")
        b.add_link(name, mass, com, inertia)

        for k, col in enumerate(link.findall("collision")):
            gname = col.get("name") or f"{name}_collision{k}"
            gwhat = f"(collision {gname!r} of link {name!r})"
            Tg = ctx.origin(col, gwhat)
            geo = col.find("geometry")
            if geo is None or len(geo) == 0:
                raise ctx.err(col, "has no <geometry>", gwhat)
            g = geo[0]
            try:
                if g.tag == "box":
                    shape = Box(0.5 * ctx.floats(g, "size", 3, gwhat))
                elif g.tag == "sphere":
                    shape = Sphere(ctx.scalar(g, "radius", gwhat))
                elif g.tag == "cylinder":
                    shape = Cylinder(ctx.scalar(g, "radius", gwhat), ctx.scalar(g, "length", gwhat))
                elif g.tag == "capsule":
                    shape = Capsule(ctx.scalar(g, "radius", gwhat), ctx.scalar(g, "length", gwhat))
                elif g.tag == "mesh":
                    if not load_meshes:
                        continue
                    fname = ctx.attr(g, "filename", gwhat)
                    scale = ctx.floats(g, "scale", 3, gwhat, default=(1.0, 1.0, 1.0))
                    mpath, why = _resolve_mesh(fname, urdf_dir, package_dirs, mesh_dirs, ctx, g, gwhat)
                    if mpath is None:
                        missing_meshes.append(f"{fname} (link {name!r}: {why})")
                        continue
                    try:
                        verts = mesh_hull_vertices(mpath, scale)
                    except ImportError:
                        no_trimesh_links.append(name)
                        continue
                    except Exception as e:  # unreadable file, or a format trimesh needs a plugin for
                        missing_meshes.append(f"{fname} (link {name!r}: cannot load: {type(e).__name__}: {e})")
                        continue
                    shape = ConvexMesh(verts)
                else:
                    raise ctx.err(g, f"unsupported geometry <{g.tag}> (box, sphere, cylinder, capsule, mesh)", gwhat)
            except ModelError:
                raise
            except Exception as e:  # ShapeError: bad sizes
                raise ctx.err(g, str(e), gwhat) from None
            b.add_geom(name, shape, pose=Tg, name=gname)

    mimics = []
    for joint in root.findall("joint"):
        name = ctx.attr(joint, "name", "(a joint)")
        what = f"of joint {name!r}"
        jtype = ctx.attr(joint, "type", what)
        if jtype == "planar":
            raise ctx.err(joint, "joint type 'planar' is not supported (use a prismatic-prismatic-revolute chain, "
                          "or floating_base='planar' for a planar root)", what)
        if jtype not in ("revolute", "continuous", "prismatic", "fixed", "floating"):
            raise ctx.err(joint, f"unknown joint type {jtype!r} (revolute, continuous, prismatic, fixed, floating)",
                          what)
        ends = {}
        for role in ("parent", "child"):
            e = joint.find(role)
            if e is None:
                raise ctx.err(joint, f"has no <{role}>", what)
            ends[role] = ctx.attr(e, "link", what)
            if ends[role] not in b.links:
                raise ctx.err(e, f"{role} link {ends[role]!r} does not exist", what)
        T = ctx.origin(joint, what)
        ax_el = joint.find("axis")
        axis = ctx.floats(ax_el, "xyz", 3, what, default=(1.0, 0.0, 0.0)) if ax_el is not None else np.array([1.0, 0, 0])
        if jtype in ("revolute", "continuous", "prismatic") and np.linalg.norm(axis) < 1e-12:
            raise ctx.err(ax_el if ax_el is not None else joint, "axis must be non-zero", what)
        kw = {}
        lim = joint.find("limit")
        if lim is not None and jtype in ("revolute", "prismatic"):
            kw["lower"] = ctx.scalar(lim, "lower", what, default=0.0, allow_inf=True)
            kw["upper"] = ctx.scalar(lim, "upper", what, default=0.0, allow_inf=True)
            if kw["lower"] > kw["upper"]:
                raise ctx.err(lim, f"lower limit {kw['lower']} exceeds upper limit {kw['upper']}", what)
        if lim is not None and jtype in ("revolute", "continuous", "prismatic"):
            kw["velocity"] = ctx.scalar(lim, "velocity", what, default=np.inf, allow_inf=True)
            kw["effort"] = ctx.scalar(lim, "effort", what, default=np.inf, allow_inf=True)
            for k in ("velocity", "effort"):
                if kw[k] < 0:
                    raise ctx.err(lim, f"{k} limit must be >= 0, got {kw[k]}", what)
        dyn = joint.find("dynamics")
        if dyn is not None and jtype != "fixed":
            kw["damping"] = ctx.scalar(dyn, "damping", what, default=0.0)
            if kw["damping"] < 0:
                raise ctx.err(dyn, f"damping must be >= 0, got {kw['damping']}", what)
        if joint.find("mimic") is not None:
            mimics.append(name)
        if name in b.joints:
            raise ctx.err(joint, f"joint {name!r} is defined twice")
        b.add_joint(name, "free" if jtype == "floating" else jtype, ends["parent"], ends["child"], pose=T,
                    axis=axis, **kw)

    if no_trimesh_links:
        warnings.warn(f"{source}: mesh collision geometry skipped on links {sorted(set(no_trimesh_links))}: "
                      "install trimesh (pip install 'cstorm[mesh]') to load meshes as convex hulls", ModelWarning,
                      stacklevel=2)
    if missing_meshes:
        warnings.warn(f"{source}: mesh files not found or not loadable, that collision geometry skipped (the links "
                      f"keep their other shapes): {missing_meshes} (pass package_dirs, set ROS_PACKAGE_PATH, or "
                      "mesh_dirs)", ModelWarning, stacklevel=2)
    if mimics:
        warnings.warn(f"{source}: <mimic> is not modelled; joints {mimics} are independent DoFs", ModelWarning, stacklevel=2)
    return b.build(floating_base)
