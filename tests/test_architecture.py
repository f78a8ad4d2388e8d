"""The package's layout: dependencies point down the data flow, no cycles, no private names across modules.

Every import of every module is read from its source (those inside functions
too), so a cycle hidden by a lazy import fails here as well.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "drivecal"
TESTS = Path(__file__).resolve().parent

#: The layers, lowest first: a module may import its own layer and those below it.
LAYERS: tuple[frozenset[str], ...] = tuple(frozenset(x) for x in (
    {"errors", "_version", "_setup", "_stats", "_io", "_units", "_status", "_figure_kinds", "_figures", "_page",
     "_parameters", "_lazy", "_pytree", "_schema", "_apart", "_exit"},
    {"physics"},
    {"plan"},
    {"model"},
    {"data"},
    {"bench"},
    {"identify"},
    {"results"},
    {"maps"},
    {"fitting"},
    {"diagnose"},
    {"selection"},
    {"design"},
    {"report"},
    {"fleet"},
    {"demo"},
    {"cli"},
))
#: Modules outside the layering: the package root re-exports lazily by name, and the
#: old flat paths of 0.1 are served by name (both through importlib, not import statements).
UNLAYERED = {"drivecal", "drivecal._legacy"}
#: Modules allowed past ~500 lines, with the reason.
LONG_MODULES: dict[str, str] = {}


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


MODULES = _modules()


def _layer(module: str) -> int:
    top = module.split(".")[1]
    for rank, members in enumerate(LAYERS):
        if top in members:
            return rank
    raise AssertionError(f"{module}: sub-package {top!r} is in no layer; add it to LAYERS (and the README)")


def _resolve(module: str, is_package: bool, level: int, target: str | None) -> str:
    base = module.split(".") if is_package else module.split(".")[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def _imports(module: str, path: Path) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) for every drivecal import in ``path``."""
    tree = ast.parse(path.read_text(), str(path))
    is_package = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] == "drivecal"]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, is_package, node.level, node.module) if node.level else node.module or ""
            if target.split(".")[0] != "drivecal":
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                # `from . import x` may name a module (then that module is the import) or a name.
                out.append((sub, None, node.lineno) if sub in MODULES else (target, alias.name, node.lineno))
    return out


def _owner(module: str) -> str:
    """The sub-package (or base module) a module belongs to."""
    return ".".join(module.split(".")[:2])


def _graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for module, path in MODULES.items():
        for target, _, _ in _imports(module, path):
            if target in MODULES and target != module:
                graph[module].add(target)
    return graph


def test_every_module_is_in_a_layer():
    for module in MODULES:
        if module not in UNLAYERED:
            _layer(module)


def test_no_upward_imports():
    """A module imports only its own layer and those below (inside functions too)."""
    bad = []
    for module, path in MODULES.items():
        if module in UNLAYERED:
            continue
        for target, _, line in _imports(module, path):
            if target in UNLAYERED and target != "drivecal":
                bad.append(f"{path.relative_to(PACKAGE)}:{line} imports {target}")
            elif target == "drivecal":
                bad.append(f"{path.relative_to(PACKAGE)}:{line} imports from the package root (import the sub-package)")
            elif _layer(target) > _layer(module):
                bad.append(f"{path.relative_to(PACKAGE)}:{line} imports {target} (a later layer)")
    assert not bad, "\n".join(bad)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_between_subpackages():
    """Between sub-packages the import graph is acyclic (a package's __init__ re-exporting its modules is not a cycle)."""
    graph = {m: {t for t in targets if _owner(t) != _owner(m)} for m, targets in _graph().items()
             if m not in UNLAYERED}
    graph = {m: {t for t in ts if t in graph} for m, ts in graph.items()}
    assert _cycles(graph) == []


def test_no_import_cycles_between_modules():
    """Module by module, leaving out a package's own __init__ (which imports its modules to re-export them)."""
    graph = {}
    for module, targets in _graph().items():
        if module in UNLAYERED or MODULES[module].name == "__init__.py":
            continue
        graph[module] = {t for t in targets if t not in UNLAYERED and MODULES[t].name != "__init__.py"}
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_private_names_across_subpackages():
    """``from drivecal.x._m import _name`` between sub-packages is a trap: export the name, or keep it inside."""
    bad = []
    for module, path in MODULES.items():
        for target, name, line in _imports(module, path):
            if _owner(target) == _owner(module) or module in UNLAYERED:
                continue
            private_name = name is not None and name.startswith("_") and not name.startswith("__")
            private_module = any(p.startswith("_") and not p.startswith("__") for p in target.split(".")[2:])
            if private_name or private_module:
                bad.append(f"{path.relative_to(PACKAGE)}:{line} imports {target}{'.' + name if name else ''}")
    assert not bad, "\n".join(bad)


