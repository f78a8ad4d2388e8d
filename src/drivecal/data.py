"""Bench data: what the bench applied and measured, segment by segment.

The column names follow drivecal's bench-file contract: ``segment``, ``locked``,
``t`` (s, from 0 in each segment), ``v_d``, ``v_q`` (V), ``i_d``, ``i_q`` (A),
optional ``w_m`` (rad/s).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from .errors import DataError
from .forward import Experiment


@dataclasses.dataclass(frozen=True)
class SegmentData:
    """One recorded segment.

    Attributes:
        name: segment label.
        locked: whether the rotor was locked.
        t: sample instants from the segment start (s), shape (N,).
        voltages: applied ``[v_d, v_q]`` (V), shape (N, 2), held between samples.
        currents: measured ``[i_d, i_q]`` (A), shape (N, 2).
        w_m: measured mechanical speed (rad/s), shape (N,), or None.
    """

    name: str
    locked: bool
    t: np.ndarray
    voltages: np.ndarray
    currents: np.ndarray
    w_m: np.ndarray | None = None

    @property
    def num_samples(self) -> int:
        return int(self.t.shape[0])


@dataclasses.dataclass(frozen=True)
class BenchData:
    """A whole bench run at one sample rate.

    Attributes:
        segments: the recorded segments in order.
        sample_rate: samples per second (Hz).
        source: where the data came from (a file path or "synthetic bench").
    """

    segments: tuple[SegmentData, ...]
    sample_rate: float
    source: str = "synthetic bench"

    @property
    def currents(self) -> np.ndarray:
        """Measured ``[i_d, i_q]`` (A) of all segments end to end, shape (M, 2)."""
        return np.concatenate([s.currents for s in self.segments], axis=0)

    @property
    def num_samples(self) -> int:
        """M, the samples over all segments."""
        return sum(s.num_samples for s in self.segments)

    def experiment(self) -> Experiment:
        """The applied voltages and rotor conditions, for the forward model."""
        return Experiment.from_segments(
            [s.voltages for s in self.segments],
            [s.locked for s in self.segments],
            1.0 / self.sample_rate,
        )

    def with_currents(self, currents: np.ndarray) -> BenchData:
        """The same run with the currents replaced by ``currents`` (A), shape (M, 2)."""
        currents = np.asarray(currents, dtype=float)
        if currents.shape != (self.num_samples, 2):
            raise DataError(
                f"{self.source}: expected currents of shape ({self.num_samples}, 2), got {currents.shape}."
            )
        out, k = [], 0
        for seg in self.segments:
            out.append(dataclasses.replace(seg, currents=currents[k : k + seg.num_samples]))
            k += seg.num_samples
        return dataclasses.replace(self, segments=tuple(out))

    def add_noise(self, sigma: float, seed: int) -> BenchData:
        """Currents plus seeded zero-mean Gaussian sensor noise of ``sigma`` (A)."""
        rng = np.random.default_rng(seed)
        return self.with_currents(self.currents + rng.normal(0.0, sigma, size=(self.num_samples, 2)))

    def to_frame(self) -> pd.DataFrame:
        """One row per sample with the bench-file columns."""
        frames = []
        for seg in self.segments:
            cols = {
                "segment": seg.name,
                "locked": int(seg.locked),
                "t": seg.t,
                "v_d": seg.voltages[:, 0],
                "v_q": seg.voltages[:, 1],
                "i_d": seg.currents[:, 0],
                "i_q": seg.currents[:, 1],
            }
            if seg.w_m is not None:
                cols["w_m"] = seg.w_m
            frames.append(pd.DataFrame(cols))
        return pd.concat(frames, ignore_index=True)
