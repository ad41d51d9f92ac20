"""Trajectory benchmark: one cost + gradient of a rollout w.r.t. its motion parameters,
cstorm's exact JAX gradient against MuJoCo finite differences, on the same robot,
horizon, time step, integrator and number of parameters (issue 4's targets).

    python -m benchmarks.trajectory [--quick] [--json]

The robot: Gymnasium's ``hopper.xml`` (``Hopper-v5``: torso, thigh, leg, foot; planar
base ``rootx, rootz, rooty``; three hinges with 200 N m motors), loaded into both with
``cs.load_mjcf`` and ``mujoco.MjModel`` (cstorm's ``q`` equals MuJoCo's ``qpos``).
Horizon ``T = 1 s`` at MuJoCo's own ``timestep = 0.002 s``: 500 RK4 steps on both sides
(``--quick``: 200 steps). Both start from MuJoCo's ``qpos0`` at rest (torso at 1.25 m, the
foot 4 cm above the floor), so with contact the hopper lands after ~0.09 s and stays on
the ground.

What is timed (wall clock, best of several runs; compile time reported separately):

- **cstorm gradient**: ``value_and_grad`` of ``J(ctrl) = int 1/2 |tau_act|^2 dt + 1/2
  |q_root(T) - q_target|^2`` w.r.t. the control points ``ctrl`` (n_ctrl, 3) of the three
  active joints' quintic B-splines (``P = 3 n_ctrl`` parameters: 30 -> 10 control points
  per joint, 300 -> 100). The hinges are *active* (they follow their splines, the
  hybrid algorithm gives their torques), the base is passive: cstorm's method. The
  rollout is `cstorm.simulate.rollout` (RK4) under reverse-mode autodiff, with
  ``derivatives="parallel"`` (the time-parallel tangent rule of
  `cstorm.simulate.tangents`; ``--derivatives analytic`` for JAX's derivative of the
  checkpointed scan, the rule of the 2026-12-03 table). The splines enter only through the basis matrices (``paths =
  B @ ctrl``), so one compiled rollout gradient w.r.t. the paths serves every ``P``; the
  two matmuls of the chain rule are inside the timed call.
- **MuJoCo finite differences**: forward differences of the same kind of cost,
  ``J(p) = sum 1/2 |gear ctrl_k|^2 dt + 1/2 |qpos_root(T) - target|^2``, where the three
  motors' controls are the same quintic B-splines of ``P`` parameters sampled at the
  steps; ``P + 1`` rollouts in one `mujoco.rollout.rollout` call over all cores
  (``os.cpu_count()`` threads, one `MjData` each, persistent pool), including building
  the ``(P+1, steps, 3)`` control array and the costs from the returned states.
- **forward**: one cstorm rollout (jit, cost only) against one MuJoCo rollout of the
  same length (one thread), and cstorm's gradient time over its forward time.

Differences that remain (so read the ratios as "what each method pays for a gradient",
not as identical computations): MuJoCo's hinges are torque-driven (``ctrl``), cstorm's
follow prescribed paths (the hybrid algorithm solves for their torques: cheaper than
forward dynamics, not dearer); MuJoCo's contact is its soft-constraint model (floor vs 4
capsules, ``solref = 0.02 1``, Newton solver, pyramidal friction cones) while cstorm's is
the smooth penalty law at the two end spheres of each capsule against the ground plane
(k = 2.5e4 N/m, c = 500 N s/m, d_on = 0.01 m, d_off = 0, mu = 0.9, v_max = 0.1 m/s; the
values of the shipped ``hopper`` example); "no contact" disables MuJoCo's contact
(``mjDSBL_CONTACT``) and gives cstorm no environment (the hopper falls freely). MuJoCo's
RK4 integrates the whole state with constraint forces inside each stage, as cstorm's
does with contact forces. Finite differences are also less accurate (forward
differences, step 1e-6), which this benchmark does not count against them.

Break-even parameter count: MuJoCo's finite-difference time grows linearly with ``P``
(``(P + 1)`` rollouts over the cores), cstorm's gradient hardly at all; the break-even
``P*`` is where the fitted line ``t_fd(P) = a + b (P + 1)`` (measured at several ``P``)
meets cstorm's gradient time at 30 parameters.

Results: ``benchmarks/results/trajectory.json`` (written by ``python -m benchmarks``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

from benchmarks._common import machine, table

import jax
import jax.numpy as jnp

T_FINAL = 1.0
PARAMS = (30, 300)
FD_EPS = 1e-6
# cstorm's contact for the hopper (the shipped `hopper` example's numbers)
CONTACT = dict(stiffness=2.5e4, damping=500.0, d_on=0.01, d_off=0.0, friction=0.9, v_max=0.1)


def hopper_xml() -> str:
    import gymnasium

    path = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", "hopper.xml")
    if not os.path.exists(path):
        raise RuntimeError(f"Gymnasium's hopper.xml not found at {path}")
    return path


def _best(fn, repeat):
    best, out = math.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        jax.block_until_ready(out)
        best = min(best, time.perf_counter() - t0)
    return best, out


class _Setup:
    """Both models, the time grid and the spline bases for one horizon."""

    def __init__(self, steps: int):
        import mujoco

        import cstorm as cs
        from cstorm.simulate import RolloutLayout

        path = hopper_xml()
        self.mj = mujoco.MjModel.from_xml_path(path)
        self.dt = float(self.mj.opt.timestep)
        self.steps = int(steps)
        self.T = self.steps * self.dt
        self.cs_model = cs.load_mjcf(path)
        m = self.cs_model
        self.active = ("thigh_joint", "leg_joint", "foot_joint")
        self.layout = RolloutLayout.make(m, self.active)
        self.q0 = np.asarray(self.mj.qpos0, float).copy()  # cstorm's q equals MuJoCo's qpos
        self.gear = np.asarray(self.mj.actuator_gear[:, 0], float)
        self.target = np.array([0.3, 1.25, 0.0])  # root x, z, pitch at T (an arbitrary terminal target)
        self.ia = np.array(self.layout.qa_idx, int)
        self.env = cs.Environment([cs.ground()])
        self.contact = cs.ContactParams(**CONTACT)

    def spline(self, n_params):
        from cstorm.trajectory import QuinticBSpline

        n_ctrl = n_params // 3
        return QuinticBSpline(n_ctrl, self.T)

    def ctrl_points(self, n_params, seed=0):
        """Random but smooth motions: cstorm's joint paths (rad) around the standing
        posture; MuJoCo's motor controls (in [-1, 1]) of similar size in torque."""
        rng = np.random.default_rng(seed)
        n_ctrl = n_params // 3
        k = np.linspace(0, 1, n_ctrl)[:, None]
        paths = self.q0[self.ia][None, :] + 0.3 * np.sin(2 * np.pi * (k + rng.uniform(size=3)))
        paths += 0.02 * rng.normal(size=paths.shape)
        ctrls = 0.05 * np.sin(2 * np.pi * (k + rng.uniform(size=3))) + 0.01 * rng.normal(size=(n_ctrl, 3))
        return paths, ctrls


