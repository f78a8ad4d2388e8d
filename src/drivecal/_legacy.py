"""The flat module paths of drivecal 0.1 (``drivecal.forward``, ``drivecal.fit``, ...), kept for one release.

Each old path imports as a module whose attributes come from the sub-packages
that now own them, with a ``DeprecationWarning`` naming the new place. Old
code such as ``from drivecal.forward import predict_currents`` keeps working;
new code imports from the sub-packages (or from ``drivecal`` itself).
"""

from __future__ import annotations

import importlib
import importlib.machinery
import sys
import types
import warnings

#: old module -> the modules that hold its names now, searched in order.
MOVED: dict[str, tuple[str, ...]] = {
    "autoplan": ("design._autoplan",),
    "config": ("plan._files", "plan._plan", "data._motor_file", "data._motor_spec", "_units", "_schema"),
    "distributions": ("_stats",),
    "export": ("bench._blocks",),
    "fit": ("fitting._fit", "fitting._options", "fitting._solver", "results._calibration", "fitting._lm"),
    "fleet_report": ("fleet._report",),
    "forward": ("model._rollout", "model._experiment", "physics._sensors"),
    "gains": ("report._gains",),
    "html": ("report._html",),
    "initial": ("fitting._initial",),
    "inverter": ("physics._inverter",),
    "mismatch": ("diagnose._mismatch",),
    "motor": ("physics._motor",),
    "optimal": ("design._optimal", "design._design_space"),
    "plots": ("report.plots", "fleet._report"),
    "record": ("report._record", "results._record", "diagnose._judge"),
    "saturation": ("diagnose._saturation",),
    "stepbench": ("bench._step",),
    "traced": ("model._lowered_cache",),
    "verdict": ("diagnose._verdict", "diagnose._whiteness"),
    "waveforms": ("plan._waveforms",),
}


class _MovedModule(types.ModuleType):
    """An old module path: attributes are looked up in the modules that own them now.

    ``drivecal.fit`` is also the fitting function; importing the old module
    rebinds that attribute of the package, so this module calls through to it.
    """

    def __init__(self, name: str, targets: tuple[str, ...]):
        super().__init__(name)
        self.__targets = targets

    def _modules(self):
        for target in self.__targets:
            try:
                yield importlib.import_module(f"drivecal.{target}")
            except ModuleNotFoundError as exc:
                if exc.name != f"drivecal.{target}":
                    raise

    def __getattr__(self, attr: str):
        if attr.startswith("__"):
            raise AttributeError(attr)
        for module in self._modules():
            if hasattr(module, attr):
                return getattr(module, attr)
        raise AttributeError(f"module {self.__name__!r} has no attribute {attr!r}")

    def __call__(self, *args, **kwargs):
        from .diagnose import fit

        return fit(*args, **kwargs)


class _Finder:
    """A meta-path finder and loader (duck-typed: importlib.abc costs ~20 ms to import at every start)."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, leaf = fullname.rpartition(".")
        if package != "drivecal" or leaf not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec):
        leaf = spec.name.rpartition(".")[2]
        homes = dict.fromkeys(f"drivecal.{t.split('._')[0]}" for t in MOVED[leaf])  # the public sub-packages
        warnings.warn(f"{spec.name} is gone since drivecal 0.2: import from {', '.join(homes)} "
                      "(or from drivecal itself); the old path works for this release only",
                      DeprecationWarning, stacklevel=3)
        return _MovedModule(spec.name, MOVED[leaf])

    def exec_module(self, module):
        pass


def install(package: types.ModuleType) -> None:
    """Serve the old paths of ``package`` (idempotent)."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.append(_Finder())
