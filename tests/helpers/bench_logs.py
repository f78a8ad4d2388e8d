"""Bench logs as a bench writes them: one continuous recording of a plan, short rests between segments,
currents in mA, speed in rpm, no segment column; written with each format's own library."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

#: The log's channel names and units, as a bench names them.
CHANNELS = {"t": ("time", "s"), "v_d": ("Ud_ref", "V"), "v_q": ("Uq_ref", "V"), "i_d": ("Id", "mA"),
            "i_q": ("Iq", "mA"), "w_m": ("n_mech", "rpm"), "theta_e": ("phi_el", "deg")}
#: drivecal's SI values -> the logged values.
TO_LOGGED = {"i_d": 1e3, "i_q": 1e3, "w_m": 60.0 / (2.0 * math.pi), "theta_e": 180.0 / math.pi}


def continuous_recording(bench, rest: int = 60) -> tuple[dict[str, np.ndarray], list[dict]]:
    """The bench's segments one after the other on one clock, ``rest`` samples at rest before each and after
    the last: the logged channels (by log name, logged units) and the true windows (format-file tables)."""
    fs = bench.sample_rate
    parts = {k: [] for k in CHANNELS if k != "t"}
    windows, offset = [], 0
    for seg in bench.segments:
        for k in parts:
            parts[k].append(np.zeros(rest))
        offset += rest
        parts["v_d"].append(seg.voltages[:, 0])
        parts["v_q"].append(seg.voltages[:, 1])
        parts["i_d"].append(seg.currents[:, 0])
        parts["i_q"].append(seg.currents[:, 1])
        parts["w_m"].append(seg.w_m if seg.w_m is not None else np.zeros(seg.num_samples))
        parts["theta_e"].append(seg.theta_e if seg.theta_e is not None else np.zeros(seg.num_samples))
        windows.append({"name": seg.name, "start": f"{(offset - 0.5) / fs * 1e3:.10g} ms",
                        "stop": f"{(offset + seg.num_samples - 0.5) / fs * 1e3:.10g} ms", "locked": seg.locked})
        offset += seg.num_samples
    for k in parts:
        parts[k].append(np.zeros(rest))
    n = offset + rest
    logged = {CHANNELS[k][0]: np.concatenate(v) * TO_LOGGED.get(k, 1.0) for k, v in parts.items()}
    logged = {"time": np.arange(n) / fs, **logged}
    return logged, windows


def format_toml(windows: list[dict], t_name: str | None = "time", names: dict[str, str] | None = None,
                extra: str = "") -> str:
    """The format file of such a log."""
    names = names or {k: v[0] for k, v in CHANNELS.items()}
    lines = ["[columns]"]
    lines += [f'{k} = "{v}"' for k, v in names.items() if not (k == "t" and t_name is None)]
    lines += ["", "[units]", 'i_d = "mA"', 'i_q = "mA"', 'w_m = "rpm"', 'theta_e = "deg"', ""]
    for w in windows:
        lines += ["[[segment]]", f'name = "{w["name"]}"', f'start = "{w["start"]}"', f'stop = "{w["stop"]}"',
                  f'locked = {str(w["locked"]).lower()}', ""]
    return "\n".join(lines) + extra


def units_of(name: str) -> str:
    return next(u for n, u in CHANNELS.values() if n == name)


def write_mdf4(path: Path, logged: dict[str, np.ndarray]) -> Path:
    from asammdf import MDF, Signal

    t = logged["time"]
    mdf = MDF(version="4.10")
    mdf.append([Signal(v, t, name=k, unit=units_of(k)) for k, v in logged.items() if k != "time"],
               comment="drivecal test bench")
    mdf.save(str(path), overwrite=True)
    mdf.close()
    return path


def write_tdms(path: Path, logged: dict[str, np.ndarray], group: str = "bench") -> Path:
    from nptdms import ChannelObject, GroupObject, TdmsWriter

    step = float(logged["time"][1] - logged["time"][0])
    with TdmsWriter(str(path)) as writer:
        channels = [ChannelObject(group, k, v, properties={"unit_string": units_of(k), "wf_increment": step,
                                                            "wf_start_offset": 0.0})
                    for k, v in logged.items() if k != "time"]
        writer.write_segment([GroupObject(group)] + channels)
    return path


def write_hdf5(path: Path, logged: dict[str, np.ndarray], group: str = "bench") -> Path:
    import h5py

    with h5py.File(path, "w") as f:
        g = f.create_group(group)
        for k, v in logged.items():
            ds = g.create_dataset(k, data=v)
            ds.attrs["unit"] = units_of(k)
    return path


@functools.lru_cache(maxsize=1)
def speed_bench():
    """The default plan on the Jaxonomy engine with an encoder (speed and angle), sigma 20 mA, seed 1: built
    once per test process."""
    import drivecal as dc

    return dc.engine_bench(dc.default_plan(), dc.DEFAULT_MOTOR, record_speed=True).add_noise(0.02, 1)


def assert_same_bench(a, b, rtol: float = 1e-12) -> None:
    """Two benches with the same segments, flags and arrays (to ``rtol``; times to 1e-12 s)."""
    assert len(a.segments) == len(b.segments)
    assert a.sample_rate == pytest.approx(b.sample_rate, rel=1e-12)
    for x, y in zip(a.segments, b.segments):
        assert (x.locked, x.at_rest, x.num_samples) == (y.locked, y.at_rest, y.num_samples)
        np.testing.assert_allclose(x.t, y.t, rtol=0, atol=1e-12)
        for name in ("voltages", "currents", "w_m", "theta_e"):
            u, v = getattr(x, name), getattr(y, name)
            assert (u is None) == (v is None), name
            if u is not None:
                np.testing.assert_allclose(u, v, rtol=rtol, atol=rtol * float(np.max(np.abs(v))), err_msg=name)


def small_frame(n: int = 60) -> pd.DataFrame:
    """A tiny two-segment dq table (a locked d-step and a free q-step, n samples each at 20 kHz)."""
    fs = 20_000.0
    t = np.arange(n) / fs
    rise = 1.0 - np.exp(-t * 0.45 / 3.2e-3)
    d = pd.DataFrame({"segment": "d", "locked": 1, "t": t, "v_d": 8.0, "v_q": 0.0, "i_d": 8.0 / 0.45 * rise,
                      "i_q": 0.0})
    q = pd.DataFrame({"segment": "spin", "locked": 0, "t": t, "v_d": 0.0, "v_q": 8.0, "i_d": 0.0,
                      "i_q": 8.0 / 0.45 * rise})
    return pd.concat([d, q], ignore_index=True)