# ---------------------------------------------------------------------------------------
# cstorm
# ---------------------------------------------------------------------------------------
def _cstorm_fns(S: _Setup, contact: bool, derivatives: str = "parallel"):
    """Jitted ``loss(paths) -> J`` and ``value_and_grad`` w.r.t. the paths (RK4 grid and
    half-step arrays), both compiled once for every parameter count. ``derivatives``:
    the rollout's derivative rule (`cstorm.simulate.rollout`)."""
    from cstorm.contact import contact_forces
    from cstorm.simulate import rollout

    m, lay = S.cs_model, S.layout
    ia = np.array(lay.va_idx, int)
    target = jnp.asarray(S.target)
    q0, v0 = jnp.asarray(S.q0), jnp.zeros(m.nv)

    def cost_fn(t, q, v, a, tau, cdata, params):
        return 0.5 * jnp.sum(tau[ia] ** 2)

    def loss(paths, env, cp):
        cfn = None
        if contact:
            def cfn(q, v):
                out = contact_forces(m, env, cp, q, v)
                return out.f_ext, None
        res = rollout(m, lay, q0, v0, paths, S.dt, S.steps, integrator="rk4", contact_fn=cfn, cost_fn=cost_fn,
                      record=False, derivatives=derivatives)
        e = res["qT"][:3] - target
        return res["J"] + 0.5 * jnp.sum(e * e)

    return jax.jit(loss), jax.jit(jax.value_and_grad(loss))


def _basis(S: _Setup, spl):
    from cstorm.simulate import active_paths

    B = active_paths(spl, S.steps, "rk4")
    return {k: jnp.asarray(v) for k, v in B.items()}


@jax.jit
def _paths(B, ctrl):
    return dict(qa=B["B0"] @ ctrl, va=B["B1"] @ ctrl, aa=B["B2"] @ ctrl, qm=B["M0"] @ ctrl, vm=B["M1"] @ ctrl,
                am=B["M2"] @ ctrl)


