"""The parameters' vocabulary: their names by role, SI units and meanings, and how a fit searches them.

Plain Python (no JAX): a page or a table that only names and labels parameters (the fleet report)
loads this alone. ``drivecal.physics`` re-exports every name; the laws that use them live there.
"""

from __future__ import annotations

#: The saturation coefficients a fit may estimate (dimensionless; ``physics._magnetics``), in drivecal's order.
MAGNETIC: tuple[str, ...] = ("sat_d", "sat_q", "sat_dq")
#: The saturating law's exponents (Hinkkanen's S, T, U, V): settings, chosen among ``physics.EXPONENT_CANDIDATES``.
EXPONENTS: tuple[str, ...] = ("exp_d", "exp_q", "exp_dq_d", "exp_dq_q")
#: The iron bridge of a PM-assisted motor (Lelli et al.; ``physics._magnetics``): its saturation coefficient (per
#: unit; 0: no bridge) and its shape (its own saturation, the q flux's weight in it, the magnet flux it carries),
#: estimable when named (the shape acts only where ``sat_b`` is non-zero). Not among :data:`MAGNETIC`: the automatic
#: model choice does not try them.
BRIDGE: tuple[str, ...] = ("sat_b", "sat_bp", "k_q", "psi_n")
#: The bridge's exponent and the centre of the self- and cross-saturation terms: settings of the law.
BRIDGE_SHAPE: tuple[str, ...] = ("exp_b", "sat_at_zero")

#: Parameters a calibration estimates by default, in this order.
ESTIMATED: tuple[str, ...] = ("R", "Ld", "Lq", "lambda_m")
#: Parameters held fixed by default (known from the datasheet or unobservable
#: from currents alone).
FIXED: tuple[str, ...] = ("pole_pairs", "J", "B")
#: Bench effects that stand between the motor and the measurement, each
#: optional: estimated only when named (motor file ``estimate``), else held at
#: the motor file's value (zero by default: an ideal inverter and sensors).
NUISANCE: tuple[str, ...] = ("delay", "v_dead", "i_dead", "offset_d", "offset_q", "offset_a", "offset_b", "alpha_R",
                             "encoder_offset")
#: Mechanical parameters, estimable when named (J and B are otherwise held at the motor file's
#: values, T_coulomb and T_load at zero): they act on the currents only where the rotor turns and
#: its speed is simulated, not taken from a measured speed.
MECHANICAL: tuple[str, ...] = ("J", "B", "T_coulomb", "T_load")
#: Every parameter a fit may estimate, in drivecal's order (the saturation coefficients last: see
#: ``physics._magnetics``; zero in a linear machine).
ESTIMABLE: tuple[str, ...] = ESTIMATED + NUISANCE + MECHANICAL + MAGNETIC + BRIDGE
#: Settings of the models, never estimated (the saturation law's exponents are chosen among candidates).
SETTINGS: tuple[str, ...] = ("T_ref", "w_coulomb") + EXPONENTS + ("i_ref",) + BRIDGE_SHAPE
#: The default motor's value of every parameter and setting (SI; ``physics.DEFAULT_MOTOR``, the field defaults of
#: ``physics.MotorParams``): the 48 V interior PMSM of the tutorial bench on an ideal inverter and ideal sensors.
#: Plain numbers, so that a motor file is read and checked without JAX (``data._motor_spec``).
DEFAULT_VALUES: dict[str, float] = {
    "R": 0.45, "Ld": 3.2e-3, "Lq": 5.8e-3, "lambda_m": 0.0533, "pole_pairs": 4.0, "J": 1.2e-3, "B": 8.0e-5,
    "T_load": 0.0, "T_coulomb": 0.0, "w_coulomb": 1.0, "delay": 0.0, "v_dead": 0.0, "i_dead": 0.01, "offset_d": 0.0,
    "offset_q": 0.0, "offset_a": 0.0, "offset_b": 0.0, "alpha_R": 3.93e-3, "T_ref": 20.0, "encoder_offset": 0.0,
    "sat_d": 0.0, "sat_q": 0.0, "sat_dq": 0.0, "exp_d": 2.0, "exp_q": 2.0, "exp_dq_d": 1.0, "exp_dq_q": 1.0,
    "i_ref": 1.0, "sat_b": 0.0, "exp_b": 2.0, "sat_bp": 0.0, "k_q": 0.0, "psi_n": 0.0, "sat_at_zero": 0.0
}

