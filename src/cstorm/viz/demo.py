"""The foundation demo: a double pendulum released from horizontal, simulated by RK4 on
the ABA, with a plot of angles and energy and a strobe picture of the motion."""

from __future__ import annotations

import csv
import os
import time

import numpy as np


def simulate_free(model, q0, v0, dt, n):
    """Torque-free RK4 rollout (fixed-base model), compiled once. Returns q, v (n+1, ·)."""
    import jax
    import jax.numpy as jnp

    from ..dynamics import aba, passive_forces

    def f(q, v):
        return v, aba(model, q, v, passive_forces(model, q, v))

    def step(s, _):
        q, v = s
        k1 = f(q, v)
        k2 = f(q + dt / 2 * k1[0], v + dt / 2 * k1[1])
        k3 = f(q + dt / 2 * k2[0], v + dt / 2 * k2[1])
        k4 = f(q + dt * k3[0], v + dt * k3[1])
        qn = q + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        vn = v + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        return (qn, vn), (qn, vn)

    @jax.jit
    def roll(q0, v0):
        _, (qs, vs) = jax.lax.scan(step, (q0, v0), None, length=n)
        return jnp.concatenate([q0[None], qs]), jnp.concatenate([v0[None], vs])

    return roll, jnp.asarray(q0), jnp.asarray(v0)


def pendulum_demo(out, t_final=3.0, dt=1e-3):
    import jax
    import jax.numpy as jnp
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import robots
    from ..dynamics import kinetic_energy, potential_energy
    from .planar import draw_model

    model = robots.double_pendulum()
    n = int(round(t_final / dt))
    roll, q0, v0 = simulate_free(model, np.array([np.pi / 2, 0.0]), np.zeros(2), dt, n)
    t0 = time.perf_counter()
    lowered = roll.lower(q0, v0).compile()
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    qs, vs = jax.block_until_ready(lowered(q0, v0))
    t_run = time.perf_counter() - t0
    energy = jax.jit(jax.vmap(lambda q, v: kinetic_energy(model, q, v) + potential_energy(model, q)))(qs, vs)
    qs, vs, energy = np.asarray(qs), np.asarray(vs), np.asarray(energy)
    t = np.arange(n + 1) * dt
    ke = np.asarray(jax.vmap(lambda q, v: kinetic_energy(model, q, v))(jnp.asarray(qs), jnp.asarray(vs)))
    drift = float(np.abs(energy - energy[0]).max() / max(1e-12, ke.max()))  # relative to the peak kinetic energy

    fig, axs = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    axs[0].plot(t, qs[:, 0], label="shoulder")
    axs[0].plot(t, qs[:, 1], label="elbow")
    axs[0].set_ylabel("angle (rad)")
    axs[0].legend(loc="upper right")
    axs[0].set_title("double pendulum released from horizontal (RK4 + ABA, dt = 1 ms)")
    axs[1].plot(t, energy - energy[0])
    axs[1].set_ylabel("E - E0 (J)")
    axs[1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "pendulum_angles.png"), dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 5))
    frames = np.linspace(0, min(n, int(1.2 / dt)), 13).astype(int)
    for k, i in enumerate(frames):
        draw_model(ax, model, qs[i], color=plt.cm.viridis(k / (len(frames) - 1)), alpha=0.55, lw=0.5)
    ax.plot(0, 0, "ko")
    ax.set_aspect("equal")
    ax.set_xlim(-1.1, 1.1)
    ax.set_ylim(-1.1, 0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title("first 1.2 s, strobe (dark = early)")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "pendulum_strobe.png"), dpi=110)
    plt.close(fig)

    tmp = os.path.join(out, ".pendulum_trajectory.csv.tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "q_shoulder", "q_elbow", "v_shoulder", "v_elbow", "energy"])
        for i in range(0, n + 1, 10):
            w.writerow([f"{t[i]:.4f}"] + [f"{x:.9g}" for x in (*qs[i], *vs[i], energy[i])])
    os.replace(tmp, os.path.join(out, "pendulum_trajectory.csv"))
    return dict(demo="double_pendulum", steps=n, dt=dt, energy_drift_rel=drift, compile_time_s=t_compile,
                run_time_s=t_run, final_q=qs[-1].tolist())
