"""Flux and incremental-inductance maps of a calibrated motor, each with its 95 % band.

What an engineer takes from a saturating calibration is not the law's coefficients but its maps:
the flux linkages ``psi_d(i_d, i_q)``, ``psi_q(i_d, i_q)`` (Wb) and the incremental inductances
``L_dd``, ``L_dq``, ``L_qq`` (H; ``d psi = [[L_dd, L_dq], [L_dq, L_qq]] d i``) on a grid of currents.
The grid spans the currents the bench data reached (their box, zero included); a grid point is
*tested* where some sample of the data lies within half a grid step of it on both axes, and
*extrapolated* otherwise (a d-axis step and a q-axis step test the two axes, not the corner where both
currents flow: only a combined step does). The bands are first order (the delta method): the maps'
gradient with respect to every estimated parameter, through ``physics.flux_of_currents`` and
``physics.incremental_inductances``, with the fit's covariance and its Student-t factor.

Also given: the small-signal values at zero current (``Ld``, ``Lq`` and ``lambda_m = psi_d(0, 0)``,
the fit's own estimates) and the apparent (chord) inductances ``(psi_d - lambda_m) / i_d`` at
``(i_d, 0)`` and ``psi_q / i_q`` at ``(0, i_q)`` at a chosen current (default: the largest the data
reached on each axis).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..model import RUN_ONCE, cached_call, side_by_side
from ..physics import flux_of_currents, incremental_inductances

#: The maps, in the order of :attr:`FluxMaps.maps`, and their units.
MAPS: dict[str, str] = {"psi_d": "Wb", "psi_q": "Wb", "L_dd": "H", "L_dq": "H", "L_qq": "H"}

#: Grid points per axis by default.
GRID_POINTS = 21


@dataclasses.dataclass(frozen=True)
class MapBand:
    """One map on the grid: ``value``, ``se`` and the 95 % band ``low``, ``high``, each (len(i_d), len(i_q))."""

    value: np.ndarray
    se: np.ndarray
    low: np.ndarray
    high: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {k: _nums(getattr(self, k)) for k in ("value", "se", "low", "high")}


@dataclasses.dataclass(frozen=True)
class FluxMaps:
    """The calibrated motor's flux and inductance maps with their bands (see the module docstring).

    Attributes:
        i_d: (G,) grid of d-axis currents (A).
        i_q: (H,) grid of q-axis currents (A).
        tested: (G, H) whether each grid point lies inside the range the data covered.
        maps: name (``MAPS``) -> :class:`MapBand`, each (G, H), indexed ``[i_d, i_q]``.
        small_signal: ``Ld``, ``Lq`` (H) and ``lambda_m`` (Wb) at zero current: ``(value, se)``.
        apparent: ``Ld``, ``Lq`` chord inductances (H): ``(value, se, at)`` with ``at`` the current
            ``(i_d, i_q)`` (A) they are taken at.
        saturating: whether the calibrated law saturates (else the maps are planes and constants).
    """

    i_d: np.ndarray
    i_q: np.ndarray
    tested: np.ndarray
    maps: dict[str, MapBand]
    small_signal: dict[str, tuple[float, float]]
    apparent: dict[str, tuple[float, float, tuple[float, float]]]
    saturating: bool

    def to_dict(self) -> dict[str, Any]:
        """The result JSON's ``flux_maps`` section (SI units; null where undefined)."""
        return {
            "i_d": _nums(self.i_d), "i_q": _nums(self.i_q), "index": "[i_d][i_q]",
            "units": dict(MAPS, i_d="A", i_q="A"),
            "tested": self.tested.tolist(), "saturating": self.saturating,
            "maps": {k: b.to_dict() for k, b in self.maps.items()},
            "small_signal": {k: {"estimate": _num(v), "se": _num(s)} for k, (v, s) in self.small_signal.items()},
            "apparent": {k: {"estimate": _num(v), "se": _num(s), "at": [_num(a) for a in at]}
                         for k, (v, s, at) in self.apparent.items()},
        }

    def along(self, axis: str) -> list[tuple[float, dict[str, tuple[float, float]], bool]]:
        """The maps along one axis's grid with the other current zero: ``(current, {map: (value, se)}, tested)``.

        ``axis``: ``"d"`` (along ``i_d`` at ``i_q = 0``) or ``"q"``.
        """
        grid, other = (self.i_d, self.i_q) if axis == "d" else (self.i_q, self.i_d)
        k = int(np.argmin(np.abs(other)))
        rows = []
        for j, current in enumerate(grid):
            at = (j, k) if axis == "d" else (k, j)
            rows.append((float(current), {n: (float(b.value[at]), float(b.se[at])) for n, b in self.maps.items()},
                         bool(self.tested[at])))
        return rows

    def __str__(self) -> str:
        lines = ["flux maps (95 % bands; * extrapolated beyond the tested range)"]
        for axis, flux, ind in (("d", "psi_d", "L_dd"), ("q", "psi_q", "L_qq")):
            lines.append(f"  along i_{axis} (other current 0):  i_{axis} [A]   {flux} [Wb]            {ind} [mH]")
            rows = self.along(axis)
            for current, vals, tested in rows[:: max(1, len(rows) // 6)]:
                (f, fs), (ell, ls) = vals[flux], vals[ind]
                lines.append(f"  {'' if tested else '*':>34}{current:8.3g}   {f:.5g} ± {1.96 * fs:.2g}"
                             f"    {1e3 * ell:.4g} ± {1.96e3 * ls:.2g}")
        for k, (v, s) in self.small_signal.items():
            unit = "Wb" if k == "lambda_m" else "H"
            lines.append(f"  small-signal {k} = {v:.5g} {unit} (SE {s:.2g})")
        for k, (v, s, at) in self.apparent.items():
            lines.append(f"  apparent {k} at i_d = {at[0]:.3g} A, i_q = {at[1]:.3g} A: {v:.5g} H (SE {s:.2g})")
        return "\n".join(lines)


def _num(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _nums(a: np.ndarray) -> list:
    return [_nums(r) for r in a] if np.ndim(a) > 1 else [_num(x) for x in np.asarray(a)]


def _grid(values: np.ndarray, points: int) -> np.ndarray:
    lo, hi = min(float(np.min(values)), 0.0), max(float(np.max(values)), 0.0)
    if hi - lo <= 0.0:
        return np.zeros(1)
    return np.linspace(lo, hi, points)


def covered_points(i_d: np.ndarray, i_q: np.ndarray, currents: np.ndarray) -> np.ndarray:
    """(G, H) whether a sample of ``currents`` ((M, 2), A) lies within half a grid step of each grid point."""
    currents = np.asarray(currents, dtype=float).reshape(-1, 2)
    currents = currents[np.all(np.isfinite(currents), axis=1)]
    out = np.zeros((len(i_d), len(i_q)), dtype=bool)
    idx = []
    for grid, c in ((i_d, currents[:, 0]), (i_q, currents[:, 1])):
        if len(grid) == 1:
            idx.append(np.zeros(len(c), dtype=int))
            continue
        step = grid[1] - grid[0]
        k = np.rint((c - grid[0]) / step).astype(int)
        idx.append(np.clip(k, 0, len(grid) - 1))
    out[idx[0], idx[1]] = True
    return out


@jax.jit
def _maps(motor: Any, i_d: jnp.ndarray, i_q: jnp.ndarray) -> jnp.ndarray:
    """(5, G, H): the maps of ``MAPS`` at the grid's currents."""
    d, q = jnp.meshgrid(i_d, i_q, indexing="ij")
    psi_d, psi_q = flux_of_currents(d, q, motor, loop=True)
    l_dd, l_dq, l_qq = incremental_inductances(psi_d, psi_q, motor)
    return jnp.stack([psi_d, psi_q, l_dd, l_dq, l_qq])


@jax.jit
def _chords(motor: Any, i_d: jnp.ndarray, i_q: jnp.ndarray) -> jnp.ndarray:
    """(2,): ``(psi_d(i_d, 0) - lambda_m) / i_d`` and ``psi_q(0, i_q) / i_q`` (H)."""
    psi_d, _ = flux_of_currents(i_d, 0.0, motor, loop=True)
    _, psi_q = flux_of_currents(0.0, i_q, motor, loop=True)
    return jnp.stack([(psi_d - motor.lambda_m) / i_d, psi_q / i_q])


def _with_band(kind: str, cal: Any, *args) -> tuple[np.ndarray, np.ndarray]:
    """The maps (``kind`` ``"maps"``: :func:`_maps`) or the chords (``"chords"``: :func:`_chords`) of ``cal.motor``
    at ``args``, and their delta-method SE over the fitted names (NaN where undefined)."""
    names = tuple(cal.fit_names)
    args = tuple(np.asarray(x, dtype=float) for x in args)
    if not names:
        value = np.asarray(_KINDS[kind](cal.motor, *args))
        return value, np.zeros_like(value)
    theta = np.asarray([float(cal.estimate[cal.names.index(n)]) for n in names], dtype=float)
    jac, value = (np.asarray(x) for x in cached_call(_value_and_jacobian, "flux_map_band", cal.motor, theta, *args,
                                                     kind=kind, names=names, compiler_options=RUN_ONCE))
    jac = jac.reshape(value.size, len(names))
    cov = np.asarray(cal.covariance, dtype=float)
    with np.errstate(invalid="ignore"):
        var = np.einsum("ij,jk,ik->i", jac, cov, jac)
    return value, np.sqrt(np.maximum(var, 0.0)).reshape(value.shape)


_KINDS = {"maps": _maps, "chords": _chords}


@functools.partial(jax.jit, static_argnames=("kind", "names"))
def _value_and_jacobian(motor: Any, theta: jnp.ndarray, *args: Any, kind: str, names: tuple[str, ...]) -> tuple:
    """The Jacobian of ``_KINDS[kind](motor, *args)`` along ``names`` at ``theta`` and its value, in one pass.

    One compiled program, kept on disk (``model.cached_call``): differentiated outside ``jit``, a warm fit traced
    and compiled it again in every process (~12 s of the SyRM's). The law's Newton steps run as a loop
    (``flux_of_currents(loop=True)``: unrolled, the program took ~10 s to compile and ~1.3 s to load; the maps
    and the chords in one program took as long as both apart). Compiled as a program that runs once
    (``model.RUN_ONCE``: LLVM's level 0, XLA's legacy emitters): the SyRM bench's maps and chords in 2.8 and
    3.8 s against 5.3 and 6.0 s, its cold default fit 18.6 -> 15.2 s, the PM-SyRM's with its motor file
    13.3 -> 11.0 s (A/B medians), warm as fast; the maps and bands move at <= 1.4e-12 relative, no printed digit.
    """
    def g(t):
        out = _KINDS[kind](motor.with_vector(names, t), *args)
        return out, out

    return jax.jacfwd(g, has_aux=True)(theta)


def flux_maps(cal: Any, currents: np.ndarray, *, points: int = GRID_POINTS,
              apparent_at: tuple[float, float] | None = None) -> FluxMaps:
    """The maps of a single calibration over the currents its data reached (see the module docstring).

    Args:
        cal: a single ``Calibration`` (its ``motor``, ``fit_names``, ``covariance``, ``t_factor``).
        currents: the measured ``[i_d, i_q]`` (A), shape (M, 2): the tested range.
        points: grid points per axis.
        apparent_at: ``(i_d, i_q)`` (A) for the chord inductances (``Ld`` at ``(i_d, 0)``, ``Lq`` at
            ``(0, i_q)``); default the data's largest current on each axis.
    """
    from ..physics import is_saturating

    currents = np.asarray(currents, dtype=float).reshape(-1, 2)
    finite = currents[np.all(np.isfinite(currents), axis=1)]
    if finite.size == 0:
        finite = np.zeros((1, 2))
    i_d, i_q = _grid(finite[:, 0], points), _grid(finite[:, 1], points)
    if apparent_at is None:
        apparent_at = tuple(float(c[np.argmax(np.abs(c))]) for c in (finite[:, 0], finite[:, 1]))
    at_d, at_q = (a if a != 0.0 else math.nan for a in apparent_at)
    # The two programs load (or compile) side by side.
    (value, se), (chord, chord_se) = side_by_side([functools.partial(_with_band, "maps", cal, i_d, i_q),
                                                    functools.partial(_with_band, "chords", cal, at_d, at_q)])
    half = float(cal.t_factor) * se
    maps = {n: MapBand(value[k], se[k], value[k] - half[k], value[k] + half[k]) for k, n in enumerate(MAPS)}
    names = list(cal.names)
    small = {}
    for n in ("Ld", "Lq", "lambda_m"):
        v = float(getattr(cal.motor, n))
        s = float(cal.se[names.index(n)]) if n in names else math.nan
        small[n] = (v, s)
    apparent = {"Ld": (float(chord[0]), float(chord_se[0]), (float(apparent_at[0]), 0.0)),
                "Lq": (float(chord[1]), float(chord_se[1]), (0.0, float(apparent_at[1])))}
    return FluxMaps(i_d=i_d, i_q=i_q, tested=covered_points(i_d, i_q, finite), maps=maps, small_signal=small,
                    apparent=apparent, saturating=is_saturating(cal.motor))
