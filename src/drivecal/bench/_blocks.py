"""Hand-off to simulation: a calibrated motor as a Jaxonomy PMSM block.

The same builder makes the synthetic bench's plant (``_engine``), so the
exported block is exactly the kind of block the bench data came from.
"""

from __future__ import annotations

from typing import Any

from ..physics import BRIDGE, BRIDGE_SHAPE, EXPONENTS, MAGNETIC, MotorParams, is_saturating

#: The fields of the saturating law that the flux-state block holds as constants.
_LAW = MAGNETIC + EXPONENTS + ("i_ref",) + BRIDGE + BRIDGE_SHAPE
#: The block's parameters in the order of ``jaxonomy.library.drives.PMSM``'s signature.
_BLOCK_PARAMETERS = ("R", "Ld", "Lq", "lambda_m", "pole_pairs", "J", "B", "T_load")


class _ShowsValues:
    """A PMSM block whose repr shows the machine: each parameter in its engineering unit, not jaxonomy's
    ``PMSM(system_id=1, name='pmsm', ...)``."""

    _law_shown: dict[str, float] = {}

    def __repr__(self) -> str:
        from .._units import format_quantity
        from ..physics import UNITS

        params = self.dynamic_parameters
        order = [n for n in _BLOCK_PARAMETERS if n in params] + sorted(set(params) - set(_BLOCK_PARAMETERS))
        try:
            values = [(n, float(params[n])) for n in order]
        except (TypeError, ValueError):  # a batched or traced parameter: jaxonomy's own repr
            return super().__repr__()
        shown = ", ".join(f"{n} = {format_quantity(v, UNITS.get(n, '-'))}" for n, v in values)
        rotor = "rotor locked" if self._locked else "rotor free"
        law = ", ".join(f"{n} = {format_quantity(v, UNITS.get(n, '-'))}" for n, v in self._law_shown.items())
        law = f"; flux states, saturating law: {law}" if self._law_shown else ""
        return f"{type(self).__name__}({self.name!r}: {shown}; {rotor}{law})"


def _pmsm_class() -> type:
    """``jaxonomy.library.drives.PMSM`` with the readable repr (made on first use: jaxonomy loads then)."""
    cls = globals().get("PMSM")
    if cls is None:
        from jaxonomy.library.drives import PMSM as Base

        cls = type("PMSM", (_ShowsValues, Base), {"__module__": __name__, "__qualname__": "PMSM",
                                                  "__doc__": Base.__doc__})
        globals()["PMSM"] = cls
    return cls


def __getattr__(name: str):
    if name == "PMSM":  # pickle finds the block's class here by name
        return _pmsm_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
        The block (a ``jaxonomy.library.drives.PMSM`` whose repr shows its parameters in
        engineering units); input port 0 is ``[v_d, v_q]`` (V), output port 0 the state,
        output port 1 the torque (N*m). A motor with magnetic saturation
        (``physics.is_saturating``) is a flux-state block (:func:`flux_pmsm_block`).
    """
    if is_saturating(motor):
        return flux_pmsm_block(motor, locked=locked, initial_state=initial_state, name=name, load_port=load_port)

    return _pmsm_class()(
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


def flux_pmsm_block(motor: MotorParams, *, locked: bool = False, initial_state: Any = None, name: str = "pmsm",
                    load_port: bool = False):
    """A PMSM whose iron saturates, as a Jaxonomy block with the flux linkages as its continuous state.

    The state is ``[psi_d, psi_q, w_m, theta_m]`` (Wb, Wb, rad/s, rad) and its derivative
    ``physics.flux_derivatives`` (the currents from ``physics.currents_of_flux``: the same law as
    drivecal's model). Ports as :func:`pmsm_block`: output port 0 is ``[i_d, i_q, w_m, theta_m]``,
    the currents computed from the flux; ``initial_state`` is in currents too (default rest, where the
    flux is ``(lambda_m, 0)``). The law's coefficients are constants of the block; R, Ld, Lq,
    lambda_m, the mechanics and the load are its parameters as in ``jaxonomy.library.drives.PMSM``.
    """
    import jax.numpy as jnp
    from jaxonomy.library.drives import PMSM

    from ..physics import currents_of_flux, flux_derivatives, flux_of_currents, flux_torque, has_bridge

    law = {n: float(getattr(motor, n)) for n in _LAW}
    whole = has_bridge(motor)  # the whole law only where it has a bridge or terms about zero flux (same currents)
    start = jnp.zeros(4) if initial_state is None else jnp.asarray(initial_state, dtype=float)

    def machine(p):
        return MotorParams(**{k: p[k] for k in ("R", "Ld", "Lq", "lambda_m", "pole_pairs", "J", "B", "T_load")},
                           **law)

    class FluxPMSM(_ShowsValues, PMSM):
        _law_shown = law

        def initialize(self, R, Ld, Lq, lambda_m, pole_pairs, J, B, T_load, initial_state=None, locked=False,
                       enable_load_port=False):
            m = machine(dict(R=R, Ld=Ld, Lq=Lq, lambda_m=lambda_m, pole_pairs=pole_pairs, J=J, B=B, T_load=T_load))
            psi_d, psi_q = flux_of_currents(start[0], start[1], m, bridge=whole)
            self.declare_continuous_state(default_value=jnp.stack([psi_d, psi_q, start[2], start[3]]), ode=self._ode)

        def _state_output(self, _time, state, *_inputs, **p):
            x = state.continuous_state
            i_d, i_q = currents_of_flux(x[0], x[1], machine(p), bridge=whole)
            return jnp.stack([i_d, i_q, x[2], x[3]])

        def _ode(self, _time, state, *inputs, **p):
            m = machine(p)
            friction = inputs[1] if self._enable_load_port else m.T_load
            d, _ = flux_derivatives(state.continuous_state, inputs[0], m, self._locked, friction=friction,
                                    bridge=whole)
            return jnp.stack(d)

        def _torque_output(self, _time, state, *_inputs, **p):
            x = state.continuous_state
            i_d, i_q = currents_of_flux(x[0], x[1], machine(p), bridge=whole)
            return flux_torque(x[0], x[1], i_d, i_q, p["pole_pairs"])

    return FluxPMSM(
        R=float(motor.R), Ld=float(motor.Ld), Lq=float(motor.Lq), lambda_m=float(motor.lambda_m),
        pole_pairs=float(motor.pole_pairs), J=float(motor.J), B=float(motor.B), T_load=float(motor.T_load),
        locked=bool(locked), enable_load_port=bool(load_port), name=name,
    )
