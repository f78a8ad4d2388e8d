"""Engine blocks for non-ideal benches: what a real motor and inverter do that the ideal model does not.

They run on the Jaxonomy engine as the independent truth of tests and
synthetic benches (``drivecal.bench``); drivecal's forward model never uses
them.
"""

from __future__ import annotations

from typing import Any

from drivecal.physics import MotorParams


def saturating_pmsm_block(motor: MotorParams, *, d_saturation_current: float, locked: bool = False,
                          name: str = "pmsm"):
    """A PMSM whose d-axis iron saturates, as a Jaxonomy block.

    The d-axis flux is ``psi_d = Ld * i_sat * tanh(i_d / i_sat) + lambda_m``
    (``i_sat`` = ``d_saturation_current``, A): the incremental inductance
    ``Ld / cosh(i_d / i_sat)**2`` falls as |i_d| grows, which is what a
    saturating machine shows a bench test (Ld at 20 A lower than at 5 A).
    The q axis, torque and mechanics follow the flux:
    ``Te = 1.5 p (psi_d i_q - Lq i_d i_q)``. Same ports as
    ``jaxonomy.library.drives.PMSM``.
    """
    from jaxonomy.backend import numpy_api as npa
    from jaxonomy.library.drives import PMSM

    i_sat = float(d_saturation_current)

    class SaturatingPMSM(PMSM):
        def _ode(self, _time, state, *inputs, **p) -> Any:
            i_d, i_q, w_m, _theta = state.continuous_state
            v_d, v_q = inputs[0][0], inputs[0][1]
            x = i_d / i_sat
            psi_d = p["Ld"] * i_sat * npa.tanh(x) + p["lambda_m"]
            l_inc = p["Ld"] / npa.cosh(x) ** 2
            w_e = p["pole_pairs"] * w_m
            di_d = (v_d - p["R"] * i_d + w_e * p["Lq"] * i_q) / l_inc
            di_q = (v_q - p["R"] * i_q - w_e * psi_d) / p["Lq"]
            if self._locked:
                dw_m, dtheta = 0.0 * w_m, 0.0 * w_m
            else:
                torque = 1.5 * p["pole_pairs"] * (psi_d * i_q - p["Lq"] * i_d * i_q)
                dw_m = (torque - p["B"] * w_m - p["T_load"]) / p["J"]
                dtheta = w_m
            return npa.stack([di_d, di_q, dw_m, dtheta])

    return SaturatingPMSM(
        R=float(motor.R), Ld=float(motor.Ld), Lq=float(motor.Lq), lambda_m=float(motor.lambda_m),
        pole_pairs=float(motor.pole_pairs), J=float(motor.J), B=float(motor.B), T_load=float(motor.T_load),
        locked=bool(locked), name=name,
    )
