"""The figure workers: the same PNG bytes as drawing in the caller, no JAX in them, no second run of __main__."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from drivecal import _figures

SRC = str(Path(_figures.__file__).resolve().parents[1])


def _jobs() -> list[tuple[str, dict, int]]:
    rng = np.random.default_rng(3)
    t = np.arange(200) / 20_000.0
    segment = {"name": "step", "locked": True, "t": t.tolist(), "v_d": np.full(200, 8.0).tolist(),
               "v_q": np.zeros(200).tolist(), "i_d": (1 - np.exp(-t / 7e-3) + 0.02 * rng.standard_normal(200)).tolist(),
               "i_q": (0.02 * rng.standard_normal(200)).tolist(), "i_d_pred": (1 - np.exp(-t / 7e-3)).tolist(),
               "i_q_pred": np.zeros(200).tolist()}
    history = np.array([[0.6, 2e-3], [0.5, 3e-3], [0.45, 3.2e-3]])
    return [
        ("currents", {"segments": [segment], "title": "a"}, 80),
        ("residuals", {"segments": [segment], "sigma_hat": 0.02}, 80),
        ("convergence", {"history": history, "names": ("R", "Ld"), "ref": history[-1], "against_truth": False}, 110),
        ("correlation", {"names": ("R", "Ld"), "corr": np.array([[1.0, -0.3], [-0.3, 1.0]])}, 80),
    ]


def test_workers_draw_the_same_bytes_as_the_caller():
    jobs = _jobs()
    with _figures.FigureRenderer(2) as renderer:
        pooled = renderer.render_all(jobs)
    here = [_figures.render(*job) for job in jobs]
    assert pooled == here
    assert all(png.startswith(b"\x89PNG") for png in pooled)


def test_a_figure_asked_for_twice_is_drawn_once(monkeypatch):
    drawn = []
    monkeypatch.setattr(_figures, "render", lambda *job: drawn.append(job[0]) or job[0].encode())
    name, kwargs, dpi = _jobs()[2]
    alike = {**kwargs, "history": kwargs["history"].copy(), "names": list(kwargs["names"]),
             "against_truth": np.bool_(False)}  # another list, array and scalar of the same values
    renderer = _figures.FigureRenderer(0)
    first, again = renderer.submit(name, kwargs, dpi), renderer.submit(name, alike, dpi)
    assert again is first
    assert renderer.render_all([(name, alike, dpi), _jobs()[3]]) == [b"convergence", b"correlation"]
    assert first.result() == b"convergence" and drawn == ["convergence", "correlation"]
    renderer.forget()  # a renderer kept for many reports draws afresh
    assert renderer.submit(name, kwargs, dpi) is not first


def test_a_job_key_tells_apart_what_draws_differently():
    name, kwargs, dpi = _jobs()[2]
    key = _figures.job_key(name, kwargs, dpi)
    assert key == _figures.job_key(name, {**kwargs, "names": list(kwargs["names"])}, dpi)
    changed = [(name, kwargs, 80), ("currents", kwargs, dpi),
               (name, {**kwargs, "history": kwargs["history"] * (1 + 1e-16 * 4)}, dpi),
               (name, {**kwargs, "history": kwargs["history"].astype(np.float32)}, dpi),
               (name, {**kwargs, "against_truth": 0}, dpi), (name, {**kwargs, "names": ("R", "Lq")}, dpi)]
    assert all(_figures.job_key(*job) != key for job in changed)
    assert _figures.job_key(name, {**kwargs, "extra": object()}, dpi) is None


def test_without_workers_the_caller_draws(monkeypatch):
    monkeypatch.setenv(_figures.PROCESSES_ENV, "0")
    renderer = _figures.FigureRenderer()
    assert renderer.processes == 0
    with renderer:
        assert renderer.render_all(_jobs()[:1]) == [_figures.render(*_jobs()[0])]
    assert renderer._threads == []


def test_a_job_the_worker_cannot_draw_raises_in_the_caller():
    with _figures.FigureRenderer(1) as renderer:
        job = renderer.submit("no such figure", {}, 80)
        with pytest.raises(KeyError):
            job.result()
        # the worker is still there for the next job
        assert renderer.render_all(_jobs()[2:3]) == [_figures.render(*_jobs()[2])]


@pytest.mark.skipif(not hasattr(os, "getpriority"), reason="process priorities are Unix's")
def test_a_worker_runs_below_the_command_s_priority():
    """The workers load matplotlib while the command computes; the command's own work goes first on the cores."""
    proc = subprocess.Popen([sys.executable, "-c", _figures.WORKER_PROGRAM], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, env={**os.environ, "PYTHONPATH": SRC})
    try:
        assert _figures._receive(proc.stdout) is not None  # ready: matplotlib loaded
        ours = os.getpriority(os.PRIO_PROCESS, 0)
        assert os.getpriority(os.PRIO_PROCESS, proc.pid) == min(ours + _figures.WORKER_NICENESS, 19)
    finally:
        proc.stdin.close()
        proc.wait(timeout=60)
        proc.stdout.close()


