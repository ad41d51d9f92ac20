"""IPOPT through casadi (optional extra ``cstorm[ipopt]``), fed with cstorm's exact JAX
first derivatives: the objective and the constraints are casadi ``Callback`` functions
whose Jacobians are further callbacks returning the compiled JAX Jacobian (cached per
x, so one rollout serves values and derivatives). The Hessian is IPOPT's limited-memory
(L-BFGS) approximation. An iteration callback drives cstorm's progress display,
checkpoints and the user's callback; a KeyboardInterrupt there stops IPOPT and is
re-raised to `solve`, which returns the best iterate.
"""

from __future__ import annotations

import numpy as np

from .bounds import clip_into, variable_bounds

__all__ = ["run_ipopt"]


def run_ipopt(ca, ev, x0, tracker, stage, params, max_iter, tol, options):
    n = x0.size
    me, mi = ev.me, ev.mi
    ne, ni = int(me.sum()), int(mi.sum())
    m = ne + ni

    def cons(x):
        _, ce, ci, *_ = ev.at(x)
        return np.concatenate([ce, ci])

    def cons_jac(x):
        v = ev.at(x)
        return np.vstack([v[5].reshape(ne, n), v[6].reshape(ni, n)])

    class _Jac(ca.Callback):
        def __init__(self, name, nout, fn):
            ca.Callback.__init__(self)
            self.nout, self.fn = nout, fn
            self.construct(name, {})

        def get_n_in(self):
            return 2

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return ca.Sparsity.dense(n, 1) if i == 0 else ca.Sparsity.dense(self.nout, 1)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(self.nout, n)

        def eval(self, arg):
            return [ca.DM(self.fn(np.asarray(arg[0]).ravel()))]

    class _Fun(ca.Callback):
        def __init__(self, name, nout, fn, jac):
            ca.Callback.__init__(self)
            self.nout, self.fn, self.jacfn = nout, fn, jac
            self.construct(name, {})

        def get_n_in(self):
            return 1

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return ca.Sparsity.dense(n, 1)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(self.nout, 1)

        def eval(self, arg):
            return [ca.DM(self.fn(np.asarray(arg[0]).ravel()))]

        def has_jacobian(self):
            return True

        def get_jacobian(self, name, inames, onames, opts):
            self._jac = _Jac(name, self.nout, self.jacfn)
            return self._jac

    state = {"interrupt": None}

    class _Iter(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("cstorm_iteration", {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_name_in(self, i):
            return ca.nlpsol_out(i)

        def get_name_out(self, i):
            return "ret"

        def get_sparsity_in(self, i):
            name = ca.nlpsol_out(i)
            if name == "f":
                return ca.Sparsity.scalar()
            if name in ("x", "lam_x"):
                return ca.Sparsity.dense(n, 1)
            if name in ("g", "lam_g"):
                return ca.Sparsity.dense(m, 1)
            return ca.Sparsity(0, 0)

        def eval(self, arg):
            try:
                tracker.record(np.asarray(arg[0]).ravel(), ev, stage, params)
            except (KeyboardInterrupt, StopIteration) as e:
                state["interrupt"] = e
                return [1]  # non-zero: IPOPT stops ("user requested stop")
            return [0]

    f_cb = _Fun("cstorm_f", 1, lambda x: np.array([ev.fscale * ev.at(x)[0]]),
                lambda x: (ev.fscale * ev.at(x)[4]).reshape(1, n))
    g_cb = _Fun("cstorm_g", m, cons, cons_jac) if m else None
    it_cb = _Iter()
    X = ca.MX.sym("x", n)
    nlp = {"x": X, "f": f_cb(X)}
    if m:
        nlp["g"] = g_cb(X)
    opts = {"ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": int(max_iter), "ipopt.tol": float(tol),
            "ipopt.print_level": 0, "print_time": False, "iteration_callback": it_cb,
            "ipopt.constr_viol_tol": 1e-8}
    for k, v in (options or {}).items():
        opts[k if "." in k or k in ("print_time", "iteration_callback") else f"ipopt.{k}"] = v
    solver = ca.nlpsol("cstorm_ipopt", "ipopt", nlp, opts)
    lbg = np.concatenate([np.zeros(ne), np.zeros(ni)])
    ubg = np.concatenate([np.zeros(ne), np.full(ni, np.inf)])
    lbx, ubx = getattr(ev, "bounds", None) or variable_bounds(ev.p)
    args = dict(x0=clip_into(x0, lbx, ubx), lbx=lbx, ubx=ubx)
    if m:
        args.update(lbg=lbg, ubg=ubg)
    res = solver(**args)
    stats = solver.stats()
    if isinstance(state["interrupt"], KeyboardInterrupt):
        raise KeyboardInterrupt
    x = np.asarray(res["x"]).ravel()
    ok = bool(stats.get("success", False))
    msg = f"IPOPT: {stats.get('return_status', 'unknown')}"
    return x, ok, msg, int(stats.get("iter_count", 0))
