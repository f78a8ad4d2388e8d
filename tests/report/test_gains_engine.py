"""The designed current loop, closed on the Jaxonomy engine, meets its specification.

The engine diagram is the sampled drive: the PMSM block (the true motor,
rotor locked) integrated by Jaxonomy's adaptive solver; per axis the error
and Jaxonomy's ``PIDDiscrete``, which samples it at the sample instants
(``u[k] = Kp e[k] + Ki e_int[k]``, ``e_int[k+1] = e_int[k] + e[k] Ts``: the
design's forward-Euler PI); then the command delay as ``UnitDelay`` blocks
(one per sample; a 1.5-sample delay is three at half the period). None of
drivecal's loop formulas is used: the achieved crossover, -3 dB bandwidth and
phase margin are measured from the simulated step response (its increments
are the closed loop's impulse response, whose DFT is ``T``; the loop gain is
``T / (1 - T)``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivecal.report import design_current_loop

#: Step response length (samples) and where the reference steps (the controller first sees it at sample K0).
N, K0 = 400, 3


def _closed_loop_step(motor, gains, sample_rate: float, delay_samples: float) -> np.ndarray:
    """Currents (A), shape (N, 2), at the sample instants after a 1 A step of both references at sample K0."""
    import jax.numpy as jnp
    from jaxonomy import DiagramBuilder, SimulatorOptions, simulate
    from jaxonomy.library import Adder, FeedthroughBlock, Mux, PIDDiscrete, Step, UnitDelay

    from drivecal.bench import pmsm_block

    dt = 1.0 / sample_rate
    builder = DiagramBuilder()
    pmsm = builder.add(pmsm_block(motor, locked=True))
    mux = builder.add(Mux(2, name="v_command"))
    for k, (kp, ki) in enumerate(gains):
        current = builder.add(FeedthroughBlock(lambda x, k=k: x[k], name=f"i{k}"))
        ref = builder.add(Step(start_value=0.0, end_value=1.0, step_time=(K0 - 0.5) * dt, name=f"ref{k}"))
        err = builder.add(Adder(2, operators="+-", name=f"e{k}"))
        pi = builder.add(PIDDiscrete(dt, kp=float(kp), ki=float(ki), kd=0.0, name=f"pi{k}"))
        builder.connect(pmsm.output_ports[0], current.input_ports[0])
        builder.connect(ref.output_ports[0], err.input_ports[0])
        builder.connect(current.output_ports[0], err.input_ports[1])
        builder.connect(err.output_ports[0], pi.input_ports[0])
        builder.connect(pi.output_ports[0], mux.input_ports[k])
    halves = round(2 * delay_samples)
    assert halves == 2 * delay_samples
    step = dt if halves % 2 == 0 else dt / 2
    last = mux
    for j in range(halves // 2 if halves % 2 == 0 else halves):
        delay = builder.add(UnitDelay(step, initial_state=jnp.zeros(2), name=f"delay{j}"))
        builder.connect(last.output_ports[0], delay.input_ports[0])
        last = delay
    builder.connect(last.output_ports[0], pmsm.input_ports[0])
    diagram = builder.build()
    t = np.arange(K0 + N) * dt
    result = simulate(diagram, diagram.create_context(), (0.0, t[-1]),
                      options=SimulatorOptions(rtol=1e-11, atol=1e-11, buffer_length=40 * len(t) + 64),
                      recorded_signals={"x": pmsm.output_ports[0]})
    t_rec, x_rec = np.asarray(result.time), np.asarray(result.outputs["x"])
    idx = np.searchsorted(t_rec, t + 1e-9 * dt, side="right") - 1
    assert np.allclose(t_rec[idx], t, rtol=0, atol=1e-9 * dt), "the engine did not record every sample instant"
    return x_rec[idx][K0:, :2]


def _measured(step: np.ndarray, sample_rate: float) -> tuple[float, float, float]:
    """``(crossover Hz, -3 dB bandwidth Hz, phase margin deg)`` from one axis's unit-step response."""
    assert abs(step[-1] - 1.0) < 1e-3 and np.max(np.abs(np.diff(step[-20:]))) < 1e-5, "not settled"
    impulse = np.diff(step, prepend=0.0)
    f = np.geomspace(sample_rate * 1e-4, sample_rate / 2, 20000)
    theta = 2 * np.pi * f / sample_rate
    t_cl = np.exp(-1j * np.outer(theta, np.arange(len(impulse)))) @ impulse
    loop = t_cl / (1.0 - t_cl)

    def first_below(y, level):
        i = int(np.argmax(y < level))
        assert i > 0 and y[i] < level
        return float(np.interp(level, [y[i], y[i - 1]], [f[i], f[i - 1]]))

    fc = first_below(np.abs(loop), 1.0)
    bw = first_below(np.abs(t_cl) ** 2, 0.5)
    at_fc = np.exp(-1j * 2 * np.pi * fc / sample_rate * np.arange(len(impulse))) @ impulse
    pm = 180.0 + float(np.degrees(np.angle(at_fc / (1.0 - at_fc))))
    return fc, bw, pm


