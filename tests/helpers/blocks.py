"""Engine blocks for non-ideal benches: what a real motor and inverter do that the ideal model does not.

They run on the Jaxonomy engine as the independent truth of tests and
synthetic benches (``drivecal.bench``); drivecal's forward model never uses
them. Their dq equations are drivecal's (``drivecal.physics``), written once.
"""

from __future__ import annotations

from typing import Any

from drivecal.physics import MotorParams, dq_derivatives, with_d_flux

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
