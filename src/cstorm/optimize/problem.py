"""One motion segment as a static parameter optimization (DESIGN.md, "The method", item
5; the draft's "Generating Motions"): single shooting with quintic B-spline paths for
the active joints, or multiple shooting of the passive state (``shooting=K``).

Decision vector ``x``: the free control points of the active joints' splines (those not
fixed by the boundary conditions), joint by joint in model order (``problem.active``):
``x = free.T.ravel()`` with ``free`` of shape ``(n_free, n_active)``; units of the joints
(rad or m). Boundary conditions hold by construction: the start position and velocity
of every active joint equal ``q0``/``v0``; optional end position, velocity and
acceleration (``q_final_active``, ``v_final_active``, ``rest_end``).

Free initial state (``free_initial``, e.g. for periodic motions): ``x`` then continues
with offsets of the start state, ``x = [free.T.ravel(), dq0, dv0]``: ``dq0`` the tangent
offsets of the selected joints' start positions (joint by joint in model order, ``nv`` of
the joint each; ``q0_j (+) dq0_j``, plain addition for 1-DoF joints), ``dv0`` the offsets
of their start velocities (likewise). The active splines' start conditions and the
passive initial state both come from the offset start state (`MotionProblem.initial_state`),
so it is one consistent state; at ``x0`` the offsets are zero (the nominal ``q0``/``v0``).

Objective ``f(x) = sum of terminal costs + integral of running costs`` (see `costs`);
equality constraints ``c_eq(x) = 0``, inequalities ``c_in(x) >= 0`` (see
`constraints`).

Multiple shooting (``shooting=K > 1``): the grid's ``N`` steps split into ``K`` equal
intervals. The active joints still follow their splines over the whole horizon; the
passive state at the start of intervals ``1..K-1`` (the *nodes*) becomes decision
variables, appended last: ``x = [..., dq_1, w_1, ..., dq_{K-1}, w_{K-1}]`` with ``dq_i``
(n_vp,) the passive tangent offset of node ``i`` from the start configuration
(``q_i = data["q0"] (+) dq_i`` on the manifold; plain addition for 1-DoF joints) and
``w_i`` (n_vp,) its passive velocity, in the order of ``layout.vp_idx``. The ``K``
intervals are one vmapped rollout; continuity is an equality constraint of level 0 (label
``"shooting continuity"``, appended last to ``c_eq``): for each node, the tangent from
the node to the previous interval's end position and the velocity difference, ``2 n_vp``
values (rad or m, rad/s or m/s). The recorded trajectory stitches the intervals (node
``i``'s grid point is interval ``i-1``'s end); at a solution the defects vanish and it is
one continuous motion. Why: the terminal state of a balancing or falling robot is
exponentially sensitive to early controls; splitting the horizon bounds that growth
per interval, so the linearizations SLSQP builds on stay good. `shoot_nodes` fills the
node variables from a single-shooting rollout (what `solve` does with the default guess)
unless the problem has a ``node_guess``: a callable ``t -> (q (nq,), v (nv,))``, a
state-level guess (e.g. a body rotating from standing to inverted) whose passive parts
become the nodes at their times; the intervals then need not join at the guess, and the
optimizer closes the defects.

Everything the compiled functions read that is a number — the model's
arrays, ``q0``, ``v0``, the end values and the problem parameters — is a dynamic
argument (``problem.data(...)``), so continuation, sequences and design studies reuse
one compiled function.
"""

from __future__ import annotations

import hashlib
import os
import json
import math

import numpy as np
import jax
import jax.numpy as jnp

from ..contact import contact_forces
from ..dynamics.configuration import difference, integrate
from ..errors import ProblemError
from ..simulate import RolloutLayout, active_paths, rollout, time_grid, DERIVATIVES, INTEGRATORS
from ..simulate.steps import n_steps
from ..trajectory import QuinticBSpline
from . import costs as _costs
from . import constraints as _cons

__all__ = ["MotionProblem", "EvalContext", "require_x64"]


def require_x64(who: str):
    """Raise `ProblemError` unless JAX runs in float64."""
    if not jax.config.jax_enable_x64:
        raise ProblemError(
            f"{who} needs float64, but JAX is running in float32. Turn float64 on before creating arrays: "
            "`jax.config.update('jax_enable_x64', True)` at the top of your program, or set the environment "
            "variable JAX_ENABLE_X64=1 (the cstorm CLI and the test suite do this)."
        )


class EvalContext:
    """What cost and constraint terms see during an evaluation: ``model`` (possibly
    traced), ``layout`` (static `RolloutLayout`), ``params`` (dict of problem parameters,
    JAX arrays), ``problem`` (the `MotionProblem`)."""

    def __init__(self, problem, model, params):
        self.problem, self.model, self.layout, self.params = problem, model, problem.layout, params


def _as_active_vector(value, names_given, layout, what):
    """dict name->value or sequence (in the order the user listed the active joints) ->
    numpy (n_active,) in layout (model) order."""
    if isinstance(value, dict):
        bad = set(value) - set(layout.active_names)
        if bad:
            raise ProblemError(f"{what}: {sorted(bad)} are not active joints ({list(layout.active_names)})")
        missing = [n for n in layout.active_names if n not in value]
        if missing:
            raise ProblemError(f"{what}: missing values for active joints {missing}")
        return np.array([float(value[n]) for n in layout.active_names])
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (len(names_given),):
        raise ProblemError(f"{what}: expected {len(names_given)} values (one per active joint), got shape {arr.shape}")
    return np.array([arr[names_given.index(n)] for n in layout.active_names])


class _NoSteps(dict):
    """``samples["steps"]`` where the rollout recorded the constraint grid only: reading
    it is an error that says what to declare."""

    def __missing__(self, key):
        raise ProblemError(f"a constraint read samples['steps'][{key!r}] (every integration step), which is "
                           "recorded only when some constraint declares it: set `uses_steps = True` on the "
                           "constraint class (see cstorm.optimize.constraints.Constraint)")


