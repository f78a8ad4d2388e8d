"""How exact a measured speed is, and what a fit makes of it.

A drive's speed is mostly the difference of an encoder's count: ``w_m[k] = (theta_q[k] - theta_q[k-1]) / Ts``
with ``theta_q`` the angle in whole counts of ``2 pi / counts``. Its values then lie on a lattice of spacing
``q = 2 pi / (counts * Ts)`` (a 4096-count encoder differenced at 1 kHz: steps of 1.53 rad/s), and where the
drive logs faster than it updates the speed, each value is held for several samples. Such a speed is no
exact input: each sample is off by up to half a step (an error of ``q / sqrt(12)`` RMS), held values are
late. :func:`speed_resolution` finds the steps (:func:`speed_lattice`), the update period
(:func:`update_period`) and the noise of a measured speed; :func:`choose_speed` decides from them what a
fit does with it: an input of the electrical equations where its errors are negligible against the
current noise, else by default a second measured output weighed by that noise (``--speed output``).

Why the ratio below. A speed error ``dw`` acts on the currents as a voltage error ``p * psi * dw`` (``psi``
the flux linkage, ``lambda_m`` on q, ``Lq i_q`` on d), which the winding turns into a current error through
``1 / (R + s L)``, at most ``1 / R`` at the slow frequencies where a parameter's sensitivity lies. Against
white current noise ``sigma_i`` per sample, a white speed error of ``sigma_w`` per sample (``sigma_w *
sqrt(hold)`` where each value is held ``hold`` samples: the same error ``hold`` times) thus adds at most
``ratio = (p psi_rms sigma_w / (R sigma_i))^2`` times the current noise's variance to every estimate. Above
:data:`INPUT_ERROR_RATIO_MAX` (10 % of the variance, intervals up to 5 % too narrow) the speed is not
an exact input.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from .._stats import noise_level
from .._parameters import MECHANICAL

if TYPE_CHECKING:  # a type only: reading a log's speed needs no motor model (JAX)
    from ..physics import MotorParams

#: Relative tolerance (of the largest |value|) within which values count as lying on a lattice: float32
#: storage (6e-8) and unit conversions (rpm to rad/s: 1e-16) are well within, chance is far outside.
LATTICE_RTOL = 1e-6
#: A lattice finer than span / this is no quantisation worth the name (and is too fine to be told from
#: the tolerance): no lattice.
LATTICE_MAX_LEVELS = 10_000
#: The speed's errors may add at most this fraction of the current noise's variance to the estimates
#: before it is no longer an exact input (see the module docstring).
INPUT_ERROR_RATIO_MAX = 0.1
#: The second-difference noise level (``_stats.noise_level``) that rounding to a lattice alone shows, in
#: steps: 0.605 on count differences of spin-ups of 10-100 ms time constant at 1 and 20 kHz, every one.
ROUNDING_NOISE_LEVEL = 0.605
#: Currents whose noise is below this fraction of their peak are noise-free (synthetic): the ratio is not judged.
NOISE_FLOOR = 1e-6
#: Whole counts per revolution within this relative distance name an encoder (16 counts at least).
_COUNTS_RTOL = 1e-4


def _float_gcd(a: float, b: float, tol: float) -> float:
    """The largest ``g`` of which ``a`` and ``b`` (>= 0) are whole multiples within ``tol`` (Euclid)."""
    a, b = max(a, b), min(a, b)
    while b > tol:
        r = math.fmod(a, b)
        if b - r <= tol:
            r = 0.0
        a, b = b, r
    return a


def speed_lattice(values: np.ndarray) -> float | None:
    """The spacing of the lattice the values lie on (their unit), or None when they lie on none.

    The values' distinct levels must number at least three and every gap between them be a whole
    multiple of one step within :data:`LATTICE_RTOL` of the largest value, with at most
    :data:`LATTICE_MAX_LEVELS` steps across their span. An offset (``n q + c``) is allowed.
    """
    w = np.asarray(values, dtype=float).ravel()
    levels = np.unique(w[np.isfinite(w)])
    if levels.size < 3:
        return None
    span = float(levels[-1] - levels[0])
    tol = LATTICE_RTOL * max(float(np.max(np.abs(levels))), span)
    gaps = np.diff(levels)
    step = float(gaps[0])
    for g in gaps[1:]:
        step = _float_gcd(step, float(g), tol)
        if step * LATTICE_MAX_LEVELS < span:
            return None
    if step * LATTICE_MAX_LEVELS < span or step <= 4 * tol:
        return None
    off = np.abs(gaps - np.round(gaps / step) * step)
    if not bool(np.all(off <= 4 * tol)):
        return None
    whole = np.round((levels - levels[0]) / step)  # the step by least squares over every level: float32 to 1e-7
    return float(whole @ (levels - levels[0]) / (whole @ whole))


def update_period(series: list[np.ndarray]) -> int:
    """Samples per update of a held signal: the greatest common divisor of the distances between the
    samples where any series changes value (1 where fewer than three changes show it)."""
    distances = []
    for w in series:
        changes = np.flatnonzero(np.diff(np.asarray(w, dtype=float)) != 0.0)
        distances.extend(np.diff(changes).tolist())
    if len(distances) < 2:
        return 1
    return max(int(np.gcd.reduce(np.asarray(distances, dtype=np.int64))), 1)


@dataclasses.dataclass(frozen=True)
class SpeedResolution:
    """How exact a measured speed is.

    Attributes:
        step: the lattice spacing of its values (rad/s), or None when continuous.
        hold: samples per update (1: a new value every sample).
        noise: its robust second-difference noise level (rad/s), median over the free segments.
        sample_rate: the bench's sample rate (Hz).
        span: its largest magnitude (rad/s).
    """

    step: float | None
    hold: int
    noise: float
    sample_rate: float
    span: float

    @property
    def quantisation(self) -> float:
        """The RMS error of the steps (rad/s); 0 when continuous. A difference of two counts holds two
        rounding errors, ``step / sqrt(6)`` (over spin-ups at 1 and 20 kHz: 0.36-0.45 of a step); a value
        rounded once (not a count difference, :attr:`counts_per_rev` None) ``step / sqrt(12)``."""
        if self.step is None:
            return 0.0
        return self.step / math.sqrt(6.0 if self.counts_per_rev is not None else 12.0)

    @property
    def sigma(self) -> float:
        """The per-sample noise a fit weighs the speed by (rad/s): the quantisation and the noise beyond
        what rounding alone shows (:data:`ROUNDING_NOISE_LEVEL`), root-sum-square, times ``sqrt(hold)``
        (a held error repeats); at least 1e-9 of the span (1e-12 rad/s)."""
        rounding = 0.0 if self.step is None else ROUNDING_NOISE_LEVEL * self.step
        beyond = math.sqrt(max(self.noise**2 - rounding**2, 0.0))
        return max(math.hypot(self.quantisation, beyond) * math.sqrt(self.hold), 1e-9 * self.span, 1e-12)

    @property
    def counts_per_rev(self) -> float | None:
        """The encoder's counts per revolution if the steps are one count per update period, else None."""
        if self.step is None or not math.isfinite(self.sample_rate):
            return None
        counts = 2.0 * math.pi * self.sample_rate / self.hold / self.step
        whole = round(counts)
        return float(whole) if whole >= 16 and abs(counts - whole) <= _COUNTS_RTOL * counts else None

    def describe(self) -> str:
        """In words: "steps of 1.534 rad/s: one count of a 4096-count encoder per 1 ms, new every sample"."""
        if self.step is None:
            return f"no steps, noise {self.noise:.3g} rad/s"
        text = f"steps of {self.step:.4g} rad/s"
        if self.counts_per_rev is not None:
            text += (f": one count of a {self.counts_per_rev:.0f}-count encoder per "
                     f"{1e3 * self.hold / self.sample_rate:.4g} ms")
        return text + (", new every sample" if self.hold == 1 else f", each held {self.hold} samples")

    def to_dict(self) -> dict[str, Any]:
        return {"summary": self.describe(), "step": self.step, "hold": self.hold, "noise": self.noise, "quantisation": self.quantisation,
                "sigma": self.sigma, "counts_per_rev": self.counts_per_rev}


