"""Hand-off to simulation: a calibrated motor as a Jaxonomy PMSM block.

The same builder makes the synthetic bench's plant (``_engine``), so the
exported block is exactly the kind of block the bench data came from.
"""

from __future__ import annotations

from typing import Any

from ..physics import MotorParams


def pmsm_block(motor: MotorParams, *, locked: bool = False, initial_state: Any = None, name: str = "pmsm",
               load_port: bool = False):
    """A ``jaxonomy.library.drives.PMSM`` with the parameters of ``motor``.

    Args:
        motor: the machine (SI units); every field becomes a block parameter.
        locked: clamp the rotor (standstill bench); fixed when the block is built.
        initial_state: ``[i_d, i_q, w_m, theta_m]`` (A, A, rad/s, rad); default rest.
        name: block name in the diagram.
        load_port: take the load torque (N*m) from input port 1 instead of
            ``motor.T_load`` (the engine bench feeds it the Coulomb friction and
            the load; the block itself has no Coulomb friction).

    Returns:
        The block; input port 0 is ``[v_d, v_q]`` (V), output port 0 the state,
        output port 1 the torque (N*m).
    """
    from jaxonomy.library.drives import PMSM

    return PMSM(
        R=float(motor.R),
        Ld=float(motor.Ld),
        Lq=float(motor.Lq),
        lambda_m=float(motor.lambda_m),
        pole_pairs=float(motor.pole_pairs),
        J=float(motor.J),
        B=float(motor.B),
        T_load=float(motor.T_load),
        initial_state=initial_state,
        locked=bool(locked),
        enable_load_port=bool(load_port),
        name=name,
    )
