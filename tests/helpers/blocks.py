"""Engine blocks for non-ideal benches: what a real motor and inverter do that the ideal model does not.

They run on the Jaxonomy engine as the independent truth of tests and
synthetic benches (``drivecal.bench``); drivecal's forward model never uses
them. Their dq equations are drivecal's (``drivecal.physics``), written once; the published PM-SyRM's
current-of-flux law, which drivecal's law cannot express, is written here from its publication.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

from drivecal.physics import MotorParams, dq_derivatives, flux_derivatives, flux_torque, with_d_flux

#: The PMSM block's parameters that are motor fields.
_BLOCK_PARAMETERS = ("R", "Ld", "Lq", "lambda_m", "pole_pairs", "J", "B", "T_load")


def saturating_pmsm_block(motor: MotorParams, *, d_saturation_current: float, locked: bool = False,
                          name: str = "pmsm"):
    """A PMSM whose d-axis iron saturates, as a Jaxonomy block.

    The d-axis flux is ``psi_d = Ld * i_sat * tanh(i_d / i_sat) + lambda_m``
    (``i_sat`` = ``d_saturation_current``, A): the incremental inductance
    ``Ld / cosh(i_d / i_sat)**2`` falls as |i_d| grows, which is what a
    saturating machine shows a bench test (Ld at 20 A lower than at 5 A).
    The q axis, torque and mechanics follow the flux:
    ``Te = 1.5 p (psi_d i_q - Lq i_d i_q)`` (``physics.with_d_flux``). Same
    ports as ``jaxonomy.library.drives.PMSM``.
    """
    from jaxonomy.backend import numpy_api as npa
    from jaxonomy.library.drives import PMSM

    i_sat = float(d_saturation_current)

    class SaturatingPMSM(PMSM):
        def _ode(self, _time, state, *inputs, **p) -> Any:
            x = state.continuous_state
            linear = MotorParams(**{k: p[k] for k in _BLOCK_PARAMETERS})
            s = x[0] / i_sat
            at_i_d = with_d_flux(linear, x[0], flux_d=p["Ld"] * i_sat * npa.tanh(s) + p["lambda_m"],
                                 inductance_d=p["Ld"] / npa.cosh(s) ** 2)
            return npa.stack(dq_derivatives(x, inputs[0], at_i_d, self._locked))

    return SaturatingPMSM(
        R=float(motor.R), Ld=float(motor.Ld), Lq=float(motor.Lq), lambda_m=float(motor.lambda_m),
        pole_pairs=float(motor.pole_pairs), J=float(motor.J), B=float(motor.B), T_load=float(motor.T_load),
        locked=bool(locked), name=name,
    )


#: A published PM-assisted synchronous reluctance motor: the 5.5-kW PM-SyRM (Baldor ECS101M0H7EF4) of Aalto's
#: motulator (example ``flux_vector/plot_flux_vector_pmsyrm_5kw.py``), its current-of-flux law fitted to measured
#: flux maps with the self- and cross-saturation model of Hinkkanen et al. 2017 (doi 10.1109/TIA.2016.2644624) and
#: the PM and iron-bridge model of Lelli, Hinkkanen, Giulii Capponi, ICEM 2024 (doi 10.1109/ICEM60801.2024.10700403).
#: SI: a_d0, a_q0 (1/H), a_dd (A/Wb^5), a_qq (A/Wb^7), a_dq (A/Wb^5), a_b (A/Wb^3), a_bp (1/Wb^2), psi_n (Wb).
LELLI_PM_SYRM = dict(a_d0=3.96, a_dd=28.46, S=4, a_q0=5.89, a_qq=2.672, T=6, a_dq=41.52, U=1, V=1,
                     a_b=81.75, a_bp=1.0, k_q=0.1, psi_n=0.804, W=2)
#: The motor's other published values (motulator's example): R (ohm), pole pairs, J (kg*m^2).
LELLI_PM_SYRM_MACHINE = dict(R=0.63, pole_pairs=2.0, J=0.015)


def lelli_currents(psi_d: Any, psi_q: Any, law: dict = LELLI_PM_SYRM) -> tuple[Any, Any]:
    """The PM-SyRM's currents ``(i_d, i_q)`` (A) at the flux linkages ``psi_d``, ``psi_q`` (Wb): Lelli et al.'s law.

    The self- and cross-saturation terms of Hinkkanen et al. about zero flux, and an iron bridge (a saturable
    reluctance in parallel with the magnet's Norton equivalent) that carries the magnet's flux ``psi_n``::

        i_d = G_d*psi_d + G_b*(psi_d - psi_n),  i_q = (G_q + k_q*G_b)*psi_q,
        G_b = a_b*s**W / (1 + a_bp*s**W),  s = sqrt((psi_d - psi_n)**2 + k_q*psi_q**2)

    Written here from the published equations, independently of ``drivecal.physics`` (whose law has no
    bridge): the plant a drivecal fit meets on a real PM-assisted motor.
    """
    import jax.numpy as jnp

    p = law
    ad, aq = jnp.abs(psi_d), jnp.abs(psi_q)
    g_d = p["a_d0"] + p["a_dd"] * ad ** p["S"] + p["a_dq"] / (p["V"] + 2) * ad ** p["U"] * aq ** (p["V"] + 2)
    g_q = p["a_q0"] + p["a_qq"] * aq ** p["T"] + p["a_dq"] / (p["U"] + 2) * ad ** (p["U"] + 2) * aq ** p["V"]
    bridge = psi_d - p["psi_n"]
    s_w = (bridge ** 2 + p["k_q"] * psi_q ** 2) ** (0.5 * p["W"])
    g_b = p["a_b"] * s_w / (1.0 + p["a_bp"] * s_w)
    return g_d * psi_d + g_b * bridge, (g_q + p["k_q"] * g_b) * psi_q


def lelli_small_signal(law: dict = LELLI_PM_SYRM) -> tuple[float, float, float]:
    """The law's magnet flux and small-signal inductances: ``(lambda_m, Ld, Lq)`` (Wb, H, H).

    ``lambda_m`` is the d flux at zero current (Newton's method on ``i_d(psi_d, 0) = 0``), ``Ld`` and ``Lq`` the
    inverse of ``d(i_d, i_q)/d(psi_d, psi_q)`` there (diagonal: the law is even in ``psi_q``). Computed once per law.
    """
    return _small_signal(tuple(law.items()))


@functools.cache
def _small_signal(items: tuple) -> tuple[float, float, float]:
    """:func:`lelli_small_signal` of the law ``dict(items)``."""
    import jax

    law = dict(items)

    def d_current(psi_d):
        return lelli_currents(psi_d, 0.0, law)[0]

    psi = 0.5
    for _ in range(40):
        psi = psi - float(d_current(psi)) / float(jax.grad(d_current)(psi))
    inv_ld = float(jax.grad(d_current)(psi))
    inv_lq = float(jax.grad(lambda q: lelli_currents(psi, q, law)[1])(0.0))
    return float(psi), 1.0 / inv_ld, 1.0 / inv_lq


def lelli_flux(i_d: Any, i_q: Any, law: dict = LELLI_PM_SYRM) -> tuple[Any, Any]:
    """The flux linkages ``(psi_d, psi_q)`` (Wb) where the law gives the currents ``i_d``, ``i_q`` (A): Newton."""
    import jax
    import jax.numpy as jnp

    lam, ld, lq = lelli_small_signal(law)
    i = jnp.stack(jnp.broadcast_arrays(jnp.asarray(i_d, dtype=float), jnp.asarray(i_q, dtype=float)), -1)

    def residual(psi, target):
        return jnp.stack(lelli_currents(psi[0], psi[1], law)) - target

    def solve(target):
        psi = jnp.array([lam, 0.0]) + jnp.array([ld, lq]) * target
        for _ in range(30):
            psi = psi - jnp.linalg.solve(jax.jacfwd(residual)(psi, target), residual(psi, target))
        return psi

    psi = jax.vmap(solve)(i.reshape(-1, 2)).reshape(i.shape)
    return psi[..., 0], psi[..., 1]


def lelli_pm_syrm_block(*, locked: bool = False, name: str = "pmsm", B: float = 0.0):
    """The published PM-SyRM as a Jaxonomy block with the flux linkages as its state, from rest.

    State ``[psi_d, psi_q, w_m, theta_m]`` (Wb, Wb, rad/s, rad), starting at ``(lambda_m, 0, 0, 0)``;
    ``physics.flux_derivatives`` with the currents of :func:`lelli_currents`.
    Ports as ``jaxonomy.library.drives.PMSM``: output port 0 is ``[i_d, i_q, w_m, theta_m]``. The block's
    Ld, Lq and lambda_m parameters are the law's small-signal values, for show: the law is the dynamics.
    """
    import jax.numpy as jnp
    from jaxonomy.library.drives import PMSM

    lam, ld, lq = lelli_small_signal()
    machine = LELLI_PM_SYRM_MACHINE

    class LelliPMSyRM(PMSM):
        def initialize(self, R, Ld, Lq, lambda_m, pole_pairs, J, B, T_load, initial_state=None, locked=False,
                       enable_load_port=False):
            self.declare_continuous_state(default_value=jnp.array([lam, 0.0, 0.0, 0.0]), ode=self._ode)

        def _state_output(self, _time, state, *_inputs, **p):
            x = state.continuous_state
            i_d, i_q = lelli_currents(x[0], x[1])
            return jnp.stack([i_d, i_q, x[2], x[3]])

        def _ode(self, _time, state, *inputs, **p):
            x = state.continuous_state
            motor = MotorParams(**{k: p[k] for k in _BLOCK_PARAMETERS})
            d, _ = flux_derivatives(x, inputs[0], motor, self._locked, friction=p["T_load"],
                                    currents=lelli_currents(x[0], x[1]))
            return jnp.stack(d)

        def _torque_output(self, _time, state, *_inputs, **p):
            x = state.continuous_state
            i_d, i_q = lelli_currents(x[0], x[1])
            return flux_torque(x[0], x[1], i_d, i_q, p["pole_pairs"])

    return LelliPMSyRM(R=machine["R"], Ld=ld, Lq=lq, lambda_m=lam, pole_pairs=machine["pole_pairs"],
                       J=machine["J"], B=B, T_load=0.0, locked=bool(locked), name=name)


def lelli_bench(plan) -> Any:
    """Noise-free bench data of ``plan`` (a ``drivecal.Plan``) run on :func:`lelli_pm_syrm_block`, each segment
    from rest (the plan's segments must not continue one another; the inverter ideal and always on)."""
    import drivecal as dc
    from drivecal.bench import run_held_voltages

    segments = []
    for seg in plan.segments:
        if seg.continues or seg.inverter != "on":
            raise ValueError(f"segment '{seg.name}': lelli_bench runs each segment from rest, inverter on")
        v = seg.voltages(plan.sample_rate)
        t, x = run_held_voltages(lelli_pm_syrm_block(locked=seg.locked), v, plan.sample_rate, label=seg.name)
        segments.append(dc.SegmentData(seg.name, seg.locked, t, v, x[:, :2].copy()))
    return dc.BenchData(tuple(segments), plan.sample_rate, source="PM-SyRM bench (Lelli et al.'s law)")


def lelli_levels() -> Any:
    """The PM-SyRM's multi-level locked plan (a ``drivecal.Plan``): locked steps at several levels on each axis, both
    signs on d, and combined d+q steps, 10 ms each at 10 kHz; up to 18 A and -12 A on d and 18 A on q (a 540-V
    drive), where its incremental Lq falls fourfold."""
    import drivecal as dc

    return dc.Plan(tuple(dc.Segment(n, 0.01, True, v_d=v_d, v_q=v_q) for n, v_d, v_q in (
        ("d 15 V", 15.0, 0.0), ("d 30 V", 30.0, 0.0), ("d 45 V", 45.0, 0.0), ("d -30 V", -30.0, 0.0),
        ("q 40 V", 0.0, 40.0), ("q 80 V", 0.0, 80.0), ("q 120 V", 0.0, 120.0),
        ("d+q", 30.0, 80.0), ("d-q", 30.0, -80.0))), sample_rate=10000.0, v_dc=540.0, current_limit=40.0)


def lelli_motor_file(path: str | Path) -> Path:
    """Write the PM-SyRM's motor file as a user knows the motor: its small-signal values, R, pole pairs and J."""
    lam, ld, lq = lelli_small_signal()
    m = LELLI_PM_SYRM_MACHINE
    Path(path).write_text(f"R = {m['R']}\nLd = {ld!r}\nLq = {lq!r}\nlambda_m = {lam!r}\n"
                          f"pole_pairs = {m['pole_pairs']}\nJ = {m['J']}\n")
    return Path(path)
