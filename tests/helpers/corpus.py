"""Auto-plan validated on a corpus of real motors: plan, run on the engine, fit, compare.

For each motor of a table such as ``shared/data/motors.csv`` (566 real PMSMs):

1. **datasheet**: the true R, Ld, Lq, lambda_m each off by a seeded uniform
   factor in ``1 +- PRIOR_SPREAD`` (a datasheet good to 10 %); pole pairs, J
   and B are known;
2. **bench limits**: current limit ``CURRENT_LIMIT_FACTOR * i_rated``, the
   table's V_dc and rated speed (max_speed), an inverter without dead time;
3. **plan**: :func:`drivecal.autoplan.auto_design` on the datasheet motor
   (feasible and identifiable, or the motor fails with the reason);
4. **bench**: the plan run on the Jaxonomy engine with the *true* motor
   (:func:`drivecal.stepbench.step_engine_bench`), plus seeded Gaussian
   sensor noise of ``NOISE_FRACTION`` of the current limit (full scale);
5. **fit**: :func:`drivecal.fitting.fit` from the datasheet values (the prior; the estimates are
   judged here, so the fit is not also given a verdict);
6. **verdict**: each estimate's distance to the truth in standard errors;
   within ``PASS_SE`` passes. With 566 x 4 estimates, 3 SE would fail about
   six times by chance (0.27 % each); 4 SE fails with probability 6e-5 each,
   about 0.14 in the whole corpus.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Callable, Iterable

import jax
import numpy as np

from drivecal.design import NOISE_FRACTION, auto_design
from drivecal import DrivecalError
from drivecal.fitting import fit
from drivecal.physics import ESTIMATED, MotorParams
from drivecal.bench import step_engine_bench

#: Bench current limit as a multiple of the rated current (A/A).
CURRENT_LIMIT_FACTOR = 1.5
#: Datasheet error: each of R, Ld, Lq, lambda_m off by a uniform factor in 1 +- this.
PRIOR_SPREAD = 0.10
#: An estimate passes within this many standard errors of the truth.
PASS_SE = 4.0
_COLUMNS = ("motor", "R", "Ld", "Lq", "lambda_m", "pole_pairs", "v_dc", "i_rated", "w_rated", "J", "B")


@dataclasses.dataclass(frozen=True)
class CorpusMotor:
    """One row of the corpus: the true motor and its bench.

    Attributes:
        name: row id (e.g. ``m000``).
        motor: the true parameters (SI).
        v_dc: DC-link voltage (V).
        i_rated: rated current (A).
        w_rated: rated mechanical speed (rad/s), the bench's max_speed.
    """

    name: str
    motor: MotorParams
    v_dc: float
    i_rated: float
    w_rated: float

    @property
    def current_limit(self) -> float:
        """``CURRENT_LIMIT_FACTOR * i_rated`` (A)."""
        return CURRENT_LIMIT_FACTOR * self.i_rated

    @property
    def noise_sigma(self) -> float:
        """Sensor noise: ``NOISE_FRACTION`` of the current limit (A)."""
        return NOISE_FRACTION * self.current_limit


def load_corpus(path: str | Path) -> list[CorpusMotor]:
    """The motors of a corpus CSV (columns as ``shared/data/motors.csv``, SI units)."""
    import pandas as pd

    frame = pd.read_csv(path)
    missing = [c for c in _COLUMNS if c not in frame]
    if missing:
        raise DrivecalError(f"{path}: missing column(s) {', '.join(missing)}; expected {', '.join(_COLUMNS)}.")
    return [
        CorpusMotor(
            name=str(row.motor),
            motor=MotorParams(R=float(row.R), Ld=float(row.Ld), Lq=float(row.Lq), lambda_m=float(row.lambda_m),
                              pole_pairs=float(row.pole_pairs), J=float(row.J), B=float(row.B)),
            v_dc=float(row.v_dc), i_rated=float(row.i_rated), w_rated=float(row.w_rated))
        for row in frame.itertuples(index=False)
    ]


#: Ten motors of the corpus spanning it: R from 7 mOhm to 95 Ohm, V_dc from 12 to 1200 V, two salient ones
#: (m030, m014), one whose time constant needs 40 kHz (m505), one whose PWM ripple needs 32 kHz (m020).
#: tests/design/test_bench_limits.py runs each end to end with its real limits and dead time.
TEN = ("m022", "m030", "m402", "m019", "m020", "m014", "m001", "m181", "m505", "m062")


def corpus_sample(motors: list[CorpusMotor], size: int = 50) -> list[CorpusMotor]:
    """A fixed sample: the extremes, then motors evenly spread in electrical time constant.

    Extremes: smallest and largest R, Ld, Lq, lambda_m, pole pairs, V_dc,
    rated current and speed, electrical time constant ``min(L)/R``,
    mechanical time constant, and saliency ``Lq/Ld``.
    """
    def tau(c):
        return min(float(c.motor.Ld), float(c.motor.Lq)) / float(c.motor.R)

    def tau_m(c):
        m = c.motor
        return float(m.J) * float(m.R) / (1.5 * float(m.pole_pairs) ** 2 * float(m.lambda_m) ** 2)

    keys: list[Callable[[CorpusMotor], float]] = [
        lambda c: float(c.motor.R), lambda c: float(c.motor.Ld), lambda c: float(c.motor.Lq),
        lambda c: float(c.motor.lambda_m), lambda c: float(c.motor.pole_pairs), lambda c: c.v_dc,
        lambda c: c.i_rated, lambda c: c.w_rated, tau, tau_m, lambda c: float(c.motor.Lq) / float(c.motor.Ld)]
    chosen: list[int] = []
    for key in keys:
        values = [key(c) for c in motors]
        for i in (int(np.argmin(values)), int(np.argmax(values))):
            if i not in chosen:
                chosen.append(i)
    order = sorted(range(len(motors)), key=lambda i: tau(motors[i]))
    rest = [i for i in order if i not in chosen]
    need = max(size - len(chosen), 0)
    if need and rest:
        picks = np.unique(np.round(np.linspace(0, len(rest) - 1, num=min(need, len(rest)))).astype(int))
        chosen += [rest[k] for k in picks]
    return [motors[i] for i in chosen]


def datasheet(truth: MotorParams, rng: np.random.Generator) -> MotorParams:
    """``truth`` with R, Ld, Lq, lambda_m each scaled by a uniform factor in ``1 +- PRIOR_SPREAD``."""
    factors = rng.uniform(1.0 - PRIOR_SPREAD, 1.0 + PRIOR_SPREAD, size=len(ESTIMATED))
    return truth.replace(**{n: float(getattr(truth, n)) * f for n, f in zip(ESTIMATED, factors)})


@dataclasses.dataclass(frozen=True)
class MotorResult:
    """How one corpus motor fared.

    Attributes:
        name: row id.
        error: why no plan or fit came out (None when one did).
        sample_rate: plan sample rate (Hz).
        num_samples: samples in the plan.
        duration: plan length (s).
        condition_number: of the plan's Jacobian at the datasheet motor.
        truth, prior, estimate, se: per parameter of ``names`` (SI).
        converged: the LM fit ended successfully.
        seconds: wall time of plan, engine and fit (s).
    """

    name: str
    error: str | None = None
    sample_rate: float = math.nan
    num_samples: int = 0
    duration: float = math.nan
    condition_number: float = math.nan
    names: tuple[str, ...] = ESTIMATED
    truth: tuple[float, ...] = ()
    prior: tuple[float, ...] = ()
    estimate: tuple[float, ...] = ()
    se: tuple[float, ...] = ()
    converged: bool = False
    seconds: dict[str, float] = dataclasses.field(default_factory=dict)

    @property
    def z(self) -> np.ndarray:
        """(estimate - truth) / se per parameter (NaN where not estimated)."""
        if not self.estimate:
            return np.full(len(self.names), np.nan)
        return (np.asarray(self.estimate) - np.asarray(self.truth)) / np.asarray(self.se)

    @property
    def passes(self) -> np.ndarray:
        """Per parameter: fitted, converged and within ``PASS_SE`` standard errors."""
        z = self.z
        return np.isfinite(z) & (np.abs(z) <= PASS_SE) & bool(self.converged)

    @property
    def passed(self) -> bool:
        return self.error is None and bool(np.all(self.passes))

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "motor": self.name, "passed": self.passed, "error": self.error, "converged": self.converged,
            "sample_rate": num(self.sample_rate), "num_samples": self.num_samples, "duration": num(self.duration),
            "condition_number": num(self.condition_number),
            "parameters": {n: {"truth": num(t), "prior": num(p), "estimate": num(e), "se": num(s), "z": num(z)}
                           for n, t, p, e, s, z in zip(self.names, self.truth, self.prior, self.estimate, self.se,
                                                       self.z)},
            "seconds": self.seconds,
        }


def validate_motor(entry: CorpusMotor, seed: int | tuple[int, ...]) -> MotorResult:
    """Datasheet -> auto-plan -> engine bench with noise -> fit, for one corpus motor (numpy seed)."""
    rng = np.random.default_rng(seed)
    prior = datasheet(entry.motor, rng)
    truth = tuple(float(getattr(entry.motor, n)) for n in ESTIMATED)
    seconds = {}
    t0 = time.perf_counter()
    try:
        # An inverter that compensates its dead time (dead_time=0): the truth has none, so the plan must not add
        # a dead-time drop to its steps (tests/design/test_bench_limits.py runs ten motors with one).
        report = auto_design(prior, v_dc=entry.v_dc, current_limit=entry.current_limit, max_speed=entry.w_rated,
                             noise_sigma=entry.noise_sigma, dead_time=0.0)
    except DrivecalError as exc:
        return MotorResult(entry.name, error=f"no plan: {exc}", truth=truth)
    plan = report.plan
    t1 = time.perf_counter()
    bench = step_engine_bench(plan, entry.motor)
    bench = bench.add_noise(entry.noise_sigma, int(rng.integers(2**31)))
    t2 = time.perf_counter()
    cal = fit(bench, prior)
    t3 = time.perf_counter()
    seconds = {"plan": t1 - t0, "engine": t2 - t1, "fit": t3 - t2}
    return MotorResult(
        name=entry.name,
        sample_rate=plan.sample_rate,
        num_samples=plan.num_samples,
        duration=sum(s.duration for s in plan.segments),
        condition_number=report.identifiability.condition_number,
        names=tuple(cal.names),
        truth=truth,
        prior=tuple(float(getattr(prior, n)) for n in cal.names),
        estimate=tuple(float(x) for x in cal.estimate),
        se=tuple(float(x) for x in cal.se),
        converged=bool(cal.converged),
        seconds=seconds,
    )


def validate(motors: Iterable[CorpusMotor], *, seed: int = 0,
             progress: Callable[[MotorResult], None] | None = None) -> list[MotorResult]:
    """:func:`validate_motor` for each motor, seeded by ``(seed, row)``; ``progress`` sees each result."""
    results = []
    for entry in motors:
        # Every motor's plan has its own shape, hence its own compiled programs: dropped after each motor, or
        # fifty motors' machine code outgrows the memory (LLVM: "Unable to allocate section memory").
        jax.clear_caches()
        row = int(entry.name.lstrip("m")) if entry.name.lstrip("m").isdigit() else len(results)
        result = validate_motor(entry, seed=(seed, row))
        results.append(result)
        if progress is not None:
            progress(result)
    return results
