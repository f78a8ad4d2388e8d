"""Iron that saturates beyond drivecal's law: where the fit cannot converge and the saturation terms' score tests
flag the data, the verdict names that (not the bench effects), with its fix.

On the published PM-SyRM of Lelli et al. (ICEM 2024), whose iron bridges saturate asymmetrically in i_d, the
law about the magnet does not converge; the default selection then tries the law with the iron bridge and
calibrates (tests/selection/test_magnetics_selection.py, which also checks the evidence read here). This verdict is
what a user sees where no law drivecal tries converges; it is checked on result JSONs built for it.
"""

from __future__ import annotations

import pytest

from drivecal.diagnose import verdict


def _result(*, converged: bool, how: str = "not supported", p_value: float = 1e-40) -> dict:
    """A fit's result JSON with the q-axis saturation term left out as ``how`` after a score test of ``p_value``."""
    choice = {"effect": "saturation_q", "included": False, "how": how, "test": "score", "statistic": 180.0,
              "dof": 1, "p_value": p_value, "p_threshold": 1e-3, "estimate": {}, "note": ""}
    return {"converged": converged, "message": "200 LM steps", "parameters": {"R": {"identifiable": True}},
            "residuals": {"white": False, "per_segment": [], "whiteness_p_threshold": 1e-3, "sigma_stated": 0.02,
                          "sigma_hat": 0.6, "sigma_ratio": 30.0, "sigma_ratio_max": 1.5, "noise_consistent": False,
                          "unmodelled_effects": []},
            "effects": {"magnetic_model": "linear", "effects": [choice]}}


def test_a_fit_that_cannot_converge_on_flagged_saturation_names_the_iron():
    judged = verdict(_result(converged=False))
    assert judged["status"] == "failed"
    assert "most likely magnetic saturation beyond drivecal's saturating law" in judged["headline"]
    assert judged["details"][0].startswith("the score tests find magnetic saturation (saturation q p = 1e-40)")
    assert "drivecal plan --imax" in judged["details"][0]
    assert "a [lelli] table" in judged["details"][0]  # the law with the iron bridge: the fix for a PM-assisted motor


@pytest.mark.parametrize("case", [dict(converged=True), dict(converged=False, p_value=0.2),
                                  dict(converged=False, how="masked"), dict(converged=False, how="not identifiable")])
def test_no_such_finding_without_its_evidence(case):
    judged = verdict(_result(**case))
    assert "beyond drivecal" not in judged["headline"] and not any("saturates beyond" in d for d in judged["details"])
