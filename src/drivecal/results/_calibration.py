"""The Calibration: a fitted motor, its uncertainty and how the fit ended (the result type; no solver in here).

Reading, printing or saving a result needs only this module: the solver lives
in :mod:`drivecal.fitting`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .._stats import t_ppf
from .._units import estimate_cells, format_quantity, format_value
from ..identify import Identifiability
from ..physics import ADDITIVE_SCALE, BRIDGE, EXPONENTS, FIXED, MAGNETIC, MECHANICAL, NUISANCE, UNITS, MotorParams
from .._status import solver_message
from ._record import json_ready, validate_fit
from ._verdict import Verdict


def result_message(code: int, converged: bool) -> str:
    """How a fit ended, in words: 'converged', or optimistix's message for ``code``."""
    if converged:
        return "converged"
    message = solver_message(code)
    return message or "the covariance is not finite: the data does not constrain the fitted parameters"


#: The first line of ``print(cal)`` for a fit that carries no verdict.
NOT_JUDGED = ("[[Verdict]] not judged: drivecal.fit(bench, prior) judges its fit; for this one, "
              "drivecal.judge_fit(cal, bench)")


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A fitted motor: estimates, uncertainty and how the fit ended.

    Array fields may carry a leading batch axis (a batch of fits is the same
    object; index it to get one). Parameters the experiment cannot identify
    keep their prior value, have ``identifiable`` False and NaN uncertainty.

    Attributes:
        names: estimated parameter names (R, Ld, Lq, lambda_m by default).
        estimate: (..., len(names)) estimates, SI units.
        se: (..., len(names)) standard errors, NaN where not identifiable.
        ci95: (..., len(names), 2) Student-t 95 % intervals [low, high].
        identifiable: per name, whether it was fitted.
        fit_names: the fitted names: the axes of ``covariance``.
        covariance: (..., n, n) covariance of the fitted names, SI units.
        sigma_hat: (...,) residual standard deviation (A).
        rss: (...,) residual sum of squares (A^2).
        iterations: (...,) LM steps taken.
        converged: (...,) whether the solve ended successfully.
        result_code: (...,) optimistix result index (0 = successful).
        initial: (..., len(names)) starting point of the search.
        prior: the nominal motor (also holds the fixed parameters).
        identifiability: the pre-fit identifiability verdict.
        num_residuals: m, current samples fitted (i_d and i_q).
        t_factor: Student-t 97.5 % quantile with m - n degrees of freedom.
        source: where the data came from.
        history: (K, n) accepted LM iterates of ``fit_names`` (SI), the start
            first and the estimate last; single fits only, else None.
        delay_samples: the nominal inverter delay (samples) the fit started from (the prior's ``delay``;
            the whole samples of it are applied in the experiment). Where ``delay`` is estimated its
            estimate is among the parameters.
        residuals: (..., M, 2) model minus measured ``[i_d, i_q]`` (A) at the
            solver's last linearisation (the estimate is at most a final
            Gauss-Newton step of ``FitOptions.step_se`` SE from it), or None.
        verdict: how the calibration ended (:class:`Verdict`: status, headline, details), or None where
            it was not judged: ``drivecal.fit`` judges its fit; ``drivecal.fitting.fit`` and
            ``fit_currents`` do not (``drivecal.judge_fit(cal, bench)`` does it afterwards).
        diagnostics: the residual diagnostics the verdict rests on, the result JSON's ``residuals``
            section (plain JSON data: sigma_hat against the sensor noise, whiteness per segment and
            axis, the unmodelled-effect tests), or None where not judged.
    """

    names: tuple[str, ...]
    estimate: np.ndarray
    se: np.ndarray
    ci95: np.ndarray
    identifiable: tuple[bool, ...]
    fit_names: tuple[str, ...]
    covariance: np.ndarray
    sigma_hat: np.ndarray
    rss: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    result_code: np.ndarray
    initial: np.ndarray
    prior: MotorParams
    identifiability: Identifiability
    num_residuals: int
    t_factor: float
    source: str = "synthetic bench"
    history: np.ndarray | None = None
    delay_samples: float = 0.0
    residuals: np.ndarray | None = None
    verdict: Verdict | None = None
    diagnostics: dict[str, Any] | None = None

    # --- batch handling --------------------------------------------------

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """() for one fit, (B,) for a batch."""
        return tuple(self.sigma_hat.shape)

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError("a single Calibration has no len(); it is not a batch")
        return self.batch_shape[0]

    def __getitem__(self, i: int) -> Calibration:
        """The i-th fit of a batch."""
        if not self.batch_shape:
            raise TypeError("a single Calibration cannot be indexed; it is not a batch")
        fields = ("estimate", "se", "ci95", "covariance", "sigma_hat", "rss", "iterations", "converged",
                  "result_code", "initial") + (("residuals",) if self.residuals is not None else ())
        return dataclasses.replace(self, **{f: getattr(self, f)[i] for f in fields})

    # --- convenient views ------------------------------------------------

    @property
    def motor(self) -> MotorParams:
        """The calibrated motor: estimates, with the fixed parameters of the prior."""
        return self.prior.with_vector(self.names, np.asarray(self.estimate, dtype=float))

    @property
    def correlation(self) -> np.ndarray:
        """(..., n, n) correlation matrix of the fitted names."""
        with np.errstate(divide="ignore", invalid="ignore"):  # a zero or undefined variance: NaN
            sd = np.sqrt(np.diagonal(self.covariance, axis1=-2, axis2=-1))
            return self.covariance / (sd[..., :, None] * sd[..., None, :])

    @property
    def dof(self) -> int:
        """Residual degrees of freedom m - n."""
        return self.num_residuals - len(self.fit_names)

    @property
    def message(self) -> str:
        """How the fit ended, in words (single fits)."""
        return result_message(int(self.result_code), bool(self.converged))

    @property
    def fixed(self) -> dict[str, float]:
        """Parameters held fixed: the mechanical ones, and unidentifiable ones at their prior."""
        out = {n: float(getattr(self.prior, n)) for n in FIXED if n not in self.names}
        # Bench effects and torques the user set but did not ask to estimate are assumptions too.
        out.update({n: float(getattr(self.prior, n)) for n in NUISANCE + MECHANICAL
                    if n not in self.names and n in ADDITIVE_SCALE and float(getattr(self.prior, n)) != 0.0})
        for n, ok in zip(self.names, self.identifiable):
            if not ok:
                out[n] = float(getattr(self.prior, n))
        return out

    def to_dict(self) -> dict[str, Any]:
        """The result JSON of a single fit (SI units; null where undefined).

        Carries everything :meth:`from_dict` needs to rebuild this object:
        the full covariance with its names, the prior motor, the LM history,
        the ``verdict`` and the residual diagnostics (``residuals``; both null
        where the fit was not judged). ``drivecal.build_result`` adds the traces
        and provenance of a saved result.
        """
        if self.batch_shape:
            raise TypeError("to_dict() is for one fit; index the batch first")

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        params = {}
        for i, n in enumerate(self.names):
            ok = self.identifiable[i]
            params[n] = {
                "estimate": num(self.estimate[i]),
                "se": num(self.se[i]) if ok else None,
                "ci95": [num(self.ci95[i, 0]), num(self.ci95[i, 1])] if ok else None,
                "unit": UNITS[n],
                "identifiable": bool(ok),
                "initial": num(self.initial[i]),
                "prior": num(getattr(self.prior, n)),
            }
            if not ok:
                params[n]["reason"] = self.identifiability.reasons.get(n, "not identifiable")
        history = None
        if self.history is not None:
            history = {"names": list(self.fit_names), "values": [[num(v) for v in row] for row in self.history]}
        return {
            "parameters": params,
            "names": list(self.fit_names),
            "covariance": [[num(c) for c in row] for row in self.covariance],
            "correlation": [[num(c) for c in row] for row in self.correlation],
            "sigma_hat": num(self.sigma_hat),
            "rss": num(self.rss),
            "converged": bool(self.converged),
            "message": self.message,
            "result_code": int(self.result_code),
            "iterations": int(self.iterations),
            "num_residuals": self.num_residuals,
            "dof": self.dof,
            "t_factor": self.t_factor,
            "identifiability": self.identifiability.to_dict(),
            "fixed": self.fixed,
            "prior": self.prior.all_values(),
            "history": history,
            "source": self.source,
            "delay_samples": self.delay_samples,
            "residuals": json_ready(self.diagnostics),
            "verdict": None if self.verdict is None else self.verdict.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "result") -> Calibration:
        """Rebuild a single fit from :meth:`to_dict` output (e.g. a saved result JSON).

        ``null`` becomes NaN. Results saved before the ``prior`` section existed
        get their prior from ``parameters.<name>.prior`` and ``fixed``.

        Args:
            d: one fit's result JSON.
            source: the file it came from, for messages.

        Raises:
            DataError: a field missing, null where a number is needed, of the
                wrong type or shape, a covariance that is not symmetric positive
                semi-definite, or a verdict whose status is not a :class:`Status` key
                (``drivecal.results.validate_fit``; one sentence naming ``source`` and the field).
        """
        validate_fit(d, source, sections=False)
        def arr(x):
            return np.array([[np.nan if v is None else float(v) for v in row] for row in x], dtype=float)

        def num(x):
            return np.nan if x is None else float(x)

        params = d["parameters"]
        names = tuple(params)
        fit_names = tuple(d["names"])
        ci = [params[n].get("ci95") or [None, None] for n in names]
        if d.get("prior") is not None:  # null: rebuilt from the parameters, as the JSON check allows
            prior = MotorParams(**{k: float(v) for k, v in d["prior"].items()})
        else:
            prior = MotorParams(**{**{n: params[n]["prior"] for n in names},
                                   **{n: d["fixed"][n] for n in FIXED if n in d["fixed"]}})
        hist = d.get("history")
        m = int(d["num_residuals"])
        return cls(
            names=names,
            estimate=np.array([num(params[n]["estimate"]) for n in names]),
            se=np.array([num(params[n]["se"]) for n in names]),
            ci95=arr(ci),
            identifiable=tuple(bool(params[n]["identifiable"]) for n in names),
            fit_names=fit_names,
            covariance=arr(d["covariance"]) if fit_names else np.zeros((0, 0)),
            sigma_hat=np.float64(num(d["sigma_hat"])),
            rss=np.float64(num(d.get("rss"))),
            iterations=np.int64(d["iterations"]),
            converged=np.bool_(d["converged"]),
            result_code=np.int64(d.get("result_code", 0 if d["converged"] else -1)),
            initial=np.array([num(params[n].get("initial", params[n]["estimate"])) for n in names]),
            prior=prior,
            identifiability=Identifiability.from_dict(d["identifiability"]),
            num_residuals=m,
            t_factor=float(d.get("t_factor") or t_ppf(0.975, m - len(fit_names))),
            source=d.get("source", "synthetic bench"),
            history=None if hist is None else arr(hist["values"]),
            delay_samples=float(d.get("delay_samples", 0)),
            verdict=None if d.get("verdict") is None else Verdict.from_dict(d["verdict"], source),
            diagnostics=json_ready(d.get("residuals")),
        )

    def to_pandas(self):
        """One row per parameter: estimate, SE, 95 % CI, relative CI half-width (%), identifiable.

        Values in SI units, named in the ``unit`` column; index ``parameter``.
        """
        import pandas as pd

        if self.batch_shape:
            raise TypeError("to_pandas() is for one fit; index the batch first")
        half = self.t_factor * self.se
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = 100.0 * half / np.abs(self.estimate)
        return pd.DataFrame(
            {
                "unit": [UNITS[n] for n in self.names],
                "estimate": self.estimate,
                "se": self.se,
                "ci95_low": self.ci95[:, 0],
                "ci95_high": self.ci95[:, 1],
                "rel_ci95_percent": rel,
                "identifiable": list(self.identifiable),
                "prior": [float(getattr(self.prior, n)) for n in self.names],
                "initial": self.initial,
                "reason": [self.identifiability.reasons.get(n, "") for n in self.names],
            },
            index=pd.Index(self.names, name="parameter"),
        )

    def to_jaxonomy(self, *, locked: bool = False, initial_state: Any = None, name: str = "pmsm"):
        """A ``jaxonomy.library.drives.PMSM`` block configured with this calibration.

        Estimates for the identifiable parameters, the prior for the rest and
        for the fixed ones (pole_pairs, J, B, T_load). Where the calibrated law
        saturates, the block is the PMSM with flux-linkage states and the same
        current-of-flux law (``drivecal.bench.pmsm_block`` gives it): its currents
        are the model's.

        Args:
            locked: clamp the rotor (standstill bench), fixed when the block is built.
            initial_state: ``[i_d, i_q, w_m, theta_m]`` (A, A, rad/s, rad); default rest.
            name: block name in the diagram.
        """
        from ..bench import pmsm_block

        if self.batch_shape:
            raise TypeError("to_jaxonomy() is for one fit; index the batch first")
        return pmsm_block(self.motor, locked=locked, initial_state=initial_state, name=name)

    def warnings(self) -> list[str]:
        """Plain-language warnings: non-identifiable parameters, failed fit, strong correlations."""
        out = []
        if not bool(self.converged):
            out.append(f"the fit did not converge: {self.message}")
        for i, n in enumerate(self.names):
            if not self.identifiable[i]:
                why = self.identifiability.reasons.get(n, "not identifiable")
                out.append(f"{n} is not identifiable ({why}); held at its prior "
                           f"{format_quantity(float(self.estimate[i]), UNITS[n])}, not calibrated")
        for a, b, r in self.correlations(threshold=0.9):
            out.append(f"{a} and {b} are strongly correlated (r = {r:+.3f}): the data mostly fixes a combination")
        return out

    def correlations(self, threshold: float = 0.1) -> list[tuple[str, str, float]]:
        """Pairs of fitted parameters with ``|r| > threshold``, largest first."""
        corr = self.correlation
        pairs = [(self.fit_names[i], self.fit_names[j], float(corr[i, j]))
                 for i in range(len(self.fit_names)) for j in range(i + 1, len(self.fit_names))]
        return sorted([p for p in pairs if abs(p[2]) > threshold], key=lambda p: -abs(p[2]))

    def __repr__(self) -> str:
        """``Calibration(R = 450.027 ± 0.043 mΩ, ..., converged, source)``: the estimates in engineering units."""
        if self.batch_shape:
            return f"Calibration(batch of {len(self)} fits, {int(np.sum(self.converged))} converged)"
        parts = [f"{n} = {format_quantity(float(self.estimate[i]), UNITS[n], float(self.se[i]))}"
                 if self.identifiable[i] else f"{n} = {format_quantity(float(self.estimate[i]), UNITS[n])} (prior)"
                 for i, n in enumerate(self.names)]
        judged = "" if self.verdict is None else f"verdict {self.verdict.status.key}; "
        return f"Calibration({', '.join(parts)}; {self.message}; {judged}{self.source})"

    def __str__(self) -> str:
        """The verdict first, then an lmfit-style report: fit statistics, parameters, correlations, warnings."""
        if self.batch_shape:
            n_ok = int(np.sum(self.converged))
            return f"Calibration batch of {len(self)} fits, {n_ok} converged"
        ident = self.identifiability
        stat = [
            ("source", self.source),
            ("fit result", f"{self.message} after {int(self.iterations)} LM steps"),
            ("# data points", f"{self.num_residuals} (i_d and i_q samples)"),
            ("# variables", f"{len(self.fit_names)} ({', '.join(self.fit_names)})"),
            ("degrees of freedom", f"{self.dof}"),
            ("sigma_hat", format_quantity(float(self.sigma_hat), "A")),
            ("RSS [A^2]", f"{float(self.rss):.6g}"),
            ("identifiability", ident.summary()),
        ]
        lines = self.verdict.lines() if self.verdict is not None else [NOT_JUDGED]
        lines += ["[[Fit Statistics]]"] + [f"    {k:<19}= {v}" for k, v in stat]
        lines += ["[[Parameters]]"] + self._parameter_lines()
        lines += self._magnetic_lines()
        pairs = self.correlations(threshold=0.1)
        lines.append("[[Correlations]] (unreported correlations are < 0.100)")
        lines += [f"    C({a}, {b}){'':<{max(0, 16 - len(a) - len(b))}} = {r:+.4f}" for a, b, r in pairs] or [
            "    none"]
        warnings = self.warnings()
        if warnings:
            lines.append("[[Warnings]]")
            lines += [f"    {w}" for w in warnings]
        return "\n".join(lines)

    def _parameter_lines(self) -> list[str]:
        """One line per parameter in its engineering unit (mΩ, mH, mWb): estimate, SE and 95 % CI to the SE's
        second significant digit."""
        rows = [("name", "unit", "estimate", "std err", "95% CI", "rel. CI", "identifiable")]
        for i, n in enumerate(self.names):
            value, se = float(self.estimate[i]), float(self.se[i])
            if self.identifiable[i]:
                c = estimate_cells(value, UNITS[n], se, tuple(self.ci95[i]))
                rel = 100.0 * self.t_factor * se / abs(value) if value else math.nan
                rows.append((n, c.unit, c.estimate, c.se, f"[{c.ci[0]}, {c.ci[1]}]",
                             "-" if rel != rel else f"+/-{format_value(rel, 1.0, rel)} %", "yes"))
            else:
                c = estimate_cells(value, UNITS[n])
                rows.append((n, c.unit, c.estimate, "-", "held at prior", "-", "NO"))
        widths = [max(len(r[k]) for r in rows) for k in range(6)]
        return [f"    {r[0]:<{widths[0]}} {r[1]:<{widths[1]}} {r[2]:>{widths[2]}} {r[3]:>{widths[3]}} "
                f"{r[4]:>{widths[4]}} {r[5]:>{widths[5]}}  {r[6]}" for r in rows]

    def _magnetic_lines(self) -> list[str]:
        """The saturating law's settings, where the calibrated motor saturates (else nothing)."""
        m = self.motor
        terms = MAGNETIC + BRIDGE
        if not (set(terms) & set(self.names)) and not any(float(getattr(m, n)) != 0.0 for n in terms):
            return []
        exps = ", ".join(f"{n} = {float(getattr(m, n)):g}" for n in EXPONENTS)
        centre = "zero flux" if float(m.sat_at_zero) else "the magnet's flux"
        lines = ["[[Magnetic law]]",
                 f"    self- and cross-saturation (Hinkkanen 2017) about {centre}; Ld, Lq at zero current",
                 f"    exponents {exps}; coefficients per unit at i_ref = {float(m.i_ref):g} A"]
        if float(m.sat_b) != 0.0 or "sat_b" in self.names:
            lines.append(f"    iron bridge (Lelli 2024): exp_b = {float(m.exp_b):g}, sat_bp = {float(m.sat_bp):.4g}, "
                         f"k_q = {float(m.k_q):.4g}, psi_n = {float(m.psi_n):.4g} Wb")
        return lines + ["    maps with 95 % bands: drivecal.maps.flux_maps(cal, bench.currents)"]

    def _repr_html_(self) -> str:
        """Jupyter: the summary table of the HTML report."""
        if self.batch_shape:
            return f"<p>{str(self)}</p>"
        from ._html import escape, summary_html

        head = "" if self.verdict is None else (f'<p class="verdict {self.verdict.status.key}"><b>'
                                                f"{escape(self.verdict.headline)}</b></p>")
        return head + summary_html(self.to_dict())
