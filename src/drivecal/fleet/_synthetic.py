"""Synthetic production runs: bench files of a fleet of motors with a manufacturing spread and planted faults.

Currents and speed come from drivecal's forward model (``model.simulate_states``),
all motors of a run at once, plus Gaussian sensor noise.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from ..data import BenchData
from ..model import Experiment, simulate_states
from ..physics import ESTIMATED, MotorParams


@functools.partial(jax.jit, static_argnames=("names",))
def _fleet_states(theta: jnp.ndarray, nominal: MotorParams, experiment: Experiment, names) -> jnp.ndarray:
    return jax.vmap(lambda th: predict_currents_and_speed(nominal.with_vector(names, th), experiment))(theta)


def predict_currents_and_speed(motor: MotorParams, experiment: Experiment) -> jnp.ndarray:
    """``[i_d, i_q, w_m]`` (A, A, rad/s) at every sample, shape (M, 3)."""
    return simulate_states(motor, experiment, keep=3)


def synthetic_fleet(
    directory: str | os.PathLike,
    count: int,
    *,
    plan=None,
    nominal: MotorParams | None = None,
    spread: float = 0.02,
    noise: float = 0.02,
    seed: int = 0,
    outliers: dict[int, dict[str, float]] | None = None,
    suffix: str = ".parquet",
) -> pd.DataFrame:
    """Write ``count`` bench files of a synthetic production run; return the true parameters.

    Each motor's R, Ld, Lq, lambda_m are the nominal values times
    ``1 + spread * N(0, 1)`` (manufacturing spread); ``outliers`` maps a motor
    index to factors that plant a fault (``{"lambda_m": 0.85}``: a demagnetised
    rotor). Currents and speed come from drivecal's forward model (equal to
    the Jaxonomy engine to ~1e-9 A, and thousands of times faster for a fleet)
    plus Gaussian current noise of ``noise`` A. Files are named
    ``SN<index>.<suffix>`` and carry a ``serial`` column.
    """
    from ..physics import DEFAULT_MOTOR
    from ..plan import default_plan

    plan = plan or default_plan()
    nominal = nominal or DEFAULT_MOTOR
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    theta = np.asarray(nominal.vector(ESTIMATED)) * (1.0 + spread * rng.standard_normal((count, len(ESTIMATED))))
    planted = np.zeros(count, dtype=bool)
    for index, factors in (outliers or {}).items():
        for name, factor in factors.items():
            theta[index, ESTIMATED.index(name)] *= factor
        planted[index] = True
    experiment = Experiment.from_plan(plan)
    template = BenchData(
        tuple(
            dataclasses.replace(s, currents=np.zeros((s.num_samples, 2)), w_m=np.zeros(s.num_samples))
            for s in _plan_segments(plan)
        ),
        plan.sample_rate,
    ).to_frame()
    serials = [f"SN{i:06d}" for i in range(count)]
    for start in range(0, count, 512):
        states = np.asarray(_fleet_states(jnp.asarray(theta[start : start + 512]), nominal, experiment, ESTIMATED))
        for k, x in enumerate(states, start):
            frame = template.assign(
                i_d=x[:, 0] + noise * rng.standard_normal(len(x)),
                i_q=x[:, 1] + noise * rng.standard_normal(len(x)),
                w_m=np.where(template["locked"] == 1, 0.0, x[:, 2]),
                serial=serials[k],
            )
            path = directory / f"{serials[k]}{suffix}"
            if suffix == ".parquet":
                frame.to_parquet(path, index=False)
            else:
                frame.to_csv(path, index=False, float_format="%.17g")
    truth = pd.DataFrame(theta, columns=list(ESTIMATED))
    truth.insert(0, "serial", serials)
    truth["planted_outlier"] = planted
    return truth


def _plan_segments(plan):
    from ..data import SegmentData

    for seg in plan.segments:
        n = seg.num_samples(plan.sample_rate)
        yield SegmentData(seg.name, seg.locked, np.arange(n) / plan.sample_rate, seg.voltages(plan.sample_rate),
                          np.zeros((n, 2)))
