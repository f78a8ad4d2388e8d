"""A `drivecal batch` results table built without fits: a healthy population, planted outliers, a slow drift.

The columns are those `drivecal batch` writes (``fleet/_batch.py``: one row per motor, the estimates with
their SE and 95 % interval, the residual checks, the fleet checks and, with tolerances, the ``spec``
column). Rows come in plain string order of the serials (``SN1, SN10, SN100, ...``), as a file listing
gives them, so a report that trends against the row index would scramble the line.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from drivecal.data import Tolerance
from drivecal.fleet import fleet_checks
from drivecal.physics import DEFAULT_MOTOR, ESTIMATED
from drivecal.results import FAIL, INCONCLUSIVE, judge_arrays

#: Relative manufacturing spread (1 SD) of every parameter.
SPREAD = 0.01
#: Lq's planted drift along the serials: from -DRIFT_SD to +DRIFT_SD spreads, linear in the serial number.
DRIFT_SD = 2.5
DRIFTING = "Lq"
#: serial number -> factors on the nominal (the planted faults).
PLANTED = {17: {"R": 1.4}, 250: {"R": 1.45}, 431: {"R": 1.5}, 123: {"lambda_m": 0.85},
           500: {"R": 0.8, "Ld": 0.8, "Lq": 0.8}}
#: Relative limits of the specification (low, high); None: one-sided.
LIMITS = {"R": (-0.05, 0.05), "Ld": (-0.08, 0.08), "Lq": (-0.08, 0.08), "lambda_m": (-0.03, None)}
INVALID = (77, 301)
NOT_CONVERGED = (402,)


def nominal() -> dict[str, float]:
    return {n: float(getattr(DEFAULT_MOTOR, n)) for n in ESTIMATED}


def tolerances() -> dict[str, tuple[float | None, float | None]]:
    nom = nominal()
    return {n: tuple(None if f is None else nom[n] * (1 + f) for f in lim) for n, lim in LIMITS.items()}


def planted_table(count: int = 600, seed: int = 3, *, spec: bool = True, test_time: bool = False,
                  shuffle: bool = False) -> pd.DataFrame:
    """The results table of ``count`` motors SN1..SN<count> (see the module's docstring); ``shuffle``: the rows in
    random order instead (then only the serial orders the line)."""
    rng = np.random.default_rng(seed)
    number = np.arange(1, count + 1)
    serial = np.array([f"SN{i}" for i in number])
    status = np.full(count, "calibrated", dtype=object)
    status[np.isin(number, INVALID)] = "invalid file"
    status[np.isin(number, NOT_CONVERGED)] = "not converged"
    ok = status == "calibrated"
    nom = nominal()
    columns: dict[str, object] = {
        "serial": serial, "file": [f"line/{s}.parquet" for s in serial], "file_sha256": ["0" * 64] * count,
        "status": status, "reason": np.where(ok, "", np.where(status == "invalid file", "the file has no samples",
                                                                "the fit did not converge")),
        "converged": ok, "message": [""] * count,
        "iterations": np.full(count, 6), "sigma_hat": np.full(count, 0.02), "num_samples": np.full(count, 1400),
        "sample_rate": np.full(count, 20e3), "measured_speed": np.zeros(count, bool),
    }
    for name in ESTIMATED:
        rel = SPREAD * rng.standard_normal(count)
        if name == DRIFTING:
            rel += SPREAD * DRIFT_SD * np.linspace(-1.0, 1.0, count)
        value = nom[name] * (1 + rel)
        for i, factors in PLANTED.items():
            if i <= count and name in factors:
                value[i - 1] = nom[name] * factors[name] * (1 + SPREAD * rng.standard_normal())
        se = 0.002 * np.abs(value)
        columns[name] = np.where(ok, value, np.nan)
        columns[f"{name}_se"] = np.where(ok, se, np.nan)
        columns[f"{name}_ci_low"] = np.where(ok, value - 1.96 * se, np.nan)
        columns[f"{name}_ci_high"] = np.where(ok, value + 1.96 * se, np.nan)
        columns[f"{name}_identifiable"] = np.full(count, True)
    columns["resid_min_p"] = np.where(ok, rng.uniform(0.01, 1.0, count), np.nan)
    mismatch = np.zeros(count, bool)
    mismatch[[i for i in (44, 333) if i < count]] = True
    columns["mismatch"] = mismatch & ok
    columns["effects"] = [""] * count
    if test_time:
        start = pd.Timestamp("2024-05-06 06:00:00")
        columns["test_time"] = start + pd.to_timedelta(number * 90, unit="s")
    table = pd.DataFrame(columns)
    rows = rng.permutation(count) if shuffle else np.argsort(serial, kind="stable")  # random, or plain string order
    table = table.iloc[rows].reset_index(drop=True)
    table = fleet_checks(table, 5.0)
    if spec:
        table = _judge(table)
    return table


def _judge(table: pd.DataFrame) -> pd.DataFrame:
    """The ``spec`` columns as the batch writes them (pass, fail, inconclusive, not calibrated, invalid file)."""
    out = table.copy()
    k = len(out)
    fail, undecided = np.zeros(k, bool), np.zeros(k, bool)
    failed = [[] for _ in range(k)]
    for name, (low, high) in tolerances().items():
        outcome, _ = judge_arrays(out[name], out[f"{name}_ci_low"], out[f"{name}_ci_high"],
                                  out[f"{name}_identifiable"], Tolerance(low, high, "test"))
        fail |= outcome == FAIL
        undecided |= outcome == INCONCLUSIVE
        for i in np.flatnonzero(outcome == FAIL):
            failed[i].append(name)
    usable = (out["status"] == "calibrated") & ~out["mismatch"]
    label = np.where(fail, "fail", np.where(undecided, "inconclusive", "pass"))
    out["spec"] = np.where(usable, label, np.where(out["status"] == "invalid file", "invalid file", "not calibrated"))
    out["spec_failed"] = [", ".join(f) if u else "" for f, u in zip(failed, usable)]
    out["spec_inconclusive"] = ""
    return out
