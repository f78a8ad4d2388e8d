"""Phase bench files: phase quantities and a rotor angle turned into dq columns, after their own checks.

Two checks belong to phase data alone, each refusing in one sentence with the fix:

- **An angle in degrees.** ``theta_e`` / ``theta_m`` are radians. A column is read
  as degrees when it wraps as a degree angle does: within a segment some step
  between samples exceeds 180 in magnitude, while every value lies within
  ±360 (1 % margin) and the largest beyond 2π (1 % margin). A radian angle,
  wrapped at 2π (steps of at most ~2π) or unwrapped (growing without bound, by
  less than π a sample for any rotor the angle sensor can follow), never does.
  A degree angle that never wraps cannot be told from a radian one and is not
  refused.
- **A third phase that contradicts the other two.** In a three-wire winding
  ``i_a + i_b + i_c = 0``. ``i_c`` is refused when the median of
  ``|i_a + i_b + i_c|`` exceeds both 5 times the sum's own noise level (MAD of
  second differences) and 5 % of the phase currents' RMS: a sign or scaling
  error of the sensor, or another channel. ``v_c`` is refused on the same
  figures only when the mismatch also follows ``v_c`` (correlation above 0.9):
  a common-mode (zero-sequence) voltage, as pole voltages against the DC link
  carry, is legitimate and removed by the Clarke transform.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import DataError
from ..physics import abc_to_dq
from ._values import check_numbers

#: The median mismatch of a third phase, as a multiple of its noise level and a fraction of the RMS,
#: beyond which the third phase is refused.
THIRD_PHASE_NOISE_FACTOR = 5.0
THIRD_PHASE_RMS_FRACTION = 0.05


def _noise(x: np.ndarray) -> float:
    """Noise level of ``x`` from its second differences (MAD; 0 for fewer than 4 samples)."""
    if x.size < 4:
        return 0.0
    d2 = np.diff(x, 2)
    return float(np.median(np.abs(d2 - np.median(d2)))) / 0.6745 / math.sqrt(6.0)


def _segment_starts(frame: dict) -> np.ndarray:
    """(N - 1,) whether each step between samples crosses into another segment (by the raw segment labels)."""
    seg = frame.get("segment")
    n = next(iter(frame.values())).shape[0]
    if seg is None or seg.shape[0] != n:
        return np.zeros(max(n - 1, 0), dtype=bool)
    labels = np.array([str(x).strip() for x in seg], dtype=object)
    return labels[1:] != labels[:-1]


def _check_degrees(name: str, theta: np.ndarray, boundary: np.ndarray, source: str) -> None:
    """Refuse an angle column that wraps as a degree angle does (see the module's docstring)."""
    if theta.size < 2:
        return
    largest = float(np.max(np.abs(theta)))
    if not (2.0 * math.pi * 1.01 < largest <= 360.0 * 1.01):
        return
    step = np.abs(np.diff(theta))
    step[boundary] = 0.0
    k = int(np.argmax(step))
    if step[k] > 180.0:
        raise DataError(
            f"{source}: column '{name}' looks like degrees (max {largest:.4g}, wrapping by {step[k]:.4g} between "
            f"data rows {k + 1} and {k + 2}); give the angle in radians (multiply by pi/180)."
        )


def _check_third_phase(frame: dict, prefix: str, source: str) -> None:
    """Refuse ``<prefix>_c`` when ``a + b + c`` is far from zero (see the module's docstring)."""
    name = f"{prefix}_c"
    if name not in frame:
        return
    a, b, c = (frame[f"{prefix}_{p}"].astype(float) for p in "abc")
    total = a + b + c
    mismatch = float(np.median(np.abs(total)))
    rms = float(np.sqrt(np.mean((a * a + b * b + c * c) / 3.0)))
    if not (mismatch > THIRD_PHASE_NOISE_FACTOR * _noise(total) and mismatch > THIRD_PHASE_RMS_FRACTION * rms):
        return
    if prefix == "v":
        with np.errstate(invalid="ignore", divide="ignore"):
            follows = abs(float(np.corrcoef(total, c)[0, 1])) > 0.9 if np.std(c) > 0 and np.std(total) > 0 else False
        if not follows:
            return  # a common-mode voltage: removed by the Clarke transform
    unit = "A" if prefix == "i" else "V"
    raise DataError(
        f"{source}: column '{name}' contradicts {prefix}_a + {prefix}_b + {prefix}_c = 0 (median "
        f"|{prefix}_a + {prefix}_b + {prefix}_c| {mismatch:.3g} {unit} against {rms:.3g} {unit} RMS per phase); "
        f"drop column '{name}' (it is then taken as -{prefix}_a - {prefix}_b) or check its sensor's sign and scaling."
    )


def _clarke_park(columns: dict, prefix: str, theta_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude-invariant Clarke then Park of phase quantities ``<prefix>_a/b(/c)``."""
    a, b = columns[f"{prefix}_a"].astype(float), columns[f"{prefix}_b"].astype(float)
    # Without the third phase, assume no zero-sequence component: c = -a - b.
    c = columns[f"{prefix}_c"].astype(float) if f"{prefix}_c" in columns else None
    return abc_to_dq(a, b, c, theta_e, xp=np)


def phase_to_dq(frame: dict, source: str, pole_pairs: float) -> dict:
    """Replace phase columns by dq columns (amplitude-invariant transforms), after the phase checks."""
    for name in ("i_b", "v_a", "v_b"):
        if name not in frame:
            raise DataError(f"{source}: phase data needs column '{name}' (with i_a, i_b, v_a, v_b, optional i_c, v_c).")
    angles = [c for c in ("theta_e", "theta_m") if c in frame]
    check_numbers(frame, source, [c for c in frame if c[:2] in ("i_", "v_")] + angles)
    if not angles:
        raise DataError(
            f"{source}: phase data needs a rotor angle column: 'theta_e' (electrical, rad) or "
            "'theta_m' (mechanical, rad; multiplied by pole_pairs from the motor file)."
        )
    boundary = _segment_starts(frame)
    for name in angles:
        _check_degrees(name, frame[name].astype(float), boundary, source)
    out = dict(frame)
    with np.errstate(over="ignore", invalid="ignore"):
        for prefix in ("i", "v"):
            _check_third_phase(frame, prefix, source)
        theta_e = frame["theta_e"].astype(float) if "theta_e" in frame else pole_pairs * frame["theta_m"].astype(float)
        out["theta_e"] = theta_e
        out["i_d"], out["i_q"] = _clarke_park(frame, "i", theta_e)
        out["v_d"], out["v_q"] = _clarke_park(frame, "v", theta_e)
    for prefix in ("i", "v"):
        if not (np.all(np.isfinite(out[f"{prefix}_d"])) and np.all(np.isfinite(out[f"{prefix}_q"]))):
            names = "/".join(c for c in frame if c[:2] == f"{prefix}_" and c[2:] in ("a", "b", "c"))
            raise DataError(f"{source}: columns {names} hold values too large to turn into dq (up to "
                            f"{max(float(np.max(np.abs(frame[c]))) for c in names.split('/')):.3g}); give "
                            f"{'currents in A' if prefix == 'i' else 'voltages in V'}.")
    return out