#: Parameters that may be zero or negative: searched additively around the
#: prior in steps of this size (their unit), not as ``ln(theta/prior)``.
ADDITIVE_SCALE: dict[str, float] = {
    "delay": 0.1,
    "v_dead": 0.1,
    "offset_d": 0.01,
    "offset_q": 0.01,
    "offset_a": 0.01,
    "offset_b": 0.01,
    "encoder_offset": 0.05,
    "T_coulomb": 1e-3,
    "T_load": 1e-3,
    "sat_d": 0.1,
    "sat_q": 0.1,
    "sat_dq": 0.1,
    "sat_b": 0.1,
    "sat_bp": 0.1,
    "k_q": 0.1,
    "psi_n": 0.05,
}

#: SI unit of every parameter, for tables and JSON.
UNITS: dict[str, str] = {
    "R": "ohm",
    "Ld": "H",
    "Lq": "H",
    "lambda_m": "Wb",
    "pole_pairs": "-",
    "J": "kg*m^2",
    "B": "N*m*s",
    "delay": "samples",
    "v_dead": "V",
    "offset_d": "A",
    "offset_q": "A",
    "offset_a": "A",
    "offset_b": "A",
    "alpha_R": "1/K",
    "encoder_offset": "rad",
    "T_load": "N*m",
    "T_coulomb": "N*m",
    "w_coulomb": "rad/s",
    "i_dead": "A",
    "T_ref": "degC",
    "sat_d": "-",
    "sat_q": "-",
    "sat_dq": "-",
    "exp_d": "-",
    "exp_q": "-",
    "exp_dq_d": "-",
    "exp_dq_q": "-",
    "i_ref": "A",
    "sat_b": "-",
    "exp_b": "-",
    "sat_bp": "-",
    "k_q": "-",
    "psi_n": "Wb",
    "sat_at_zero": "-",
}

#: One-line meaning of every parameter.
DESCRIPTIONS: dict[str, str] = {
    "R": "stator phase resistance",
    "Ld": "d-axis inductance",
    "Lq": "q-axis inductance",
    "lambda_m": "permanent-magnet flux linkage",
    "pole_pairs": "pole pairs",
    "J": "rotor inertia",
    "B": "viscous friction",
    "delay": "inverter command delay (computation + PWM)",
    "v_dead": "inverter dead-time voltage per phase, device drop included",
    "offset_d": "d-axis current-sensor offset",
    "offset_q": "q-axis current-sensor offset",
    "offset_a": "phase-a current-sensor offset",
    "offset_b": "phase-b current-sensor offset",
    "alpha_R": "temperature coefficient of R",
    "encoder_offset": "encoder zero's offset from the d axis (electrical): the angle column reads theta_e + offset",
    "T_load": "load torque",
    "T_coulomb": "Coulomb (dry) friction torque",
    "w_coulomb": "speed width of the Coulomb friction's sign",
    "i_dead": "current width of the dead-time transition",
    "T_ref": "temperature at which R is stated",
    "sat_d": "d-axis self-saturation (per unit at i_ref)",
    "sat_q": "q-axis self-saturation (per unit at i_ref)",
    "sat_dq": "cross-saturation between the axes (per unit at i_ref)",
    "exp_d": "exponent of the d-axis self-saturation (Hinkkanen's S)",
    "exp_q": "exponent of the q-axis self-saturation (Hinkkanen's T)",
    "exp_dq_d": "d exponent of the cross-saturation (Hinkkanen's U)",
    "exp_dq_q": "q exponent of the cross-saturation (Hinkkanen's V)",
    "i_ref": "reference current of the saturation coefficients",
    "sat_b": "iron-bridge saturation of a PM-assisted motor (per unit at i_ref)",
    "exp_b": "exponent of the iron bridge's saturation (Lelli's W)",
    "sat_bp": "the iron bridge's own saturation limit (Lelli's a_bp, per unit at i_ref)",
    "k_q": "weight of the q flux in the iron bridge's saturation (Lelli's k_q)",
    "psi_n": "flux of the magnet's Norton equivalent that the iron bridge carries (Lelli's psi_n)",
    "sat_at_zero": "1: self- and cross-saturation written about zero flux (Hinkkanen's form); 0: about the magnet's",
}
