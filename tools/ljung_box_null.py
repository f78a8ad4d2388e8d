"""Simulate the null distribution of the Ljung-Box statistic and write drivecal's table of it.

The chi^2(lags) approximation of the Ljung-Box statistic Q is poor in the far
upper tail at the series lengths drivecal tests (segments of 100-1000 samples):
at n = 200 and 10 lags it rejects white noise 2.4x too often at p = 1e-3 and
4x at p = 1.7e-4, the per-test level of the default plan. This script draws
white Gaussian series of each tabulated length, computes Q exactly as
``drivecal.diagnose.ljung_box`` does, and records the upper quantiles of Q at
the tabulated tail probabilities. ``drivecal/diagnose/_ljung_box_table.py`` is
its output (run from the repository root):

    .venv/bin/python tools/ljung_box_null.py > src/drivecal/diagnose/_ljung_box_table.py

Deterministic (seeded); about four minutes on one core.
"""

from __future__ import annotations

import sys
import time

import numpy as np

LAGS = 10
#: Series lengths tabulated (log-spaced); above the last, chi^2 is used (it over-rejects < 1.15x there).
LENGTHS = (16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512, 768, 1024, 1536, 2048)
#: Upper-tail probabilities tabulated.
TAILS = (1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5)
SEED = 20261124


def q_statistic(x: np.ndarray, lags: int) -> np.ndarray:
    n = x.shape[-1]
    d = x - x.mean(axis=-1, keepdims=True)
    denom = np.einsum("...i,...i->...", d, d)
    r = np.stack([np.einsum("...i,...i->...", d[..., :-k], d[..., k:]) for k in range(1, lags + 1)], axis=-1)
    r = r / denom[..., None]
    return n * (n + 2) * np.sum(r**2 / (n - np.arange(1, lags + 1)), axis=-1)


def draws(n: int) -> int:
    """Series drawn at length n: 3e6 where it is cheap, 1e6 for the long series (~100 beyond the 1e-4 quantile)."""
    return 3_000_000 if n <= 256 else 1_000_000


def main() -> None:
    rng = np.random.default_rng(SEED)
    rows = []
    start = time.time()
    for n in LENGTHS:
        total = draws(n)
        chunk = max(1000, min(50_000, 20_000_000 // n))
        qs = np.concatenate([q_statistic(rng.standard_normal((min(chunk, total - k), n)), LAGS)
                             for k in range(0, total, chunk)])
        rows.append([float(np.quantile(qs, 1.0 - p)) for p in TAILS])
        print(f"n={n}: {total} series, {time.time() - start:.0f} s", file=sys.stderr)
    print('"""The Ljung-Box statistic\'s upper quantiles under white Gaussian noise (10 lags), simulated.')
    print()
    print("Written by tools/ljung_box_null.py (seeded; the draws per length are in that script). Do not edit.")
    print('"""')
    print()
    print(f"LAGS = {LAGS}")
    print(f"LENGTHS = {LENGTHS!r}")
    print(f"TAILS = {TAILS!r}")
    print("#: QUANTILES[i][j]: Q exceeded with probability TAILS[j] by a white series of length LENGTHS[i].")
    print("QUANTILES = (")
    for n, row in zip(LENGTHS, rows):
        print("    (" + ", ".join(f"{q:.6g}" for q in row) + "),  # n = " + str(n))
    print(")")


if __name__ == "__main__":
    main()