def test_tests_import_no_private_names_of_other_modules():
    """A test file may reach into the private module it is named for (test_lowered_cache.py: _lowered_cache), no other."""
    bad = []
    for path in sorted(TESTS.rglob("*.py")):
        subject = path.stem.removeprefix("test_")
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if not isinstance(node, ast.ImportFrom) or not (node.module or "").startswith("drivecal"):
                continue
            parts = node.module.split(".")
            for alias in node.names:
                names = parts[1:] + [alias.name]
                private = [p for p in names if p.startswith("_") and not p.startswith("__")]
                if any(p.lstrip("_") != subject for p in private):
                    bad.append(f"{path.relative_to(TESTS)}:{node.lineno} imports {node.module}.{alias.name}")
    assert not bad, "\n".join(bad)


def test_no_module_is_too_long():
    long = {m: len(p.read_text().splitlines()) for m, p in MODULES.items()}
    long = {m: n for m, n in long.items() if n > 520 and m not in LONG_MODULES}
    assert not long, f"modules over ~500 lines (split them, or give the reason in LONG_MODULES): {long}"


def test_import_drivecal_and_help_do_not_load_jax():
    """The package root and the CLI's help load no JAX (the help answers at once)."""
    code = ("import sys, drivecal, drivecal.cli\n"
            "from click.testing import CliRunner\n"
            "r = CliRunner().invoke(drivecal.cli.cli, ['--help'])\n"
            "assert r.exit_code == 0, r.output\n"
            "for c in sorted(drivecal.cli.cli.list_commands(None)):\n"
            "    r = CliRunner().invoke(drivecal.cli.cli, [c, '--help'])\n"
            "    assert r.exit_code == 0, (c, r.output)\n")
    loaded = _loaded_after(code, ("jax", "jaxonomy", "matplotlib", "pandas", "dask", "scipy"))
    assert loaded == "[]", f"--help imported {loaded}"


def _loaded_after(code: str, heavy: tuple[str, ...]) -> str:
    """Which of the ``heavy`` modules a fresh interpreter has loaded after running ``code`` (a sorted list's repr)."""
    code = f"import sys\n{code}print(sorted(m for m in {heavy!r} if m in sys.modules))\n"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


def test_sub_packages_load_heavy_libraries_only_where_used():
    """Importing the sub-packages (what a command does before its work) loads no optimistix or equinox (a solve being
    traced and plan optimisation load them), no pydantic (reading a plan, motor or format file), no pandas or pyarrow
    (reading and writing tables) and no scipy.special (the first interval or test): `drivecal report`, `gains`,
    `design` and `plan` then never load what their work does not need."""
    code = ("import drivecal.cli._design, drivecal.cli._gains, drivecal.cli._plan, drivecal.cli._report\n"
            "import drivecal.data, drivecal.design, drivecal.diagnose, drivecal.fitting, drivecal.identify\n"
            "import drivecal.report, drivecal.results, drivecal.selection\n")
    loaded = _loaded_after(code, ("optimistix", "lineax", "equinox", "pydantic", "pandas", "pyarrow", "scipy.special"))
    assert loaded == "[]", f"importing the sub-packages loaded {loaded}"


@pytest.mark.parametrize("old, name, new", [
    ("forward", "predict_currents", "drivecal.model"), ("fit", "Calibration", "drivecal.results"),
    ("motor", "MotorParams", "drivecal.physics"), ("record", "build_result", "drivecal.report"),
    ("verdict", "verdict", "drivecal.diagnose"), ("config", "load_plan", "drivecal.plan"),
    ("traced", "call", "drivecal.model._lowered_cache")])
def test_old_module_paths_keep_working_for_one_release(old, name, new):
    """``from drivecal.<old> import <name>`` warns once, naming the new place, and gives the object that lives there."""
    code = (f"import importlib, warnings\nwarnings.simplefilter('error', DeprecationWarning)\n"
            f"try:\n    from drivecal.{old} import {name}\nexcept DeprecationWarning as w:\n    print('warned', w)\n"
            f"warnings.simplefilter('ignore')\nfrom drivecal.{old} import {name}\n"
            f"assert {name} is getattr(importlib.import_module({new!r}), {name!r})\nprint('ok')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "warned" in proc.stdout and "ok" in proc.stdout
