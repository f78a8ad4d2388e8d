"""Segments of one continuous recording: cut along a format file's windows, or proposed from the data.

A window holds the samples with ``start <= t < stop``, ``t`` in seconds from
the recording's first sample; samples outside every window are ignored. A
proposal (:func:`propose_windows`, for ``drivecal inspect``) puts a window
around each stretch between rests (the commanded voltages zero for a while) and
calls it locked unless the measured speed shows the rotor turning.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import DataError
from ._format_file import Window
from ._readers import Columns


def _clock(t: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Seconds from the first sample, the typical step (s) and the recording's length (s, last sample + a step)."""
    rel = t - t[0]
    step = float(np.median(np.diff(rel))) if rel.shape[0] > 1 else 0.0
    return rel, step, float(rel[-1]) + step


def cut_windows(columns: Columns, windows: tuple[Window, ...], where: str, fmt_source: str) -> Columns:
    """The samples of each window, in time order, with its name in ``segment`` (and ``locked`` where it says)."""
    rel, step, length = _clock(np.asarray(columns["t"], dtype=float))
    tolerance = 1e-9 * max(length, 1e-9)
    picked, names, flags = [], [], []
    for w in sorted(windows, key=lambda w: w.start):
        if w.start < -tolerance or w.stop > length + tolerance:
            raise DataError(f"{where}: window '{w.name}' ({w.start:.9g} s to {w.stop:.9g} s, in {fmt_source}) falls "
                            f"outside the recording (0 s to {length:.9g} s); correct its start and stop.")
        rows = np.flatnonzero((rel >= w.start) & (rel < w.stop))
        if rows.shape[0] < 2:
            raise DataError(f"{where}: window '{w.name}' ({w.start:.9g} s to {w.stop:.9g} s, in {fmt_source}) holds "
                            f"{rows.shape[0]} sample(s) (one every {step:.6g} s); widen it to at least two samples.")
        if w.locked is None and "locked" not in columns:
            raise DataError(f"{where}: window '{w.name}' says neither locked = true nor false and the log maps no "
                            f"'locked' channel; add locked = true or false to the window in {fmt_source}.")
        picked.append(rows)
        names += [w.name] * rows.shape[0]
        flags.append(np.full(rows.shape[0], np.nan if w.locked is None else float(w.locked)))
    rows = np.concatenate(picked)
    out = {k: v[rows] for k, v in columns.items() if k != "segment"}
    out["segment"] = np.array(names, dtype=object)
    flag = np.concatenate(flags)
    if "locked" in out:
        given = ~np.isnan(flag)
        out["locked"] = np.where(given, flag, np.asarray(out["locked"], dtype=float))
    else:
        out["locked"] = flag
    return out


@dataclasses.dataclass(frozen=True)
class Proposal:
    """A proposed window: its samples ``first`` to ``last`` (inclusive) and whether the rotor turns in it."""

    window: Window
    first: int
    last: int
    turns: bool | None  # None: no speed to tell from


def propose_windows(t: np.ndarray, v_d: np.ndarray | None, v_q: np.ndarray | None, w_m: np.ndarray | None,
                    *, min_rest: float = 5e-4) -> list[Proposal]:
    """Windows around the stretches where a voltage is commanded, separated by rests.

    Args:
        t: sample times (s).
        v_d, v_q: commanded voltages (V); None where the log has none.
        w_m: measured mechanical speed (rad/s), or None.
        min_rest: the shortest rest that separates two segments (s); shorter zero stretches (a PRBS
            crossing zero) stay inside their segment.

    Each window reaches half a step beyond its first and last sample (clipped to the recording), so a
    sample lies well inside it whatever the rounding of the times written.
    """
    rel, step, length = _clock(np.asarray(t, dtype=float))
    volts = [np.asarray(v, dtype=float) for v in (v_d, v_q) if v is not None]
    if not volts or step <= 0:
        return []
    active = np.any(np.abs(np.stack(volts)) > 0, axis=0)
    rest_samples = max(2, int(round(min_rest / step)))
    # Close the gaps shorter than a rest: a zero crossing inside a segment.
    idle = ~active
    edges = np.diff(np.concatenate([[0], idle.astype(int), [0]]))
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        if b - a < rest_samples and a > 0 and b < active.shape[0]:
            active[a:b] = True
    edges = np.diff(np.concatenate([[0], active.astype(int), [0]]))
    speed = None if w_m is None else np.abs(np.asarray(w_m, dtype=float))
    threshold = None
    if speed is not None:
        d2 = np.diff(speed, 2) if speed.shape[0] > 3 else np.zeros(1)
        noise = float(np.median(np.abs(d2 - np.median(d2)))) / 0.6745 / np.sqrt(6.0)
        threshold = max(10.0 * noise, 1e-3 * float(speed.max(initial=0.0)), 0.1)
    out = []
    for k, (first, stop) in enumerate(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1))):
        last = stop - 1
        if last - first < 1:
            continue
        turns = None if speed is None else bool(speed[first:stop].max() > threshold)
        start = max(0.0, float(rel[first]) - 0.5 * step)
        end = min(length, float(rel[last]) + 0.5 * step)
        name = f"segment {k + 1}" if turns is None else f"{'free' if turns else 'locked'} {k + 1}"
        out.append(Proposal(Window(name, start, end, None if turns is None else not turns), int(first), int(last),
                            turns))
    return out