@jax.jit
def _chain(B, g):
    return (B["B0"].T @ g["qa"] + B["B1"].T @ g["va"] + B["B2"].T @ g["aa"] + B["M0"].T @ g["qm"]
            + B["M1"].T @ g["vm"] + B["M2"].T @ g["am"])


# ---------------------------------------------------------------------------------------
# MuJoCo
# ---------------------------------------------------------------------------------------
class _MuJoCo:
    def __init__(self, S: _Setup, contact: bool):
        import mujoco
        from mujoco import rollout as mjr

        self.mujoco, self.mjr = mujoco, mjr
        self.S = S
        self.m = mujoco.MjModel.from_xml_path(hopper_xml())
        if not contact:
            self.m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self.nthread = os.cpu_count() or 1
        self.datas = [mujoco.MjData(self.m) for _ in range(self.nthread)]
        d = mujoco.MjData(self.m)
        mujoco.mj_resetData(self.m, d)
        self.state0 = np.zeros(mujoco.mj_stateSize(self.m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_getState(self.m, d, self.state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        # qpos inside the full-physics state: [time, qpos, qvel, act, ...]
        self.iq = 1 + np.arange(self.m.nq)
        self.B0 = {}

    def _basis(self, spl):
        if spl not in self.B0:
            t = np.arange(self.S.steps) * self.S.dt  # control k acts over [t_k, t_k + dt)
            self.B0[spl] = spl.basis_matrix(t, 0)
        return self.B0[spl]

    def _costs(self, U, nthread):
        """Costs of the control sequences U (nb, steps, 3): one `rollout` call (over a
        persistent pool of ``nthread`` threads; one thread: in the calling thread)."""
        S = self.S
        datas = self.datas[:max(1, nthread)]
        state, _ = self.mjr.rollout(self.m, datas, self.state0, U, persistent_pool=nthread > 1)
        e = state[:, -1, self.iq[:3]] - S.target
        tq = U * S.gear
        return 0.5 * np.sum(tq * tq, axis=(1, 2)) * S.dt + 0.5 * np.sum(e * e, axis=1)

    def cost(self, spl, p):
        """One rollout (one thread) at parameters p (n_ctrl, 3)."""
        return self._costs((self._basis(spl) @ p)[None], 1)[0]

    def fd_gradient(self, spl, p):
        """Forward differences at p (n_ctrl, 3): ``P + 1`` rollouts in one call over all
        threads. The perturbed control sequences differ from the nominal one in one
        motor's column by ``FD_EPS`` times one basis function (built in O(P steps))."""
        B = self._basis(spl)
        n_ctrl = p.shape[0]
        P = 3 * n_ctrl
        U0 = B @ p
        U = np.repeat(U0[None], P + 1, axis=0)
        k = np.arange(P)
        U[1 + k, :, k % 3] += FD_EPS * B[:, k // 3].T
        J = self._costs(U, self.nthread)
        return J[0], (J[1:] - J[0]) / FD_EPS


# ---------------------------------------------------------------------------------------
def run(quick: bool = False, derivatives: str = "parallel") -> list:
    """Time the cases and return rows (dicts): ``benchmark`` ("trajectory"), ``case``,
    ``cstorm_us``, ``peer``, ``peer_us``, ``ratio`` (cstorm / peer; < 1: cstorm faster),
    ``compile_s`` (cstorm's compile time for the row's function), ``notes``."""
    steps = 200 if quick else int(round(T_FINAL / 0.002))
    repeat = 3 if quick else 7
    S = _Setup(steps)
    rows = []
    for contact in (False, True):
        tag = "contact" if contact else "no contact"
        mj = _MuJoCo(S, contact)
        loss, vg = _cstorm_fns(S, contact, derivatives)
        env, cp = S.env, S.contact
        # compile (timed separately) on the 30-parameter paths
        spl30 = S.spline(PARAMS[0])
        B30 = _basis(S, spl30)
        c30 = jnp.asarray(S.ctrl_points(PARAMS[0])[0])
        p30 = _paths(B30, c30)
        t0 = time.perf_counter()
        jax.block_until_ready(loss(p30, env, cp))
        comp_f = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(vg(p30, env, cp))
        comp_g = time.perf_counter() - t0
        jax.block_until_ready(_chain(B30, vg(p30, env, cp)[1]))

        # forward: one cstorm rollout vs one MuJoCo rollout (one thread)
        t_fwd, J = _best(lambda: loss(_paths(B30, c30), env, cp), repeat)
        if not np.isfinite(float(J)):
            raise RuntimeError(f"cstorm rollout ({tag}) is not finite: {float(J)}")
        mjp30 = S.ctrl_points(PARAMS[0])[1]
        mj.cost(spl30, mjp30)
        t_mj1, _ = _best(lambda: mj.cost(spl30, mjp30), repeat)
        rows.append(dict(benchmark="trajectory", case=f"forward rollout, {tag}, {steps} RK4 steps",
                         cstorm_us=t_fwd * 1e6, peer="MuJoCo rollout (1 thread)", peer_us=t_mj1 * 1e6,
                         ratio=t_fwd / t_mj1, compile_s=comp_f, notes="cost only, no trajectory stored"))

        # MuJoCo FD at several P (for the break-even line), cstorm gradient at 30 and 300
        fd_times = {}
        for P in sorted(set((18, 30, 90, 300))):
            spl = S.spline(P)
            p = S.ctrl_points(P)[1]
            mj.fd_gradient(spl, p)  # warm the pool
            fd_times[P] = _best(lambda: mj.fd_gradient(spl, p), max(2, repeat // 2))[0]
        Ps = np.array(sorted(fd_times), float)
        b, a = np.polyfit(Ps + 1, np.array([fd_times[int(P)] for P in Ps]), 1)
        # cstorm's gradients: best of `repeat` rounds, the parameter counts interleaved
        # within each round (one compiled function serves all; a burst of load then
        # hits every count alike instead of one row)
        calls, t_grads = {}, {P: math.inf for P in PARAMS}
        for P in PARAMS:
            B = _basis(S, S.spline(P))
            c = jnp.asarray(S.ctrl_points(P)[0])

            def grad_call(B=B, c=c):
                val, g = vg(_paths(B, c), env, cp)
                return val, _chain(B, g)

            val, g = jax.block_until_ready(grad_call())
            if not (np.isfinite(float(val)) and np.all(np.isfinite(np.asarray(g)))):
                raise RuntimeError(f"cstorm gradient ({tag}, P={P}) is not finite")
            calls[P] = grad_call
        for _ in range(repeat):
            for P in PARAMS:
                t_grads[P] = min(t_grads[P], _best(calls[P], 1)[0])
        for P in PARAMS:
            t_g = t_grads[P]
            t_fd = fd_times[P]
            rows.append(dict(benchmark="trajectory", case=f"cost+gradient, {P} params, {tag}, {steps} steps",
                             cstorm_us=t_g * 1e6, peer=f"MuJoCo FD ({P + 1} rollouts, {mj.nthread} threads)",
                             peer_us=t_fd * 1e6, ratio=t_g / t_fd, compile_s=comp_g,
                             notes=f"cstorm reverse-mode value_and_grad (derivatives={derivatives!r}); "
                                   f"speed-up {t_fd / t_g:.1f}x"))
        P_star = (t_grads[PARAMS[0]] - a) / b - 1 if b > 0 else math.inf
        for r in rows[-len(PARAMS):]:
            r["notes"] += f"; break-even at ~{max(P_star, 0):.0f} params (MuJoCo FD {b * 1e6:.0f} us per rollout " \
                          f"over {mj.nthread} threads + {a * 1e6:.0f} us)"
        rows.append(dict(benchmark="trajectory", case=f"gradient / forward, {tag}", cstorm_us=t_grads[PARAMS[0]] * 1e6,
                         peer="cstorm forward rollout", peer_us=t_fwd * 1e6, ratio=t_grads[PARAMS[0]] / t_fwd,
                         compile_s=comp_g, notes="target <= 4"))
    return rows


def report(rows) -> str:
    hdr = ["case", "cstorm (ms)", "peer", "peer (ms)", "ratio cstorm / peer", "cstorm compile (s)", "notes"]
    body = [[r["case"], f"{r['cstorm_us'] / 1e3:.2f}", r["peer"], f"{r['peer_us'] / 1e3:.2f}", f"**{r['ratio']:.3f}**",
             f"{r['compile_s']:.1f}", r["notes"]] for r in rows]
    return f"Machine: {machine()}\n\n" + table(body, hdr)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="200 steps, fewer repeats")
    ap.add_argument("--json", action="store_true", help="print the rows as one JSON object")
    ap.add_argument("--derivatives", default="parallel", choices=("parallel", "analytic", "autodiff"),
                    help="the rollout's derivative rule (default: parallel, the time-parallel step Jacobians)")
    args = ap.parse_args(argv)
    rows = run(quick=args.quick, derivatives=args.derivatives)
    if args.json:
        print(json.dumps(dict(benchmark="trajectory", machine=machine(), rows=rows)))
    else:
        print(report(rows))


if __name__ == "__main__":
    main()
