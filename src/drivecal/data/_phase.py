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

The angle column is taken as it is: an encoder whose zero is off the rotor's d axis reads
``theta_e + encoder_offset`` (electrical, rad), and every dq column this module writes is then turned
by ``-encoder_offset`` (``physics.encoder_frame``). The model corrects it where the motor file gives or
estimates ``encoder_offset``, as a Park transform at ``theta_e - encoder_offset`` would
(``model.in_rotor_frame``); so it does for a dq file's ``theta_e`` column, taken (as for the phase
offsets) as the angle the drive's Park transform used. A dq bench file without an angle column was turned
into dq by the drive with an angle the file does not hold: drivecal does not correct an encoder offset there.

One check holds for any bench file with a turning rotor, phase or dq:

- **Pole pairs.** Where a free segment shows both an electrical rotation (a
  ``theta_e`` column, or else the phase voltages' own rotation) and a mechanical
  one (a ``theta_m`` column, or else the integral of ``w_m``), their ratio is the
  number of pole pairs. A motor file whose ``pole_pairs`` is more than
  :data:`POLE_PAIR_TOLERANCE` away from it is refused, naming the measured ratio
  (a wrong count, or a speed logged in another unit). The voltages' rotation
  includes any turn of the commanded dq voltage's own angle (none for steps and
  spin-ups at a constant command), so it is used only over at
  least :data:`POLE_PAIR_MIN_TURNS` electrical revolutions; an angle column over
  :data:`POLE_PAIR_MIN_ANGLE_TURNS`.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import DataError
from ..physics import abc_to_dq, clarke
from ._values import check_numbers

#: The median mismatch of a third phase, as a multiple of its noise level and a fraction of the RMS,
#: beyond which the third phase is refused.
THIRD_PHASE_NOISE_FACTOR = 5.0
THIRD_PHASE_RMS_FRACTION = 0.05
#: Relative disagreement between the measured electrical-per-mechanical rotation and the motor file's
#: pole_pairs beyond which the file is refused (a wrong count is off by 1/p or more: 25 % at 4 pole pairs).
POLE_PAIR_TOLERANCE = 0.15
#: Electrical revolutions over which the phase voltages' rotation is trusted as the electrical angle's
#: (a commanded dq voltage that itself turns by half a revolution moves the ratio by 1/6 over three).
#: Not the currents': their own dq angle turns with the speed in a spin-up (over the default plan's
#: spin-up the phase currents turn 3.25 times as fast as a 4-pole-pair rotor).
POLE_PAIR_MIN_TURNS = 3.0
#: Electrical revolutions an angle column must show for the check (it is exact; only the speed's
#: integral and noise blur it).
POLE_PAIR_MIN_ANGLE_TURNS = 0.5


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
    check_pole_pairs(frame, source, pole_pairs)
    with np.errstate(over="ignore", invalid="ignore"):
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


def _as_float(x: np.ndarray | None) -> np.ndarray | None:
    """A column of real numbers as float64, or None (absent, or not real numbers: the column checks name it)."""
    x = None if x is None else np.asarray(x)
    return None if x is None or x.dtype.kind not in "biuf" else x.astype(float)


def _turn_steps(angle: np.ndarray) -> np.ndarray:
    """Steps between successive samples of an angle (rad), each wrapped into (-pi, pi], shape (N - 1,)."""
    return np.angle(np.exp(1j * np.diff(angle)))


def check_pole_pairs(frame: dict, source: str, pole_pairs: float) -> None:
    """Refuse ``pole_pairs`` where the free segments' own rotation says otherwise (see the module's docstring).

    Args:
        frame: the bench columns as read (phase or dq), SI units.
        source: the file name, for the message.
        pole_pairs: the motor file's pole pairs (-).
    """
    has = frame.keys()
    if "locked" not in has or ("theta_m" not in has and not {"w_m", "t"} <= has) or (
            "theta_e" not in has and not {"v_a", "v_b"} <= has):
        return  # nothing to compare (a fleet's dq files mostly): decided before converting any column
    t, w_m, locked = _as_float(frame.get("t")), _as_float(frame.get("w_m")), _as_float(frame.get("locked"))
    theta_e, theta_m = _as_float(frame.get("theta_e")), _as_float(frame.get("theta_m"))
    phases = [_as_float(frame.get(c)) for c in ("v_a", "v_b", "v_c")]
    from_voltages = theta_e is None and phases[0] is not None and phases[1] is not None
    if locked is None or (theta_m is None and (w_m is None or t is None)) or (theta_e is None and not from_voltages):
        return
    free = (locked[1:] == 0) & (locked[:-1] == 0) & ~_segment_starts(frame)  # (N - 1,) steps within free segments
    with np.errstate(invalid="ignore", over="ignore"):
        if theta_e is not None:
            electrical = _turn_steps(theta_e)  # an angle column may wrap at 2 pi
        else:
            alpha, beta = clarke(phases[0], phases[1], phases[2])
            size = np.hypot(alpha, beta)
            electrical = _turn_steps(np.arctan2(beta, alpha))
            strong = size > 0.1 * np.nanmax(np.where(np.r_[free, False], size, 0.0), initial=0.0)
            free = free & strong[1:] & strong[:-1]
        mechanical = _turn_steps(theta_m) if theta_m is not None else 0.5 * (w_m[1:] + w_m[:-1]) * np.diff(t)
        e, m = float(np.sum(electrical[free])), float(np.sum(mechanical[free]))
    enough = POLE_PAIR_MIN_TURNS if from_voltages else POLE_PAIR_MIN_ANGLE_TURNS
    if not (math.isfinite(e) and math.isfinite(m)) or m == 0.0 or abs(e) / (2.0 * math.pi) < enough:
        return
    ratio = e / m
    if abs(ratio - pole_pairs) > POLE_PAIR_TOLERANCE * pole_pairs:
        what = "phase voltages turn" if from_voltages else "electrical angle theta_e turns"
        speed = "theta_m" if theta_m is not None else "w_m"
        raise DataError(
            f"{source}: in the free segments the {what} {ratio:.3g} times as fast as the rotor ({speed}), "
            f"but the motor file says pole_pairs = {pole_pairs:g}; set pole_pairs = {max(round(ratio), 1)} in the "
            f"motor file, or check that {speed} is mechanical and in {'rad' if speed == 'theta_m' else 'rad/s'}.")