def speed_resolution(speeds: list[np.ndarray], sample_rate: float) -> SpeedResolution | None:
    """The resolution of the measured speeds of a bench's free segments (rad/s each), or None if none."""
    speeds = [np.asarray(w, dtype=float) for w in speeds]
    if not speeds:
        return None
    return SpeedResolution(step=speed_lattice(np.concatenate(speeds)), hold=update_period(speeds),
                           noise=float(np.median([noise_level(w) for w in speeds])), sample_rate=float(sample_rate),
                           span=max(float(np.max(np.abs(w), initial=0.0)) for w in speeds))


def input_error_ratio(speed_noise: float, motor: MotorParams, currents: np.ndarray, current_noise: float) -> float:
    """At most how much of the current noise's variance a speed of per-sample noise ``speed_noise`` (rad/s;
    ``SpeedResolution.sigma``) adds to the estimates as an exact input (the module docstring's ``ratio``);
    ``currents``: ``[i_d, i_q]`` (A) where the speed is measured."""
    i_d, i_q = np.asarray(currents, dtype=float).T
    psi = math.sqrt(float(np.mean((float(motor.lambda_m) + float(motor.Ld) * i_d) ** 2
                                  + (float(motor.Lq) * i_q) ** 2)))
    ratio = float(motor.pole_pairs) * psi * speed_noise / (float(motor.R) * current_noise)
    return ratio**2


