"""Bench data: what the bench applied and measured, segment by segment.

Bench files (CSV, Parquet or MATLAB ``.mat``) hold one row per sample with the
columns ``segment`` (name), ``locked`` (0/1), ``t`` (s), ``v_d``, ``v_q`` (V),
``i_d``, ``i_q`` (A) and optionally ``w_m`` (rad/s, measured mechanical speed)
and ``temperature`` (degC, winding temperature; R follows it).
Instead of dq columns a file may hold phase quantities ``i_a``, ``i_b``
(``i_c``), ``v_a``, ``v_b`` (``v_c``) (phase-to-neutral, A and V) with a rotor
angle ``theta_e`` (electrical, rad) or ``theta_m`` (mechanical, rad); they are
turned into dq with the amplitude-invariant Clarke and Park transforms.

This module holds the data types (:class:`SegmentData`, :class:`BenchData`) and
the experiments built from them; files are read in :mod:`._readers` and checked
in :mod:`._checks`.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import DataError
from ..model import Experiment
from ..physics import dq_to_abc
from .._stats import noise_level
from .._io import atomic_path
from ._readers import TABLE_FORMATS
from ._speed import SpeedResolution, speed_resolution

if TYPE_CHECKING:
    import pandas as pd


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
        at_rest: the segment starts from rest (zero currents and speed); when
            False the forward model starts from the first sample instead.
        temperature: winding temperature (degC) per sample, shape (N,), or None.
        theta_e: measured electrical rotor angle (rad) per sample, shape (N,),
            of a phase bench file, or None.
        continues: the segment continues the previous one (one sample period after its
            last sample, not at rest): the model carries its state and the delayed
            command over instead of starting from this segment's first sample.
        inverter_off: the inverter's switches were open (bench-file column ``inverter``
            0): no current flows and a free rotor coasts on its friction.
    """

    name: str
    locked: bool
    t: np.ndarray
    voltages: np.ndarray
    currents: np.ndarray
    w_m: np.ndarray | None = None
    at_rest: bool = True
    temperature: np.ndarray | None = None
    theta_e: np.ndarray | None = None
    continues: bool = False
    inverter_off: bool = False

    @property
    def num_samples(self) -> int:
        return int(self.t.shape[0])

    def initial_state(self) -> np.ndarray:
        """``[i_d, i_q, w_m, theta_m]`` the forward model starts from (A, A, rad/s, rad)."""
        if self.at_rest:
            return np.zeros(4)
        w0 = 0.0 if (self.locked or self.w_m is None) else float(self.w_m[0])
        return np.array([self.currents[0, 0], self.currents[0, 1], w0, 0.0])


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

    @property
    def has_measured_speed(self) -> bool:
        """Some free segment carries a measured speed ``w_m``."""
        return any(s.w_m is not None and not s.locked for s in self.segments)

    def experiment(self, measured_speed: bool = True, delay_samples: float = 0.0, host: bool = False, *,
                   speed: str | None = None, current_noise: float | None = None,
                   speed_noise: float | None = None) -> Experiment:
        """The applied voltages and rotor conditions, for the forward model.

        Args:
            measured_speed: on free segments with a measured ``w_m``, use it as
                an input of the electrical equations (J and B then play no
                part); when False the speed is simulated from J and B.
            speed: what a measured ``w_m`` is, replacing ``measured_speed``: "input" (as
                ``measured_speed=True``), "ignore" (as False), or "output": a second measured
                output, the speed simulated from J, B and the friction and compared with it,
                its residuals weighed by the noise ratio (:meth:`noise_levels`).
            current_noise, speed_noise: the sensors' noise (A, rad/s) where known (the motor
                file's); else estimated from the samples (:meth:`noise_levels`).
            delay_samples: the inverter's PWM/computation delay (samples): the
                recorded command k acts at sample k + delay_samples; its whole samples are
                applied here, a fraction by the model (``MotorParams.delay``).
            host: numpy arrays (see ``Experiment.from_segments``).
        """
        if speed not in (None, "input", "output", "ignore"):
            raise ValueError(f"speed must be 'input', 'output' or 'ignore', got {speed!r}")
        mode = speed or ("input" if measured_speed else "ignore")
        weight = 1.0
        if mode == "output" and self.has_measured_speed:
            sigma_i, sigma_w = self.noise_levels()
            weight = (current_noise or sigma_i) / (speed_noise or sigma_w)
        return _experiment([self], mode != "ignore", delay_samples, host, stacked=False,
                           speed_output=mode == "output", speed_weight=weight)

    def noise_levels(self) -> tuple[float, float]:
        """The current and speed sensors' noise, estimated from the samples: ``(sigma_i, sigma_w)`` (A, rad/s).

        The current's is the median over segments (and over i_d, i_q) of the robust second-difference
        estimate (``_stats.noise_level``), which slow signals barely touch. The speed's, from the free
        segments that measured it, is its resolution's (:meth:`speed_resolution`): that level, or a
        quantised speed's rounding error ``step / sqrt(12)`` where larger, times the square root of the
        samples each value is held; a noise-free speed gets a floor of 1e-9 of its range (1e-12 rad/s at
        least), so the weight stays finite.
        """
        sigma_i = float(np.median([noise_level(s.currents, axis=0) for s in self.segments]))
        resolution = self.speed_resolution()
        return sigma_i, math.nan if resolution is None else resolution.sigma

    def speed_resolution(self) -> SpeedResolution | None:
        """How exact the free segments' measured speed is (steps, update period, noise), or None without one."""
        return speed_resolution([s.w_m for s in self.segments if s.w_m is not None and not s.locked],
                                self.sample_rate)

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

    def columns(self) -> dict[str, np.ndarray]:
        """The bench-file columns, one entry per sample: text (``segment``), integers (``locked``,
        ``inverter``) and floats (s, V, A, rad/s, rad, degC)."""
        parts: list[dict[str, np.ndarray]] = []
        start = 0.0  # a continuing segment's clock runs on from the previous one's (one sample period later)
        for k, seg in enumerate(self.segments):
            prev = self.segments[k - 1] if k else None
            start = start + float(prev.t[-1]) + 1.0 / self.sample_rate if seg.continues and prev is not None else 0.0
            n = seg.num_samples
            cols = {
                "segment": np.full(n, seg.name, dtype=object),
                "locked": np.full(n, int(seg.locked), dtype=np.int64),
                "t": seg.t + start,
                "v_d": seg.voltages[:, 0],
                "v_q": seg.voltages[:, 1],
                "i_d": seg.currents[:, 0],
                "i_q": seg.currents[:, 1],
            }
            if any(s.w_m is not None for s in self.segments):
                cols["w_m"] = seg.w_m if seg.w_m is not None else np.zeros(n)
            if any(s.theta_e is not None for s in self.segments):
                cols["theta_e"] = seg.theta_e if seg.theta_e is not None else np.zeros(n)
            if any(s.inverter_off for s in self.segments):
                cols["inverter"] = np.full(n, int(not seg.inverter_off), dtype=np.int64)
            if any(s.temperature is not None for s in self.segments):
                cols["temperature"] = seg.temperature if seg.temperature is not None else np.full(n, np.nan)
            parts.append(cols)
        return {name: np.concatenate([np.asarray(cols[name]) for cols in parts]) for name in parts[0]}

    def to_frame(self) -> pd.DataFrame:
        """One row per sample with the bench-file columns (:meth:`columns`)."""
        import pandas as pd

        return pd.DataFrame(self.columns())

    def to_csv_text(self) -> str:
        """The bench file as CSV text (what :meth:`save` writes to a .csv), every float exact (``%.17g``), without
        pandas: what ``to_frame().to_csv(index=False, float_format="%.17g", lineterminator="\\n")`` writes."""
        import csv
        import io

        cols = self.columns()
        text = []
        for values in cols.values():
            if values.dtype.kind == "f":
                text.append(["" if math.isnan(v) else "%.17g" % v for v in values.tolist()])
            else:
                text.append([str(v) for v in values.tolist()])
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(cols)
        writer.writerows(zip(*text))
        return out.getvalue()

    def to_phase_frame(self, theta_e: np.ndarray) -> pd.DataFrame:
        """The run as phase quantities: ``i_a, i_b, i_c, v_a, v_b, v_c`` (A, V, phase-to-neutral)
        and ``theta_e`` (rad), by inverse amplitude-invariant Park and Clarke.

        Args:
            theta_e: electrical rotor angle at every sample (rad), shape (M,).
        """
        frame = self.to_frame()
        theta_e = np.asarray(theta_e, dtype=float)
        for prefix in ("i", "v"):
            d, q = frame.pop(f"{prefix}_d").to_numpy(), frame.pop(f"{prefix}_q").to_numpy()
            frame[f"{prefix}_a"], frame[f"{prefix}_b"], frame[f"{prefix}_c"] = dq_to_abc(d, q, theta_e, xp=np)
        frame["theta_e"] = theta_e
        return frame

    def save(self, path: str | Path) -> Path:
        """Write the bench file (format from the suffix: .csv, .parquet, .mat), atomically."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in TABLE_FORMATS:
            raise DataError(f"{path}: unknown bench-file format '{suffix}'; use one of {', '.join(TABLE_FORMATS)}.")
        with atomic_path(path) as tmp:
            if suffix == ".csv":
                tmp.write_bytes(self.to_csv_text().encode())
            elif suffix == ".parquet":
                self.to_frame().to_parquet(tmp, index=False)
            else:
                from scipy.io import savemat

                columns = self.columns()
                columns["segment"] = columns.pop("segment")  # the names last, as the files written before
                savemat(tmp, columns, oned_as="column", appendmat=False)
        return path


def stacked_experiment(benches: list[BenchData], measured_speed: bool = True, delay_samples: float = 0.0,
                       host: bool = False) -> Experiment:
    """The experiments of benches of one plan shape, stacked along a leading axis (B, ...).

    As ``stack_experiments([b.experiment(...) for b in benches])``, built at once (a fleet stacks
    thousands); the benches must agree on segment lengths, rotor conditions and which free
    segments measured their speed.
    """
    return _experiment(benches, measured_speed, delay_samples, host, stacked=True)


def _experiment(benches: list[BenchData], measured_speed: bool, delay_samples: float, host: bool,
                stacked: bool, speed_output: bool = False, speed_weight: float = 1.0) -> Experiment:
    join = np.stack if stacked else (lambda arrays: arrays[0])

    def differ(seg):
        raise ValueError(f"{seg.name}: the benches differ in which free segments measured their speed; "
                         "stack benches of one plan shape only.")

    def per_segment(get, fill=differ):
        """Per segment, ``get(segment)`` of every bench joined (``fill`` where one lacks it); None where all do."""
        out = []
        for segs in zip(*(b.segments for b in benches)):
            values = [get(seg) for seg in segs]
            if all(v is None for v in values):
                out.append(None)
            else:
                out.append(join([fill(seg) if v is None else v for seg, v in zip(segs, values)]))
        return out

    def nan(seg):
        return np.full(seg.num_samples, np.nan)

    first = benches[0].segments
    return Experiment.from_segments(
        per_segment(lambda seg: seg.voltages),
        [seg.locked for seg in first],
        join([1.0 / b.sample_rate for b in benches]),
        initial_states=per_segment(lambda seg: seg.initial_state()),
        speeds=per_segment(lambda seg: seg.w_m if (measured_speed and seg.w_m is not None and not seg.locked) else None),
        temperatures=per_segment(lambda seg: seg.temperature, nan),
        angles=per_segment(lambda seg: seg.theta_e, nan),
        delay_samples=delay_samples,
        host=host,
        continues=[seg.continues for seg in first],
        inverter_off=[seg.inverter_off for seg in first],
        speed_output=speed_output,
        speed_weight=speed_weight,
    )
