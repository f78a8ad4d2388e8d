"""Solver settings of a fit (FitOptions)."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """Solver settings.

    Attributes:
        rtol, atol: optimistix LM termination tolerances on ``z = ln(theta/prior)``
            and on the residuals. 1e-5 moves no estimate by more than ~3e-5
            standard errors from a solve at 1e-10 (128 noise seeds of the default
            plan, from the data, the prior and +-50 % random starts), and spares
            the steps a tighter tolerance spends on rejected noise-level trials.
        max_steps: LM steps before giving up (reported, not raised).
        first_pass_steps: batches only: under ``vmap`` every fit of a batch runs
            until its slowest member stops, so the batch is first solved with at
            most this many steps, and only the fits that hit it are solved again
            from their start with ``max_steps`` (in a small batch of their own).
            The results are those of one solve with ``max_steps``. None: one
            pass; ``"auto"``: 3 from a start found in the data (~97 % of fits
            stop after 3 with the statistical stop), else 16.
        start: where the search starts when no ``initial`` is given: ``"data"``,
            an equation-error estimate from the recorded currents
            (``initial.start_from_data``; ~1 % from the optimum, so LM needs
            ~3 steps instead of ~12 from a datasheet guess), or ``"prior"``.
        step_se: also stop at an accepted point where the Gauss-Newton step
            from it, ``(J^T J)^-1 J^T r``, measures at most this many standard
            errors in the covariance's own metric (``sqrt(dz^T J^T J dz) /
            sigma_hat``, which bounds every parameter's move in its SE): the
            point is then that close to the optimum, and the step that
            optimistix's termination would still take to confirm it (one more
            rollout and Jacobian) is skipped. That last step is then applied
            (the estimate lands ~1e-4 of step_se from the optimum; sigma_hat and
            the covariance are those of the accepted point, step_se SE away).
            0 turns both off.
        shared_jacobian_steps: batches solved in tiles (``SOLVE_TILE``) from a
            start found in the data only: Gauss-Newton steps taken from that
            start before LM, every fit of a tile using the Jacobian of the
            tile's first fit at that fit's current point (forward differences).
            A step costs each fit one rollout of its model instead of a
            Jacobian sweep (the rollout and one tangent per parameter), and two
            take a fleet's starts from ~100 to ~0.3 standard errors from their
            optima (median over 256 motors, in the covariance's metric; at most
            ~8), so LM then stops after two sweeps instead of three. A fit whose
            residual the first step does not reduce keeps its data start. 0
            turns them off; the estimates agree either way to ~1e-6 SE.
    """

    rtol: float = 1e-5
    atol: float = 1e-5
    step_se: float = 1e-2
    max_steps: int = 200
    first_pass_steps: int | str | None = "auto"
    start: str = "data"
    shared_jacobian_steps: int = 2

    def __post_init__(self):
        if self.start not in ("data", "prior"):
            raise ValueError(f"FitOptions.start must be 'data' or 'prior', got {self.start!r}")
