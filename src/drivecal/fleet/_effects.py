"""A batch's motors whose residuals are not white, fitted again with the bench effects their data support."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..data import BenchData, MotorFile
from ..selection import select_effects
from ._checks import residual_diagnostics


def select_for(columns: dict[str, Any], i: int, bench: BenchData, path: str, motor_file: MotorFile,
               measured_speed: bool, effects: str | tuple[str, ...]) -> None:
    """Row ``i`` of ``columns`` (a motor whose residuals are not white) fitted again with its bench effects.

    The batch fits every motor without bench effects; only a motor the
    whiteness check flags pays for the effect selection (``selection.select_effects``:
    score tests, and a refit per effect they support), so a fleet of motors
    that need none keeps the batch's speed. Where effects are fitted the
    row takes the new fit (its effect parameters in columns of their own),
    names them in ``effects`` and is judged again on its new residuals.
    """
    experiment = bench.experiment(measured_speed, delay_samples=motor_file.delay_samples)
    sel = select_effects(experiment, bench.currents, motor_file.motor, names=motor_file.names, effects=effects,
                         source=path, magnetics="linear")
    cal = sel.calibration
    if not sel.included or not bool(cal.converged):
        return
    n = len(columns["serial"])
    for j, name in enumerate(cal.names):
        for suffix, value in (("", cal.estimate[j]), ("_se", cal.se[j]), ("_ci_low", cal.ci95[j, 0]),
                              ("_ci_high", cal.ci95[j, 1])):
            column = columns.setdefault(name + suffix, np.full(n, np.nan))
            column[i] = value
        flags = columns.setdefault(f"{name}_identifiable", np.full(n, False))
        flags[i] = bool(cal.identifiable[j])
    diag = residual_diagnostics(np.asarray(cal.residuals)[None], np.asarray(experiment.segment_start))
    columns["sigma_hat"][i] = float(cal.sigma_hat)
    columns["iterations"][i] = int(cal.iterations)
    columns["resid_min_p"][i] = diag["resid_min_p"][0]
    columns["mismatch"][i] = diag["mismatch"][0]
    columns["effects"][i] = ",".join(sel.included)
