"""Flux and inductance maps with bands: a linear calibration's maps are its planes and constants, with the
parameters' own intervals; the tested range follows the data; the JSON section round-trips."""

from __future__ import annotations

import json

import numpy as np

from drivecal.maps import MAPS, flux_maps, covered_points


def test_linear_maps_are_the_parameters_planes(default_fit, default_bench):
    cal = default_fit
    maps = flux_maps(cal, default_bench.currents)
    m = cal.motor
    d, q = np.meshgrid(maps.i_d, maps.i_q, indexing="ij")
    np.testing.assert_allclose(maps.maps["psi_d"].value, float(m.lambda_m) + float(m.Ld) * d, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(maps.maps["psi_q"].value, float(m.Lq) * q, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(maps.maps["L_dd"].value, float(m.Ld), rtol=1e-10)
    np.testing.assert_allclose(maps.maps["L_qq"].value, float(m.Lq), rtol=1e-10)
    np.testing.assert_allclose(maps.maps["L_dq"].value, 0.0, atol=1e-15)
    # The incremental inductance of a linear machine is Ld itself: its band is Ld's interval.
    i = cal.names.index("Ld")
    np.testing.assert_allclose(maps.maps["L_dd"].se, float(cal.se[i]), rtol=1e-8)
    np.testing.assert_allclose(maps.maps["L_dd"].low, float(cal.ci95[i, 0]), rtol=1e-8)
    # At zero current psi_d is lambda_m, with lambda_m's SE.
    z = (int(np.argmin(np.abs(maps.i_d))), int(np.argmin(np.abs(maps.i_q))))
    j = cal.names.index("lambda_m")
    if maps.i_d[z[0]] == 0.0 and maps.i_q[z[1]] == 0.0:
        np.testing.assert_allclose(maps.maps["psi_d"].se[z], float(cal.se[j]), rtol=1e-8)
    assert maps.small_signal["Ld"] == (float(m.Ld), float(cal.se[i]))
    np.testing.assert_allclose(maps.apparent["Ld"][0], float(m.Ld), rtol=1e-10)
    assert not maps.saturating


def test_the_tested_range_is_where_the_data_went():
    grid = np.linspace(0.0, 10.0, 11)
    # A d-axis step and a q-axis step: the axes are tested, the corner where both flow is not.
    currents = np.concatenate([np.stack([np.linspace(0, 10, 200), np.zeros(200)], 1),
                               np.stack([np.zeros(200), np.linspace(0, 10, 200)], 1)])
    tested = covered_points(grid, grid, currents)
    assert tested[:, 0].all() and tested[0, :].all()
    assert not tested[1:, 1:].any()


def test_json_section(default_fit, default_bench):
    doc = json.loads(json.dumps(flux_maps(default_fit, default_bench.currents, points=5).to_dict()))
    assert set(doc["maps"]) == set(MAPS)
    assert np.shape(doc["maps"]["psi_d"]["value"]) == (len(doc["i_d"]), len(doc["i_q"])) == np.shape(doc["tested"])
    assert doc["small_signal"]["Ld"]["estimate"] > 0 and doc["units"]["L_dd"] == "H"


def test_map_figure_renders_from_the_json(default_fit, default_bench):
    from drivecal.report import plots

    section = json.loads(json.dumps(flux_maps(default_fit, default_bench.currents, points=7).to_dict()))
    fig = plots.flux_maps_figure(section)
    assert len(fig.axes) == 4 and fig.axes[2].get_ylabel() == "L_dd [mH]"