@dataclasses.dataclass(frozen=True)
class SpeedChoice:
    """What a fit makes of a measured speed, and why.

    Attributes:
        mode: "input", "output" or "ignore" (``BenchData.experiment``'s ``speed``).
        requested: the mode asked for (``--speed``, ``--measured-speed``), or None: chosen by default.
        resolution: the measured speed's resolution, or None without one.
        ratio: :func:`input_error_ratio` at the prior, or None without a measured speed or a measurable
            current noise (noise-free currents, below :data:`NOISE_FLOOR` of their peak).
        flagged: the speed is too coarse or noisy to be an exact input (``ratio`` above
            :data:`INPUT_ERROR_RATIO_MAX`).
        reason: one line for the user (empty where there is nothing to say).
    """

    mode: str
    requested: str | None = None
    resolution: SpeedResolution | None = None
    ratio: float | None = None
    flagged: bool = False
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The result JSON's ``speed`` section."""
        return {"mode": self.mode, "requested": self.requested, "flagged": self.flagged,
                "input_error_ratio": self.ratio, "input_error_ratio_max": INPUT_ERROR_RATIO_MAX,
                "resolution": None if self.resolution is None else self.resolution.to_dict(),
                "reason": self.reason or None}


def choose_speed(bench, motor: MotorParams, names: tuple[str, ...], *, speed: str | None = None,
                 current_noise: float | None = None, speed_noise: float | None = None,
                 mechanics_given: bool = True) -> SpeedChoice:
    """What a fit of ``bench`` makes of its measured speed.

    ``speed`` given (``--speed``, or the legacy flags turned into it) is obeyed, a flagged speed used as an
    input noted in ``reason`` (empty where nothing changed or needs saying). Otherwise: a second output where mechanics are estimated; else an input
    unless the speed is flagged (:data:`INPUT_ERROR_RATIO_MAX`), when it becomes a second output weighed by
    its resolution (``SpeedResolution.sigma``, unless a ``speed_noise`` is stated) if the motor's J and B are
    known (``mechanics_given``); without them it stays an input and ``reason`` says so.

    Args:
        bench: the :class:`BenchData`.
        motor: the prior (p, R, Ld, Lq, lambda_m of the ratio).
        names: the parameters to estimate.
        current_noise, speed_noise: the sensors' noise (A, rad/s) where stated; the current's else estimated
            from the samples, the speed's else its resolution's (``SpeedResolution.sigma``).
    """
    default = "output" if any(n in MECHANICAL for n in names) else "input"
    if not bench.has_measured_speed:
        return SpeedChoice(speed or default, speed)
    resolution = bench.speed_resolution()
    free = np.concatenate([s.currents for s in bench.segments if s.w_m is not None and not s.locked])
    sigma_i = current_noise or bench.noise_levels()[0]
    if not sigma_i > NOISE_FLOOR * float(np.max(np.abs(bench.currents), initial=0.0)):
        return SpeedChoice(speed or default, speed, resolution)  # noise-free currents: nothing to weigh against
    ratio = input_error_ratio(max(resolution.sigma, speed_noise or 0.0), motor, free, sigma_i)
    flagged = ratio > INPUT_ERROR_RATIO_MAX
    if not flagged:
        return SpeedChoice(speed or default, speed, resolution, ratio)
    what = (f"measured speed w_m ({resolution.describe()}): as an exact input its errors could add up to "
            f"{ratio:.3g} times the current noise's variance to the estimates (limit {INPUT_ERROR_RATIO_MAX:g})")
    weight = (f"{speed_noise:.3g} rad/s, stated" if speed_noise else f"{resolution.sigma:.3g} rad/s, from its "
              "resolution")
    if speed is not None:  # as asked: only an input is worth a word
        why = f"{what}; an input as asked (--speed input); --speed output or --simulated-speed would not take it as exact"
        return SpeedChoice(speed, speed, resolution, ratio, True, why if speed == "input" else "")
    if default == "output":  # mechanics estimated: a second output anyway
        return SpeedChoice("output", None, resolution, ratio, True)
    if mechanics_given:
        return SpeedChoice("output", None, resolution, ratio, True,
                           f"{what}; so a second measured output instead (noise {weight}, the "
                           "speed simulated from the motor file's J and B; --speed input to override)")
    return SpeedChoice("input", None, resolution, ratio, True,
                       f"{what}; kept as the input because the motor file states no J and B to simulate it from "
                       "(give them and --speed output, or --simulated-speed)")
