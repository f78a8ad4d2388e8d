"""The fit: Levenberg-Marquardt on the currents, then honest intervals.

Unknowns are searched as ``z = ln(theta / theta_prior)`` so every parameter
stays positive and every direction has the same scale (a raw ``ln(theta)``
lets the first trust-region step jump to stiff, absurd motors). Bench effects
that may be zero or negative (sensor offsets, dead-time voltage) are searched
additively, ``theta = theta_prior + step * z`` (``physics.search_scale``). A batch's
whole solve — optimistix LM, the Jacobian at the optimum, the covariance — is one
``jax.jit``-compiled function, ``vmap``-ped over datasets and starting points; a
single fit takes the same steps from the host, each one call of its sensitivity
kernel (``_host_lm``).

Uncertainty: ``Cov = sigma_hat^2 (J^T J)^-1`` with ``sigma_hat^2 = ||r||^2 / (m - n)``,
standard errors from its diagonal and Student-t 95 % intervals with m - n
degrees of freedom (m current samples, n fitted parameters). Under vmap
nothing throws: each fit carries its own result code.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._stats import t_ppf
from ..data import BenchData, MotorFile, SpeedChoice, choose_speed
from ..errors import DrivecalError
from ..identify import Identifiability, assess_identifiability
from ..model import Experiment, model_experiment, with_experiment_delay
from ..physics import ESTIMATED, MotorParams, from_search, parameter_values, to_search
from ..results import Calibration
from ._options import FitOptions
from ._host_lm import solve_on_host
from ._solver import _Solved, _first, _solve_staged


def _start_vector(initial: MotorParams | np.ndarray | None, prior: MotorParams, names: tuple[str, ...]) -> np.ndarray:
    if initial is None:
        return parameter_values(prior, names, np)
    if isinstance(initial, MotorParams):
        return parameter_values(initial, names, np)
    return np.asarray(initial, dtype=float)


def fit_currents(
    experiment: Experiment,
    currents: np.ndarray,
    prior: MotorParams,
    *,
    initial: MotorParams | np.ndarray | None = None,
    identifiability: Identifiability | None = None,
    names: tuple[str, ...] = ESTIMATED,
    options: FitOptions = FitOptions(),
    source: str = "synthetic bench",
    delay_samples: float | None = None,
) -> Calibration:
    """Fit measured currents of a known experiment; batched if ``currents`` is.

    Args:
        experiment: the applied voltages and rotor conditions (M samples),
            shared by all datasets or, with a leading axis B on every array,
            one per dataset (then ``currents`` must be batched).
        currents: measured ``[i_d, i_q]`` (A), shape (M, 2) or (B, M, 2).
        prior: nominal motor: scale of the search, value of anything not
            identifiable, and the fixed parameters.
        initial: starting point, shape (len(names),) or (B, len(names)) in SI
            units, or a MotorParams; default ``options.start`` (an estimate
            from the data, or the prior).
        identifiability: a verdict already computed for this experiment and
            prior (computed here if not given).
        names: parameters to estimate.
        options: solver settings.
        source: label of the data, for reports.
        delay_samples: the nominal inverter delay (samples) recorded in the
            result; default ``prior.delay`` (whose whole samples the experiment
            applies; see ``Experiment.base_delay``).

    Returns:
        A :class:`Calibration`, with a leading batch axis when ``currents`` has one.
    """
    currents = np.asarray(currents, dtype=float)
    batched = currents.ndim == 3
    if currents.shape[-2:] != (experiment.num_samples, 2):
        raise DrivecalError(
            f"{source}: currents have shape {currents.shape}, expected ({experiment.num_samples}, 2) "
            "to match the experiment."
        )
    if not np.all(np.isfinite(currents)):
        raise DrivecalError(f"{source}: currents contain NaN or Inf; remove or repair those samples.")
    per_dataset = experiment.voltages.ndim == 3
    if per_dataset and (not batched or experiment.voltages.shape[0] != currents.shape[0]):
        raise DrivecalError(f"{source}: a batch of {experiment.voltages.shape[0]} experiments needs currents of "
                            f"shape ({experiment.voltages.shape[0]}, M, 2), got {currents.shape}.")
    prior = with_experiment_delay(prior, experiment)
    experiment = model_experiment(experiment, prior, names)
    # A batch of experiments shares one plan shape; judge it on the first (the structure is common).
    first = _first(experiment) if per_dataset else experiment
    ident = identifiability or assess_identifiability(first, prior, names=names)
    fit_names = ident.fit_names
    if not fit_names:
        raise DrivecalError(
            f"{source}: this experiment identifies none of {', '.join(names)}; "
            "add locked d/q steps and a free spin-up."
        )
    cur = currents if batched else currents[None]
    fit_idx = [names.index(n) for n in fit_names]
    start = None  # from the data, inside the compiled solve
    if initial is not None or options.start != "data":
        start = np.broadcast_to(_start_vector(initial, prior, names), cur.shape[:1] + (len(names),))
        if not np.all(np.isfinite(to_search(prior, fit_names, start[:, fit_idx]))):
            raise DrivecalError(f"{source}: initial values of {', '.join(fit_names)} must be finite, and positive "
                                "where the parameter is (R, inductances, flux, alpha_R).")
    history = None
    if batched:
        solved = _solve_staged(cur, start, prior, experiment, tuple(names), fit_names, options)
    else:  # stepped from the host with the identifiability check's kernel: no solve program to compile or load
        solved = _Solved(**solve_on_host(cur, start, prior, experiment, tuple(names), fit_names, options))
        z0 = to_search(prior, fit_names, solved.initial[:, fit_idx])
        steps = [z0[0]] + list(np.asarray(solved.accepted)[0, : int(solved.iterations[0])])
        steps = [steps[0]] + [b for a, b in zip(steps, steps[1:]) if not np.array_equal(a, b)]
        history = from_search(prior, fit_names, np.asarray(steps), np)[0]
        if not np.array_equal(history[-1], solved.theta[0]):  # the final Gauss-Newton step (FitOptions.step_se)
            history = np.concatenate([history, solved.theta[:1]])

    m = experiment.num_samples * 2
    t_factor = float(t_ppf(0.975, m - len(fit_names)))
    b = cur.shape[0]
    estimate = np.broadcast_to(parameter_values(prior, names, np), (b, len(names))).copy()
    se = np.full((b, len(names)), np.nan)
    estimate[:, fit_idx] = solved.theta
    se[:, fit_idx] = np.sqrt(np.diagonal(solved.covariance, axis1=-2, axis2=-1))
    ci95 = np.stack([estimate - t_factor * se, estimate + t_factor * se], axis=-1)
    calib = Calibration(
        names=tuple(names),
        estimate=estimate,
        se=se,
        ci95=ci95,
        identifiable=tuple(n in fit_names for n in names),
        fit_names=fit_names,
        covariance=np.asarray(solved.covariance),
        sigma_hat=np.asarray(solved.sigma_hat),
        rss=np.asarray(solved.rss),
        iterations=np.asarray(solved.iterations),
        converged=np.asarray(solved.converged),
        result_code=np.asarray(solved.result_code),
        initial=np.array(solved.initial),
        prior=prior,
        identifiability=ident,
        num_residuals=m,
        t_factor=t_factor,
        source=source,
        history=history,
        delay_samples=float(prior.delay if delay_samples is None else delay_samples),
        residuals=np.asarray(solved.residuals),
    )
    return calib if batched else calib[0]


def fit(
    bench: BenchData,
    prior: MotorParams | MotorFile,
    *,
    initial: MotorParams | np.ndarray | None = None,
    names: tuple[str, ...] | None = None,
    options: FitOptions = FitOptions(),
    measured_speed: bool | None = None,
    delay_samples: float | None = None,
    speed: str | None = None,
) -> Calibration:
    """Calibrate a motor from bench data.

    Identifiability is judged first at ``prior``; parameters the bench run
    cannot identify are held at their prior and reported as such. The fit is
    not judged here: the package's ``drivecal.fit`` (``drivecal.diagnose.fit``)
    is this fit with its verdict and residual diagnostics attached.

    Args:
        bench: the recorded run.
        prior: nominal motor (datasheet values) and fixed parameters: a ``MotorParams``, or a
            loaded motor file (``drivecal.load_motor``), whose ``estimate`` list and
            ``delay_samples`` then apply unless ``names`` / ``delay_samples`` are given.
        initial: starting point (default: ``options.start``, an estimate from the data).
        names: parameters to estimate (default: the motor file's ``estimate``, else R, Ld, Lq, lambda_m).
        options: solver settings.
        measured_speed: where free segments carry a measured ``w_m``, True uses it as an input so J and B
            play no part, False simulates the speed from J and B (see ``BenchData.experiment``); None (the
            default) chooses as ``drivecal fit`` does (``drivecal.data.choose_speed``): an input, unless
            mechanics are estimated or the speed is too coarse or noisy to be an exact input (a quantised
            encoder difference), when it is a second measured output; a warning says why.
        delay_samples: the inverter's nominal PWM/computation delay (samples);
            default ``prior.delay``. Estimated when ``"delay"`` is in ``names``.
        speed: what a measured ``w_m`` is, replacing ``measured_speed``: "input", "output"
            (a second measured output, weighed by the sensors' noise: the motor file's, else estimated
            from the data) or "ignore" (see ``BenchData.experiment``).
    """
    experiment, prior, names, _ = fit_setup(bench, prior, names=names, measured_speed=measured_speed,
                                            delay_samples=delay_samples, speed=speed)
    return fit_currents(experiment, bench.currents, prior, initial=initial, names=names, options=options,
                        source=bench.source, delay_samples=float(prior.delay))


def fit_setup(
    bench: BenchData,
    prior: MotorParams | MotorFile,
    *,
    names: tuple[str, ...] | None = None,
    measured_speed: bool | None = None,
    delay_samples: float | None = None,
    speed: str | None = None,
) -> tuple[Experiment, MotorParams, tuple[str, ...], SpeedChoice]:
    """What :func:`fit` fits: ``(experiment, prior, names, speed_choice)`` (arguments as :func:`fit`).

    The motor file's estimate list, delay and sensor noises applied; the prior's ``delay`` the nominal
    delay (samples); the measured speed's role chosen (``drivecal.data.choose_speed``; a warning says
    why when it is not the one asked for).
    """
    noises, mechanics_given = (None, None), True
    if isinstance(prior, MotorFile):
        names = names if names is not None else prior.estimate
        if delay_samples is None:
            delay_samples = prior.delay_samples
        noises, mechanics_given = (prior.current_noise, prior.speed_noise), prior.mechanics_given
        prior = prior.motor
    names = ESTIMATED if names is None else tuple(names)
    if delay_samples is not None:
        prior = prior.replace(delay=float(delay_samples))
    if speed is None and measured_speed is not None:
        speed = "input" if measured_speed else "ignore"
    choice = choose_speed(bench, prior, names, speed=speed, current_noise=noises[0], speed_noise=noises[1],
                          mechanics_given=mechanics_given)
    if choice.reason:
        warnings.warn(f"{bench.source}: {choice.reason}", stacklevel=3)
    experiment = bench.experiment(delay_samples=float(prior.delay), speed=choice.mode, current_noise=noises[0],
                                  speed_noise=noises[1])
    return experiment, prior, names, choice