def available_memory() -> int | None:
    """Bytes of memory this process can still get: ``MemAvailable`` of /proc/meminfo
    (Linux), else the physical memory; None where neither is known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):  # pragma: no cover
        return None


def memory_estimate(n_steps, n_ctrl, n_active, nq, nv, shooting=1) -> int:
    """A lower estimate of the bytes one values-and-Jacobian evaluation of a problem
    holds at once: the spline basis on the grid (six (N+1, n_ctrl) matrices), the
    trajectory (q, v, a, tau per step) and the state's tangent with respect to every
    decision variable at every step ((nq + nv) x n_vars per step), all float64."""
    N1 = int(n_steps) + 1
    n_vars = int(n_ctrl) * int(n_active) + 2 * nv * max(0, int(shooting) - 1)
    return 8 * N1 * (6 * int(n_ctrl) + nq + 3 * nv + (nq + nv) * max(1, n_vars))


def check_memory(n_steps, n_ctrl, n_active, nq, nv, shooting=1, name="motion"):
    """Raise `ProblemError` with the estimate (`memory_estimate`) when it exceeds the
    memory available (`available_memory`), before anything of that size is allocated."""
    need = memory_estimate(n_steps, n_ctrl, n_active, nq, nv, shooting)
    have = available_memory()
    if have is not None and need > have:
        raise ProblemError(f"MotionProblem {name!r}: {n_steps} steps with {n_ctrl} control points per active joint "
                           f"need at least {need / 2**30:.3g} GiB of memory, more than the {have / 2**30:.3g} GiB "
                           "available; shorten t_final, enlarge dt or use fewer control points (n_ctrl)")


class MotionProblem:
    """One motion segment.

    Args:
      model: the robot `Model`.
      active: names of the active joints (1-DoF; their paths are the decision variables).
        All other DoFs are passive (zero torque plus springs/dampers/limits and contact).
      t_final: duration (s). n_ctrl: control points per active joint (>= 6).
      dt: integration step (s); ``t_final`` must be a whole number ``N`` of steps.
      q0: (nq,) initial configuration. v0: (nv,) initial velocity (default zeros).
      env, contact: optional environment and `ContactParams` (see `cstorm.contact`); with
        them the rollout adds contact wrenches and records per-point contact data.
        ``contact_fn`` (alternative): a JAX callable ``(model, q, v) -> (f_ext (n_bodies,
        6), data)``.
      q_final_active: optional end positions of the active joints (dict name->value or a
        sequence in the order of ``active``), imposed by construction.
      v_final_active: optional end velocities (likewise). rest_end: end at rest
        (``v = a = 0``) for the active joints. rest_start: zero initial acceleration of the
        active joints (their initial velocity must then be 0 in ``v0``).
      costs: list of `costs.Cost` terms (default ``[TorqueSquared()]``).
      constraints: list of `constraints.Constraint` terms.
      params: dict of named problem parameters (floats or arrays) that terms refer to by
        name; continuation ramps them.
      integrator: ``"rk4"`` (default) or ``"euler"``.
      n_path_samples: about how many grid points path constraints are sampled at.
      initial_guess: None (active joints interpolate linearly from start to end value),
        an array ``x0``, or a dict ``name -> (t, values)`` of samples fitted by least
        squares (other joints: linear).
      jacobian: ``"auto"`` (forward mode when there are fewer variables than outputs),
        ``"fwd"`` or ``"rev"``.
      segment: steps per checkpointed scan segment (default ~sqrt(N)).
      derivatives: how the rollout is differentiated (`cstorm.simulate.rollout`):
        ``"analytic"`` (default: JAX differentiates the scan, with the analytic
        hybrid-dynamics Jacobians inside), ``"parallel"`` (the step Jacobians of all
        steps at once, then a linear recurrence, `cstorm.simulate.tangents`; with
        ``"fwd"`` the values come from the same pass, and with `record_grid_only` only
        the constraint grid's points are differentiated: one values+Jacobian evaluation
        of the tumbler's segments 2-4x faster (start 145 against 289 ms, roll 72
        against 231 ms), its compile ~33 against ~18 s, so it pays off over solves of
        more than ~100 evaluations) or ``"autodiff"`` (through everything; the
        reference). Same values; derivatives equal to rounding.
      contact_jacobians: how the contact forces of ``env``/``contact`` are differentiated
        (`cstorm.contact.contact_forces`'s ``jacobians``): ``"analytic"`` (default; the
        ground contact points' derivative rule) or ``"autodiff"``. Same values;
        derivatives equal to about 1e-14, which can still send SLSQP down another path
        through a sensitive plan (the tumbler's, see `cstorm.examples.tumbler`).
      q_bound, v_bound: divergence bounds of the rollout.
      name: a label for displays and files.
      free_initial: optional dict ``joint name -> "q" | "v" | "qv"``: these parts of the
        joints' initial state become decision variables, as offsets from ``q0``/``v0``
        appended to ``x`` (see the module docstring; zero in the default initial guess).
        Use with `constraints.Periodic` for periodic motions (a gait cycle), which single
        shooting from a fixed start cannot be at nonzero speed. Active joints' start
        position and velocity follow the offset state (their splines start there); with
        ``rest_start=True`` an active joint's velocity cannot be free. `solve` takes no
        variable bounds: bound the start state, where wanted, by a constraint on the
        trajectory's first sample (``samples["q"][0]`` in a `constraints.Constraint`).
      shooting: number of shooting intervals ``K`` (default 1: single shooting); ``N`` must
        be a multiple of ``K`` and every joint wholly active or wholly passive (see the
        module docstring).
      node_guess: optional callable ``t -> (q (nq,), v (nv,))``: the nodes of the default
        guess (multiple shooting; default: the guess's own rollout).
      success_criteria: optional problem-specific success criteria, checked after a
        solve by `cstorm.report.evaluate_criteria` (and reported in ``summary.json`` by
        ``cstorm solve``): a callable ``(solution) -> {name: {"value", "tol", "ok"}}`` or
        a list of criterion specs (dicts, see `cstorm.report`). Also settable as an
        attribute after construction.

    Attributes: ``model, layout, spline, n_steps, dt, t (grid), n_vars, n_eq, n_ineq,
    term_slices`` (each constraint term's rows of ``c_eq`` / ``c_in``), ``x0,
    solve_options`` (defaults merged into `solve`'s options, e.g. a continuation
    schedule shipped with an example).
    """

    def __init__(self, model, active, t_final, n_ctrl, dt, q0, v0=None, *, env=None, contact=None, contact_fn=None,
                 q_final_active=None, v_final_active=None, rest_end=False, rest_start=False, costs=None,
                 constraints=None, params=None, integrator="rk4", n_path_samples=50, initial_guess=None,
                 jacobian="auto", segment=None, q_bound=1e4, v_bound=1e4, name="motion", success_criteria=None,
                 free_initial=None, shooting=1, node_guess=None, derivatives="analytic",
                 contact_jacobians="analytic"):
        require_x64("MotionProblem")
        self.model = model
        self.name = str(name)
        self.success_criteria = success_criteria
        names_given = tuple([active] if isinstance(active, str) else active)
        if not names_given:
            raise ProblemError("MotionProblem: at least one active joint is needed (the decision variables are "
                               "the active joints' spline control points)")
        self.layout = RolloutLayout.make(model, names_given)
        self.active = self.layout.active_names
        self._names_given = names_given
        if integrator not in INTEGRATORS:
            raise ProblemError(f"MotionProblem: integrator must be one of {INTEGRATORS}, got {integrator!r}")
        self.integrator = integrator
        self.t_final = float(t_final)
        if isinstance(n_ctrl, bool) or not isinstance(n_ctrl, (int, np.integer, float, np.floating)) or \
                not float(n_ctrl).is_integer():
            raise ProblemError(f"MotionProblem: n_ctrl (control points per active joint) must be a whole number, "
                               f"got {n_ctrl!r}")
        check_memory(n_steps(self.t_final, dt), int(n_ctrl), self.layout.n_active, model.nq, model.nv,
                     int(shooting) if isinstance(shooting, (int, np.integer)) else 1, name)
        self.spline = QuinticBSpline(int(n_ctrl), self.t_final)
        self.n_steps, self.dt, self.t = time_grid(self.t_final, dt)
        self.q0 = np.asarray(q0, dtype=float).reshape(-1)
        if self.q0.shape != (model.nq,):
            raise ProblemError(f"MotionProblem: q0 must have shape ({model.nq},), got {self.q0.shape}")
        self.v0 = np.zeros(model.nv) if v0 is None else np.asarray(v0, dtype=float).reshape(-1)
        if self.v0.shape != (model.nv,):
            raise ProblemError(f"MotionProblem: v0 must have shape ({model.nv},), got {self.v0.shape}")
        if not (np.all(np.isfinite(self.q0)) and np.all(np.isfinite(self.v0))):
            raise ProblemError("MotionProblem: q0 and v0 must be finite")
        self.qa_final = None if q_final_active is None else _as_active_vector(
            q_final_active, names_given, self.layout, "q_final_active")
        self.va_final = None if v_final_active is None else _as_active_vector(
            v_final_active, names_given, self.layout, "v_final_active")
        if rest_end and self.va_final is not None:
            raise ProblemError("MotionProblem: rest_end=True already sets the final active velocities to 0")
        self.rest_end, self.rest_start = bool(rest_end), bool(rest_start)
        if self.rest_start and np.any(self.v0[list(self.layout.va_idx)] != 0):
            raise ProblemError("MotionProblem: rest_start=True needs zero initial velocity of the active joints")
        self.free_initial = self._parse_free_initial(free_initial)
        self.shooting = int(shooting)
        if self.shooting < 1 or self.shooting != shooting:
            raise ProblemError(f"MotionProblem: shooting must be a positive integer, got {shooting!r}")
        if self.n_steps % self.shooting:
            raise ProblemError(f"MotionProblem: shooting={self.shooting} must divide the number of steps "
                               f"N = {self.n_steps} (t_final / dt)")
        if self.shooting > 1:
            vp = set(self.layout.vp_idx)
            for i, jn in enumerate(model.joint_names):
                vs = set(range(model.v_starts[i], model.v_starts[i] + model.joints[i].nv))
                if vs & vp and not vs <= vp:
                    raise ProblemError(f"MotionProblem: shooting={self.shooting} needs every joint wholly active or "
                                       f"wholly passive; joint {jn!r} is partly active")
        self.n_vp = len(self.layout.vp_idx)
        self.n_node_vars = 2 * self.n_vp * (self.shooting - 1)
        if node_guess is not None and not callable(node_guess):
            raise ProblemError("MotionProblem: node_guess must be a callable t -> (q (nq,), v (nv,))")
        self.node_guess = node_guess
        self.params = {k: np.asarray(v, dtype=float) for k, v in (params or {}).items()}
        self.costs = list(costs) if costs is not None else [_costs.TorqueSquared()]
        self.constraints = list(constraints or [])
        self.env, self.contact = env, contact  # before the terms' check(), which may read them
        # constraint grid (before the terms' check(), which may read it): every `stride`-th step, both ends included
        stride = max(1, self.n_steps // max(1, int(n_path_samples)))
        idx = np.arange(0, self.n_steps + 1, stride)
        if idx[-1] != self.n_steps:
            idx = np.append(idx, self.n_steps)
        self.sample_idx = idx
        for c in self.costs:
            if not isinstance(c, _costs.Cost):
                raise ProblemError(f"MotionProblem: costs must be cost terms (cstorm.optimize.costs), got {c!r}")
            c.check(self)
        for c in self.constraints:
            if not isinstance(c, _cons.Constraint):
                raise ProblemError(
                    f"MotionProblem: constraints must be constraint terms (cstorm.optimize.constraints), got {c!r}")
            c.check(self)
        if jacobian not in ("auto", "fwd", "rev"):
            raise ProblemError(f"MotionProblem: jacobian must be 'auto', 'fwd' or 'rev', got {jacobian!r}")
        self.jacobian_mode = jacobian
        if derivatives not in DERIVATIVES:
            raise ProblemError(f"MotionProblem: derivatives must be one of {DERIVATIVES}, got {derivatives!r}")
        self.derivatives = derivatives
        #: `evaluate` records the trajectory on the constraint grid only where it can (see
        #: `recorded_rows`; with ``derivatives="parallel"`` the grid-point Jacobians of ~40
        #: points instead of every step, ~30 % less time per values+Jacobian on the
        #: tumbler). False: every step; values and Jacobians equal to
        #: rounding (the batched Jacobians' rounding depends on the batch)
        self.record_grid_only = True
        self.segment = segment
        self.q_bound, self.v_bound = float(q_bound), float(v_bound)
        if contact_jacobians not in ("analytic", "autodiff"):
            raise ProblemError(f"MotionProblem: contact_jacobians must be 'analytic' or 'autodiff', got "
                               f"{contact_jacobians!r}")
        self.contact_jacobians = contact_jacobians
        self._contact_fn = self._make_contact_fn(env, contact, contact_fn)
        # boundary conditions (static pattern) and sizes
        self._bc_pattern = dict(q0=True, v0=True, a0=self.rest_start, q1=self.qa_final is not None,
                                v1=self.va_final is not None or self.rest_end, a1=self.rest_end)
        key = {k: 0.0 for k, on in self._bc_pattern.items() if on}
        self.n_free = self.spline.n_free(**key)
        if self.n_free < 1:
            raise ProblemError(f"MotionProblem: n_ctrl={n_ctrl} leaves no free control points after the boundary "
                               "conditions; increase n_ctrl")
        self.n_spline_vars = self.n_free * self.layout.n_active
        self.n_vars = self.n_spline_vars + len(self._fi_dq) + len(self._fi_dv) + self.n_node_vars
        self._basis = {k: jnp.asarray(v) for k, v in active_paths(self.spline, self.n_steps, integrator).items()}
        self.solve_options = {}
        self._compiled = {}
        #: per constraint term, in order, then the shooting continuity defects (with
        #: ``shooting > 1``): ``(kind, rows, stage, label)``, ``kind`` "eq" or "ineq", ``rows``
        #: the term's slice of ``c_eq`` or ``c_in``, ``stage`` its constraint level
        self.term_slices = self._slices()
        self.n_eq = sum(sl.stop - sl.start for kind, sl, _, _ in self.term_slices if kind == "eq")
        self.n_ineq = sum(sl.stop - sl.start for kind, sl, _, _ in self.term_slices if kind == "ineq")
        self.x0 = self.initial_x(initial_guess)

    # ------------------------------------------------------------------ free initial state
    def _parse_free_initial(self, spec):
        """Validate ``free_initial``; set the static index maps ``_fi_joints`` ((joint index,
        q part?, v part?) in model order), ``_fi_dq`` / ``_fi_dv`` (v indices of the q / v
        offsets, in x order). Returns the normalized dict (or None)."""
        self._fi_joints, self._fi_dq, self._fi_dv = (), (), ()
        if spec is None:
            return None
        if not isinstance(spec, dict):
            raise ProblemError(f"MotionProblem: free_initial must be a dict joint name -> 'q' | 'v' | 'qv', "
                               f"got {type(spec).__name__}")
        m = self.model
        out = {}
        for name, part in spec.items():
            if name not in m.joint_names:
                raise ProblemError(f"MotionProblem: free_initial names {name!r}, which is not a joint; joints are "
                                   f"{list(m.joint_names)}")
            if part not in ("q", "v", "qv"):
                raise ProblemError(f"MotionProblem: free_initial[{name!r}] must be 'q', 'v' or 'qv', got {part!r}")
            if self.rest_start and "v" in part and name in self.layout.active_names:
                raise ProblemError(f"MotionProblem: free_initial[{name!r}] frees the velocity of an active joint, "
                                   "but rest_start=True fixes it at 0")
            out[name] = part
        joints, dq, dv = [], [], []
        for i, name in enumerate(m.joint_names):
            if name in out:
                part = out[name]
                joints.append((i, "q" in part, "v" in part))
                vs = list(range(m.v_starts[i], m.v_starts[i] + m.joints[i].nv))
                dq += vs if "q" in part else []
        for i, _, has_v in joints:
            if has_v:
                dv += list(range(m.v_starts[i], m.v_starts[i] + m.joints[i].nv))
        self._fi_joints, self._fi_dq, self._fi_dv = tuple(joints), tuple(dq), tuple(dv)
        return out

    def initial_state(self, x, data):
        """Pure JAX: the start state ``(q0 (nq,), v0 (nv,))`` at decision vector ``x``:
        ``data["q0"]``/``data["v0"]`` with the free-initial offsets of ``x`` applied (see
        the module docstring); the nominal state when nothing is free."""
        q0, v0 = data["q0"], data["v0"]
        if not self._fi_joints:
            return q0, v0
        m = self.model
        n0 = self.n_spline_vars
        dq = x[n0: n0 + len(self._fi_dq)]
        dv = x[n0 + len(self._fi_dq): n0 + len(self._fi_dq) + len(self._fi_dv)]
        k = 0
        for i, has_q, _ in self._fi_joints:
            if has_q:
                j, qs, nv = m.joints[i], m.q_starts[i], m.joints[i].nv
                q0 = q0.at[qs: qs + j.nq].set(j.integrate(q0[qs: qs + j.nq], dq[k: k + nv]))
                k += nv
        if len(self._fi_dv):
            v0 = v0.at[np.array(self._fi_dv, int)].add(dv)
        return q0, v0

    # ------------------------------------------------------------------ data and contact
    def _make_contact_fn(self, env, contact, contact_fn):
        """``(model, env, contact_params, q, v) -> (f_ext, data)`` or None."""
        if contact_fn is not None:
            if env is not None:
                raise ProblemError("MotionProblem: give env/contact or contact_fn, not both")
            return lambda model, env_, params_, q, v: contact_fn(model, q, v)
        if env is None:
            return None
        if contact is None:
            raise ProblemError("MotionProblem: env given without contact parameters (contact=cs.ContactParams(...))")
        def fn(model, env_, params_, q, v):
            out = contact_forces(model, env_, params_, q, v, jacobians=self.contact_jacobians)
            return out.f_ext, out
        return fn

    def data(self, params=None, q0=None, v0=None, model=None):
        """The dynamic inputs of the compiled functions (a pytree): the model, start
        state, active end values and problem parameters (``params`` overrides
        entries)."""
        p = dict(self.params)
        for k, v in (params or {}).items():
            if k not in p:
                raise ProblemError(f"{self.name}: unknown problem parameter {k!r}; parameters are {sorted(p)}")
            p[k] = np.asarray(v, dtype=float)
        d = dict(model=self.model if model is None else model,
                 q0=jnp.asarray(self.q0 if q0 is None else q0, dtype=jnp.float64),
                 v0=jnp.asarray(self.v0 if v0 is None else v0, dtype=jnp.float64),
                 params={k: jnp.asarray(v) for k, v in p.items()}, basis=self._basis)
        if self.env is not None:
            d["env"], d["contact"] = self.env, self.contact
        if self.qa_final is not None:
            d["qa_final"] = jnp.asarray(self.qa_final)
        if self.va_final is not None:
            d["va_final"] = jnp.asarray(self.va_final)
        return d

    # ------------------------------------------------------------------ evaluation
    def ctrl(self, x, data):
        """Control points (n_ctrl, n_active) of the active paths (layout order)."""
        na = self.layout.n_active
        free = jnp.reshape(x[:self.n_spline_vars], (na, self.n_free)).T
        ia, iv = np.array(self.layout.qa_idx, int), np.array(self.layout.va_idx, int)
        q0, v0 = self.initial_state(x, data)
        bc = dict(q0=q0[ia], v0=v0[iv])
        if self.rest_start:
            bc["a0"] = jnp.zeros(na)
        if self.qa_final is not None:
            bc["q1"] = data["qa_final"]
        if self.rest_end:
            bc["rest_end"] = True
        elif self.va_final is not None:
            bc["v1"] = data["va_final"]
        return self.spline.expand(free, **bc)

    def _rollout(self, x, data, record=True, rows=None):
        model = data["model"]
        ctrl = self.ctrl(x, data)
        B = data["basis"]
        paths = dict(qa=B["B0"] @ ctrl, va=B["B1"] @ ctrl, aa=B["B2"] @ ctrl)
        if self.integrator == "rk4":
            paths.update(qm=B["M0"] @ ctrl, vm=B["M1"] @ ctrl, am=B["M2"] @ ctrl)
        ctx = EvalContext(self, model, data["params"])
        running = [c for c in self.costs if type(c).running is not _costs.Cost.running]

        def cost_fn(t, q, v, a, tau, contact, params):
            out = jnp.zeros((), q.dtype)
            for c in running:
                r = c.running(ctx, t, q, v, a, tau, contact)
                if r is not None:
                    out = out + r
            return out

        cfn = None
        if self._contact_fn is not None:
            cfn = lambda q, v: self._contact_fn(model, data.get("env"), data.get("contact"), q, v)
        q0, v0 = self.initial_state(x, data)
        kw = dict(integrator=self.integrator, contact_fn=cfn, cost_fn=cost_fn if running else None,
                  params=data["params"], segment=self.segment, q_bound=self.q_bound, v_bound=self.v_bound,
                  record=record, derivatives=self.derivatives)
        if self.shooting == 1:
            kw["record_rows"] = rows
            return rollout(model, self.layout, q0, v0, paths, self.dt, self.n_steps, **kw), ctx
        return self._multiple_shooting(x, data, q0, v0, paths, kw), ctx

    def _node_states(self, x, data):
        """Node configurations ``(K-1, nq)`` and velocities ``(K-1, nv)`` at ``x`` (the
        active entries are placeholders: the rollout takes them from the paths)."""
        model, vp = data["model"], np.array(self.layout.vp_idx, int)
        z = jnp.reshape(x[self.n_vars - self.n_node_vars:], (self.shooting - 1, 2, self.n_vp))
        dq = jnp.zeros((self.shooting - 1, model.nv), x.dtype).at[:, vp].set(z[:, 0])
        qs = jax.vmap(lambda d: integrate(model, data["q0"], d))(dq)
        vs = jnp.broadcast_to(data["v0"], (self.shooting - 1, model.nv)).at[:, vp].set(z[:, 1])
        return qs, vs

    def _multiple_shooting(self, x, data, q0, v0, paths, kw):
        """The ``K`` intervals as one vmapped rollout, stitched (see the module docstring);
        adds ``defects`` (2 n_vp (K-1),) to the result."""
        model, K = data["model"], self.shooting
        n = self.n_steps // K
        qs, vs = self._node_states(x, data)
        Q0, V0 = jnp.concatenate([q0[None], qs]), jnp.concatenate([v0[None], vs])
        grid = np.arange(K)[:, None] * n + np.arange(n + 1)[None, :]  # (K, n+1), shared ends
        pk = {k: (y[grid] if k in ("qa", "va", "aa") else y[grid[:, :n]]) for k, y in paths.items()}
        t0 = jnp.asarray(np.arange(K) * n * self.dt)
        res = jax.vmap(lambda a, b, c, d: rollout(model, self.layout, a, b, c, self.dt, n, t0=d, **kw))(Q0, V0, pk, t0)
        vp = np.array(self.layout.vp_idx, int)
        dq = jax.vmap(lambda qn, qe: difference(model, qn, qe)[vp])(qs, res["qT"][:-1])
        dv = res["vT"][:-1, vp] - vs[:, vp]
        bad = res["diverged"]
        first = jnp.argmax(bad)
        out = dict(J=jnp.sum(res["J"]), diverged=jnp.any(bad),
                   div_step=jnp.where(jnp.any(bad), first * n + res["div_step"][first], -1),
                   div_dof=jnp.where(jnp.any(bad), res["div_dof"][first], -1),
                   div_reason=jnp.where(jnp.any(bad), res["div_reason"][first], 0),
                   qT=res["qT"][-1], vT=res["vT"][-1],
                   defects=jnp.concatenate([dq, dv], axis=1).ravel())
        if kw["record"]:
            stitch = lambda y: jnp.concatenate([y[0], jnp.reshape(y[1:, 1:], (-1,) + y.shape[2:])])
            tr = res["traj"]
            out["traj"] = {k: (None if tr.get(k) is None else jax.tree_util.tree_map(stitch, tr[k])) for k in tr}
        return out

    def variable_groups(self) -> dict:
        """Index arrays into ``x`` by kind: ``"spline"`` (free control points),
        ``"initial_q"``, ``"initial_v"`` (free-initial offsets), ``"node_q"``, ``"node_v"``
        (multiple-shooting nodes' positions and velocities); e.g. to build per-variable
        bounds or trust radii."""
        n0 = self.n_spline_vars
        n1 = n0 + len(self._fi_dq)
        n2 = n1 + len(self._fi_dv)
        nodes = np.arange(n2, self.n_vars).reshape(max(self.shooting - 1, 0), 2, self.n_vp)
        return dict(spline=np.arange(n0), initial_q=np.arange(n0, n1), initial_v=np.arange(n1, n2),
                    node_q=nodes[:, 0].ravel(), node_v=nodes[:, 1].ravel())

    def shoot_nodes(self, x, data=None):
        """``x`` (n_vars,) with its node variables replaced by the states of a
        single-shooting rollout of its controls (the intervals then join continuously):
        ``K - 1`` evaluations of the compiled trajectory; or, when the problem has a
        ``node_guess``, by its states at the node times. ``x`` unchanged when
        ``shooting == 1``. Returns a numpy array."""
        x = np.array(x, dtype=float).reshape(-1)
        if self.shooting == 1:
            return x
        data = self.data() if data is None else data
        traj, n = self.compiled("trajectory"), self.n_steps // self.shooting
        vp = np.array(self.layout.vp_idx, int)
        n0 = self.n_vars - self.n_node_vars
        for i in range(1, self.shooting):
            if self.node_guess is None:
                tr = traj(jnp.asarray(x), data)
                q, v = tr["q"][i * n], tr["v"][i * n]
            else:
                q, v = (np.asarray(a, float).reshape(-1) for a in self.node_guess(float(self.t[i * n])))
                if q.shape != (self.model.nq,) or v.shape != (self.model.nv,):
                    raise ProblemError(f"{self.name}: node_guess(t) must return q ({self.model.nq},) and v "
                                       f"({self.model.nv},), got {q.shape} and {v.shape}")
            k = n0 + 2 * self.n_vp * (i - 1)
            x[k: k + self.n_vp] = np.asarray(difference(data["model"], data["q0"], q))[vp]
            x[k + self.n_vp: k + 2 * self.n_vp] = np.asarray(v)[vp]
        return x

    def evaluate(self, x, data):
        """Pure JAX: dict ``f`` (scalar objective), ``c_eq`` (n_eq,), ``c_in`` (n_ineq,),
        ``diverged`` (bool) at decision vector ``x`` (n_vars,)."""
        rows = self.recorded_rows()
        res, ctx = self._rollout(x, data, record=True, rows=rows)
        tr = res["traj"]
        end = dict(q=tr["q"][-1], v=tr["v"][-1], a=tr["a"][-1], tau=tr["tau"][-1])
        f = res["J"]
        for c in self.costs:
            if type(c).terminal is not _costs.Cost.terminal:
                val = c.terminal(ctx, end)
                if val is not None:
                    f = f + val
        samples = self._samples(tr, recorded=rows is not None)
        eq, inq = [], []
        for c in self.constraints:
            val = jnp.atleast_1d(c.values(ctx, end, samples)).ravel()
            (eq if c.kind == "eq" else inq).append(val)
        if self.shooting > 1:
            eq.append(res["defects"])
        z = jnp.zeros(0, f.dtype)
        return dict(f=f, c_eq=jnp.concatenate(eq) if eq else z, c_in=jnp.concatenate(inq) if inq else z,
                    diverged=res["diverged"])

    def trajectory(self, x, data):
        """Pure JAX: the full rollout at ``x``: dict ``t, q, v, a, tau, contact`` on the
        grid plus ``J`` and the divergence record (see `cstorm.simulate.rollout`)."""
        res, _ = self._rollout(x, data, record=True)
        out = dict(res["traj"])
        out.update({k: res[k] for k in ("J", "diverged", "div_step", "div_dof", "div_reason")})
        out["ctrl"] = self.ctrl(x, data)
        return out

    def _slices(self):
        """Per constraint term: (kind, slice into c_eq or c_in, stage, label)."""
        out = []
        d = self.data()
        n = {"eq": 0, "ineq": 0}
        sizes = jax.eval_shape(lambda x, dd: self._term_sizes(x, dd), jnp.zeros(self.n_vars), d)
        for c, s in zip(self.constraints, sizes):
            k = s.shape[0]
            out.append((c.kind, slice(n[c.kind], n[c.kind] + k), c.stage, c.label()))
            n[c.kind] += k
        if self.shooting > 1:
            k = 2 * self.n_vp * (self.shooting - 1)
            out.append(("eq", slice(n["eq"], n["eq"] + k), 0, "shooting continuity"))
        return out

    def _term_sizes(self, x, data):
        res, ctx = self._rollout(x, data, record=True)
        tr = res["traj"]
        end = dict(q=tr["q"][-1], v=tr["v"][-1], a=tr["a"][-1], tau=tr["tau"][-1])
        return [jnp.atleast_1d(c.values(ctx, end, self._samples(tr))).ravel() for c in self.constraints]

    def recorded_rows(self):
        """The grid points whose recorded data `evaluate` reads, as a tuple of step
        indices into the grid ``t``: the constraint grid (`sample_idx`, both ends
        included); or None (every step) when a constraint reads ``samples["steps"]`` (its
        ``uses_steps``), with multiple shooting, with ``record_grid_only`` False, or unless
        ``derivatives="parallel"`` (only then are just these points' Jacobians evaluated;
        the other modes differentiate every step anyway and keep their verified paths)."""
        if (self.shooting > 1 or not self.record_grid_only or self.derivatives != "parallel"
                or any(getattr(c, "uses_steps", True) for c in self.constraints)):
            return None
        return tuple(int(i) for i in self.sample_idx)

    def _samples(self, tr, recorded=False):
        """The trajectory on the constraint grid: dict ``t (S,)``, ``q, v, a, tau`` and,
        with contact, ``contact`` (the per-point contact data at the samples); ``steps``:
        the same fields (no contact) on every integration step, ``(N+1, ...)``, for terms
        that aggregate over all steps (``TorqueLimits(dense=True)``; a term that reads
        them declares ``uses_steps = True``). ``recorded``: ``tr`` holds the constraint
        grid's points only (`recorded_rows`), and ``steps`` is not available."""
        idx = self.sample_idx
        at = (lambda y: y) if recorded else (lambda y: y[idx])
        steps = _NoSteps() if recorded else dict(t=jnp.asarray(self.t), q=tr["q"], v=tr["v"], a=tr["a"], tau=tr["tau"])
        samples = dict(t=jnp.asarray(self.t[idx]), q=at(tr["q"]), v=at(tr["v"]), a=at(tr["a"]), tau=at(tr["tau"]),
                       steps=steps)
        if tr.get("contact") is not None:
            samples["contact"] = jax.tree_util.tree_map(at, tr["contact"])
        return samples

    def constraint_masks(self, level=None):
        """Boolean masks over ``c_eq`` and ``c_in``: the constraints enforced at stage
        ``level`` (terms with ``stage <= level``; None: all)."""
        me, mi = np.zeros(self.n_eq, bool), np.zeros(self.n_ineq, bool)
        for kind, sl, stage, _ in self.term_slices:
            if level is None or stage <= level:
                (me if kind == "eq" else mi)[sl] = True
        return me, mi

    @property
    def n_levels(self) -> int:
        """Number of constraint stages (1 + the largest ``stage`` of any term)."""
        return 1 + max([c.stage for c in self.constraints], default=0)

    # ------------------------------------------------------------------ compiled functions
    def compiled(self, which="fun_jac"):
        """Jitted functions of ``(x, data)`` (compiled on first use, once per problem):
        ``"fun_jac"`` -> (f, c_eq, c_in, diverged, grad f, J_eq, J_in); ``"fun"`` -> (f,
        c_eq, c_in, diverged); ``"fun_batch"`` -> ``"fun"`` of a batch ``x`` (B, n_vars),
        each output with a leading axis B; ``"trajectory"`` -> `trajectory`."""
        if which not in self._compiled:
            if which == "fun_jac":
                self._compiled[which] = jax.jit(self.fun_jac)
            elif which == "fun":
                self._compiled[which] = jax.jit(
                    lambda x, d: (lambda r: (r["f"], r["c_eq"], r["c_in"], r["diverged"]))(self.evaluate(x, d)))
            elif which == "fun_batch":
                one = lambda x, d: (lambda r: (r["f"], r["c_eq"], r["c_in"], r["diverged"]))(self.evaluate(x, d))
                self._compiled[which] = jax.jit(jax.vmap(one, in_axes=(0, None)))
            elif which == "trajectory":
                self._compiled[which] = jax.jit(self.trajectory)
            else:
                raise ValueError(which)
        return self._compiled[which]

    def cached(self, key, build):
        """The object this problem caches under ``key`` (any hashable), made by ``build()``
        on first use: compiled functions that belong to one problem (a solver's
        transcription, its helpers). `compiled` keeps its functions in the same cache;
        copies of a problem (``copy.copy``) share it."""
        if key not in self._compiled:
            self._compiled[key] = build()
        return self._compiled[key]

    @property
    def contact_fn(self):
        """The contact model as a pure function ``(model, env, contact_params, q, v) ->
        (f_ext, contact data)`` (``f_ext`` (n_bodies, 6), `cstorm.contact_forces`'
        convention), ``env`` and ``contact_params`` taken from `data`; None for a problem
        without contact."""
        return self._contact_fn

    @property
    def basis(self) -> dict:
        """The active paths' spline basis on the integration grid
        (`cstorm.simulate.active_paths`), JAX arrays: ``B0, B1, B2`` ((N+1, n_ctrl):
        position, velocity, acceleration at the grid points) and, for RK4, ``M0, M1, M2``
        ((N, n_ctrl) at the half steps); ``q_a = B0 @ ctrl`` with ``ctrl`` (n_ctrl,
        n_active) from `ctrl`."""
        return self._basis

    def fun_jac(self, x, data):
        """Pure JAX: values and first derivatives at the decision vector ``x`` (n_vars,):
        ``(f, c_eq (n_eq,), c_in (n_ineq,), diverged, grad f (n_vars,), J_eq (n_eq,
        n_vars), J_in (n_ineq, n_vars))``, the values those of `evaluate`. Forward or
        reverse mode by the problem's ``jacobian`` setting (``"auto"``: forward when
        n_vars <= max(64, 4 (1 + n_eq + n_ineq))). ``compiled("fun_jac")`` is its jitted
        form."""
        def y(xx):
            r = self.evaluate(xx, data)
            return jnp.concatenate([r["f"][None], r["c_eq"], r["c_in"]]), r["diverged"]

        m = 1 + self.n_eq + self.n_ineq
        n = self.n_vars
        mode = self.jacobian_mode
        if mode == "auto":
            # forward mode: one batched pass of n tangents; reverse: m cotangents, each a
            # recomputing backward pass through the checkpointed scan (several times dearer)
            mode = "fwd" if n <= max(64, 4 * m) else "rev"
        if mode == "fwd":
            # the primal runs separately from the batched tangents, on purpose: fusing
            # them (one vmapped jvp with has_aux, ~10 % faster) moves the Jacobians by
            # ~1e-15, and luxo's solve plan then fails: re-check its solve
            # test before changing this
            eye = jnp.eye(n, dtype=x.dtype)
            if self.derivatives == "parallel":
                # the time-parallel rule evaluates the primal rollout once inside the JVP and
                # its tangents from that (`cstorm.simulate.tangents`): take the values from
                # there instead of a second rollout (the same code: the values and the
                # Jacobians are bitwise those of the separate primal; ~20 % faster)
                def jvp(t):
                    v_, t_, d_ = jax.jvp(y, (x,), (t,), has_aux=True)
                    return v_, d_, t_

                val, div, Jt = jax.vmap(jvp, out_axes=(None, None, 0))(eye)  # Jt (n, m)
            else:
                val, div = y(x)
                jvp = lambda t: jax.jvp(lambda xx: y(xx)[0], (x,), (t,))[1]
                Jt = jax.vmap(jvp)(eye)  # (n, m)
            J = Jt.T
        else:
            val, vjp, div = jax.vjp(y, x, has_aux=True)
            J = jax.vmap(lambda ct: vjp(ct)[0])(jnp.eye(m, dtype=x.dtype))  # (m, n)
        ne = self.n_eq
        return (val[0], val[1:1 + ne], val[1 + ne:], div, J[0], J[1:1 + ne], J[1 + ne:])

    # ------------------------------------------------------------------ initial guess
    def initial_x(self, guess):
        """The decision vector (n_vars,) of an initial guess given as ``MotionProblem``'s
        ``initial_guess`` takes it: None (each active joint linear from its start to its
        end value), ``{joint: (t, values)}`` samples (s; rad or m) that each active
        joint's spline is fitted to under the problem's boundary conditions, or a vector
        (n_vars,) returned as it is. Offsets of free initial states and shooting nodes are
        0. Raises `ProblemError` for a wrong shape or a non-active joint."""
        na, nf = self.layout.n_active, self.n_free
        if guess is not None and not isinstance(guess, dict):
            x = np.asarray(guess, dtype=float).reshape(-1)
            if x.shape != (self.n_vars,):
                raise ProblemError(f"{self.name}: initial_guess must have shape ({self.n_vars},), got {x.shape}")
            return x
        guess = guess or {}
        bad = set(guess) - set(self.active)
        if bad:
            raise ProblemError(f"{self.name}: initial_guess names non-active joints {sorted(bad)}")
        qa0 = self.q0[list(self.layout.qa_idx)]
        va0 = self.v0[list(self.layout.va_idx)]
        qa1 = self.qa_final if self.qa_final is not None else qa0
        cols = []
        for k, nme in enumerate(self.active):
            bc = dict(q0=qa0[k], v0=va0[k])
            if self.rest_start:
                bc["a0"] = 0.0
            if self.qa_final is not None:
                bc["q1"] = self.qa_final[k]
            if self.rest_end:
                bc["rest_end"] = True
            elif self.va_final is not None:
                bc["v1"] = self.va_final[k]
            if nme in guess:
                ts, vals = guess[nme]
            else:
                ts = np.linspace(0, self.t_final, 2 * self.spline.n_ctrl)
                vals = qa0[k] + (qa1[k] - qa0[k]) * ts / self.t_final
            ctrl = self.spline.fit(np.asarray(ts, float), np.asarray(vals, float), **bc)
            cols.append(np.asarray(self.spline.reduce(ctrl, **{k2: v for k2, v in bc.items()})))
        x = np.stack(cols, axis=1).T.reshape(-1) if na else np.zeros(0)
        return np.concatenate([x, np.zeros(self.n_vars - self.n_spline_vars)])  # offsets and nodes: 0

    # ------------------------------------------------------------------ description
    def describe(self) -> dict:
        """JSON-able description (for provenance and hashing)."""
        return dict(name=self.name, model=self.model.name, active=list(self.active), t_final=self.t_final,
                    n_ctrl=self.spline.n_ctrl, dt=self.dt, n_steps=self.n_steps, integrator=self.integrator,
                    q0=self.q0.tolist(), v0=self.v0.tolist(),
                    q_final_active=None if self.qa_final is None else self.qa_final.tolist(),
                    v_final_active=None if self.va_final is None else self.va_final.tolist(),
                    rest_end=self.rest_end, rest_start=self.rest_start,
                    params={k: np.asarray(v).tolist() for k, v in self.params.items()},
                    costs=[c.describe() for c in self.costs], constraints=[c.describe() for c in self.constraints],
                    n_vars=self.n_vars, n_eq=self.n_eq, n_ineq=self.n_ineq,
                    **({} if self.free_initial is None else {"free_initial": dict(self.free_initial)}),
                    **({} if self.shooting == 1 else {"shooting": self.shooting}))

    def hash(self) -> str:
        """A short hash of `describe()` (which problem a checkpoint or solution is for)."""
        return hashlib.sha256(json.dumps(self.describe(), sort_keys=True, default=str).encode()).hexdigest()[:16]

    def __repr__(self):
        return (f"MotionProblem({self.name!r}, model={self.model.name!r}, active={list(self.active)}, "
                f"t_final={self.t_final}, n_ctrl={self.spline.n_ctrl}, dt={self.dt:g}, n_vars={self.n_vars}, "
                f"n_eq={self.n_eq}, n_ineq={self.n_ineq}" + (f", shooting={self.shooting})" if self.shooting > 1 else ")"))