CASES = [
    (20e3, "bandwidth", 1000.0), (20e3, "crossover", 1000.0), (20e3, "phase_margin", 60.0),
    (1e3, "bandwidth", 100.0), (1e3, "crossover", 50.0), (1e3, "phase_margin", 45.0),
]
KEYWORD = {"bandwidth": "bandwidth_hz", "crossover": "crossover_hz", "phase_margin": "phase_margin_deg"}


@pytest.mark.parametrize("sample_rate, kind, value", CASES)
def test_the_engine_loop_meets_the_specification(default_fit, truth, sample_rate, kind, value):
    design = design_current_loop(default_fit, sample_rate_hz=sample_rate, num_samples=200, **{KEYWORD[kind]: value})
    assert design.delay_samples == 1.0
    step = _closed_loop_step(truth, [(ax.kp, ax.ki) for ax in design.axes], sample_rate, 1.0)
    for k, ax in enumerate(design.axes):
        fc, bw, pm = _measured(step[:, k], sample_rate)
        achieved = {"crossover": fc, "bandwidth": bw, "phase_margin": pm}[kind]
        print(f"{sample_rate:g} Hz {kind} {value:g}: {ax.axis} axis crossover {fc:.2f} Hz, bandwidth {bw:.2f} Hz, "
              f"margin {pm:.2f} deg (design {ax.crossover.nominal:.2f}, {ax.bandwidth.nominal:.2f}, "
              f"{ax.phase_margin.nominal:.2f})")
        assert achieved == pytest.approx(value, rel=0.10)
        # and the other figures as the design reports them (the engine is the true motor, 0.1 % away)
        assert fc == pytest.approx(ax.crossover.nominal, rel=0.01)
        assert bw == pytest.approx(ax.bandwidth.nominal, rel=0.01)
        assert pm == pytest.approx(ax.phase_margin.nominal, abs=1.0)


def test_a_fitted_fractional_delay_is_designed_for(default_fit, truth):
    """A calibration whose fit estimated the delay (1.5 samples at 20 kHz): the design uses it, and its
    loop closed on the engine with that delay meets the bandwidth; designing for one sample would not."""
    cov = np.zeros((5, 5))
    cov[:4, :4] = default_fit.covariance
    cov[4, 4] = 0.01**2
    cal = dataclasses.replace(
        default_fit, names=default_fit.names + ("delay",), fit_names=default_fit.fit_names + ("delay",),
        estimate=np.append(default_fit.estimate, 1.5), se=np.append(default_fit.se, 0.01),
        ci95=np.vstack([default_fit.ci95, [1.48, 1.52]]), identifiable=default_fit.identifiable + (True,),
        initial=np.append(default_fit.initial, 1.0), covariance=cov)
    design = design_current_loop(cal, 1000.0, sample_rate_hz=20e3, delay_sample_rate_hz=20e3, num_samples=500)
    assert design.delay_samples == 1.5 and "fitted" in design.delay_source
    assert all(np.isfinite(ax.kp_se) and ax.kp_sd_mc / ax.kp_se == pytest.approx(1.0, abs=0.1) for ax in design.axes)
    step = _closed_loop_step(truth, [(ax.kp, ax.ki) for ax in design.axes], 20e3, 1.5)
    naive = design_current_loop(default_fit, 1000.0, sample_rate_hz=20e3, num_samples=200)
    step_naive = _closed_loop_step(truth, [(ax.kp, ax.ki) for ax in naive.axes], 20e3, 1.5)
    for k in range(2):
        _, bw, _ = _measured(step[:, k], 20e3)
        _, bw_naive, _ = _measured(step_naive[:, k], 20e3)
        print(f"delay 1.5: bandwidth {bw:.2f} Hz designed for it, {bw_naive:.2f} Hz designed for one sample")
        assert bw == pytest.approx(1000.0, rel=0.10)
        assert bw_naive > bw * 1.05  # the one-sample design overshoots: the delay matters
    # the same delay at a controller twice as slow is 0.75 of its samples
    assert design_current_loop(cal, 100.0, sample_rate_hz=10e3, delay_sample_rate_hz=20e3,
                               num_samples=200).delay_samples == pytest.approx(0.75)


def test_engine_harness_has_one_sample_of_computation_delay(truth):
    """The first current after the step is at K0 + 2 (command computed at K0 from the current sampled then,
    applied from K0 + 1), and the next command sees that current at once (no measurement delay)."""
    kp = 10.0
    step = _closed_loop_step(truth, [(kp, 0.0), (kp, 0.0)], 20e3, 1.0)
    a = np.exp(-truth.R / 20e3 / truth.Ld)
    i = [0.0, 0.0]
    for k in range(1, 5):  # i[k+1] = a i[k] + (1 - a)/R * Kp (1 - i[k-1]): the sampled loop, by hand
        i.append(a * i[k] + (1 - a) / truth.R * kp * (1.0 - i[k - 1]))
    assert np.all(step[:2] == 0.0)
    assert step[:6, 0] == pytest.approx(i, rel=1e-6)