def test_the_worker_loads_no_jax():
    code = "import sys, drivecal._figures; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": SRC})
    assert out.stdout.strip() == "False"


def test_a_script_without_a_main_guard_runs_once(tmp_path):
    """multiprocessing's spawn would import the caller's script again in each worker; these workers do not."""
    marker = tmp_path / "runs.txt"
    script = tmp_path / "user_script.py"
    script.write_text(textwrap.dedent(f"""
        import numpy as np
        from drivecal._figures import FigureRenderer
        with open({str(marker)!r}, "a") as f:
            f.write("run\\n")
        with FigureRenderer(2) as r:
            png, = r.render_all([("correlation", {{"names": ("R",), "corr": np.ones((1, 1))}}, 50)])
        assert png.startswith(b"\\x89PNG")
    """))
    subprocess.run([sys.executable, str(script)], check=True, env={**os.environ, "PYTHONPATH": SRC}, timeout=120)
    assert marker.read_text() == "run\n"


def test_a_figure_is_drawn_once(monkeypatch):
    """Its layout, then one draw: no second draw for the tight box (the figures' cost is their draws)."""
    from matplotlib.figure import Figure

    draws = []
    draw = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda self, renderer: (draws.append(1), draw(self, renderer))[1])
    for job in _jobs():
        draws.clear()
        _figures.render(*job)
        assert len(draws) == 1, job[0]


def test_the_png_is_cut_to_the_content_and_nothing_sticks_out():
    import io

    from PIL import Image

    def png(text_x: float):
        fig = _figures.plt.figure(figsize=(4.0, 3.0))
        fig.add_subplot().plot([0, 1], [0, 1])
        fig.text(text_x, 0.5, "a note that does not fit in the figure" if text_x > 0.5 else "")
        return Image.open(io.BytesIO(_figures.png_bytes(fig, 50)))

    inside = png(0.1)
    assert inside.mode == "RGB" and inside.size[0] < 4.0 * 50 and inside.size[1] < 3.0 * 50  # margins cut
    outside = png(0.8)
    assert outside.size[0] > 4.0 * 50  # the note sticks out: the PNG holds all of it (savefig's tight box)


def test_log_axes_are_labelled_in_plain_text():
    """``10⁻³`` with superscripts, not mathtext (whose parser costs tens of ms a label); the same ticks."""
    fig = _figures.FIGURES["identifiability"]([{"label": "a", "names": ("R", "Ld"), "rank": 2, "dead": (),
                                                "singular_values": [1.0, 1e-3], "sensitivity": [2.0, 1e-4]}])
    fig.canvas.draw()
    labels = [t.get_text() for ax in fig.axes for t in ax.get_yticklabels() if t.get_text()]
    _figures.plt.close(fig)
    assert "10⁻³" in labels and "10⁰" in labels and not any("$" in t for t in labels)
