"""Traced computations kept on disk, so that a new process need not trace them again.

JAX's persistent compilation cache (see ``drivecal/__init__.py``) keeps the compiled kernels, but its key is the
lowered program: every new process still traces and lowers each jitted function before it can look the kernel up,
and for the fit's solve that is seconds of Python. :func:`call` keeps the lowered program itself (``jax.export``:
StableHLO and its signature) next to the kernels, keyed by everything the trace depends on: drivecal's source code,
the versions of the libraries traced through, the structure, shapes and dtypes of the arguments, the static
arguments and the JAX settings that change a trace. A later process loads it and runs it; its kernel is then an
ordinary compilation-cache hit. Where this process compiled the kernel itself, the compiled executable is kept
beside the program, and a later process runs it straight away: no lowering, no cache lookup (a warm ``drivecal fit``
spent about a sixth of its CPU time lowering the loaded programs). Where the compilation cache supplied the kernel
(the same program traced by an earlier version of drivecal), the bytes the cache holds are kept: jaxlib 0.9
serialises an executable loaded from the cache without its code, and it fails when run.

Other computed results that are pure functions of their inputs (the engine's benches) are kept in folders of their
own beside the programs, under keys of the same kind (:func:`result_key`, :func:`keep_result`, :func:`kept_result`).

The same program runs whether it was just traced or loaded, so the numbers do not depend on the state of the cache
(and they are those of the plain ``jax.jit`` call). Off with ``DRIVECAL_JAX_CACHE=0`` (the plain call then runs);
any failure to export, save or load falls back to the plain call. Calls with tracers (inside ``jit``, ``vmap`` or
``grad``) always take the plain call. A command's programs are loaded ahead of need as the last process that
started with the same program loaded them (``_preload``).
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import pickle
import tempfile
import threading
import zlib
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

import jax
import numpy as np

from ._ahead import _OUTPUTS_UNUSED, _traced, _turn
from ._preload import noted

logger = logging.getLogger(__name__)

#: Bump when the on-disk entry changes meaning.
_FORMAT = 7
#: Entries kept; beyond this the least recently used go (a program is ~10-50 kB compressed).
_MAX_ENTRIES = 256
#: Libraries whose code is traced into drivecal's computations.
_TRACED_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "numpy")
#: Marks a computation that cannot be exported: later processes go straight to the plain call.
_UNKEPT = b"not kept"

#: XLA:CPU's legacy fusion emitters, as a compile option (``call``'s ``compiler_options``): for kernels that run
#: once or a few times per command, where compiling them is the cost (they compile with about half the CPU
#: time), and for a batch's solve (fewer object files: kept on disk). Not for every kernel: the Jaxonomy
#: engine's simulations ran several times slower with them.
LEGACY_EMITTERS = {"xla_cpu_use_fusion_emitters": False}

#: XLA:CPU's backend (LLVM) at optimisation level 0, with its legacy fusion emitters: for a program that runs
#: once or a few times in a command and for milliseconds at most (a single fit's solve, the sensitivity
#: Jacobian and the predicted currents without the dead time's rollout, the score tests' Jacobians).
#: Level 0 compiled in about half the time (examples/bench.csv's Jacobian 1.16 -> 0.56 s, then run in 3.2 ms
#: against 0.4 ms; its fit --json moved 1e-11 relative at most, no printed digit). The legacy emitters at
#: level 0 halve it again and run faster: the demo's identifiability Jacobian (1 400 samples) 0.85 -> 0.40 s
#: to compile, 12 -> 2 ms to run; examples/bench.csv's 0.53 -> 0.25 s, 2.1 -> 0.8 ms; the predicted
#: currents' 0.17 -> 0.10 s. With the dead time's rollout: :func:`run_once_options`.
RUN_ONCE = {"xla_backend_optimization_level": 0, **LEGACY_EMITTERS}
#: :func:`run_once_options` with the dead time's rollout: LLVM's level 1, the legacy emitters.
DEAD_TIME_RUN_ONCE = {"xla_backend_optimization_level": 1, **LEGACY_EMITTERS}


def run_once_options(dead_time: bool) -> dict[str, Any]:
    """:data:`RUN_ONCE`, or with the dead time's rollout (``Experiment.dead_time``: tens of ms a run, at every LM
    step) :data:`DEAD_TIME_RUN_ONCE`: legacy emitters (half the compile), level 1 (level 0 made the inverter
    bench's warm fit 0.5 s longer; level 2 compiled slower, ran as fast: docs/performance.md, stop 59)."""
    return DEAD_TIME_RUN_ONCE if dead_time else RUN_ONCE


#: The plain calls jitted with compile options (:func:`_plain`).
_PLAIN: dict[tuple, Callable] = {}

# key -> (jitted call of the loaded program, output tree), or None: use the plain call.
_LOADED: dict[str, tuple[Callable, Any] | None] = {}
#: One lock per key: threads that ask for the same program at once (a first fit's score-test kernels compiled
#: ahead beside its own) wait for the one loading or exporting it rather than doing the same work again.
_KEY_LOCKS: dict[str, threading.Lock] = {}
_KEY_LOCKS_GUARD = threading.Lock()
def directory() -> Path | None:
    """Where lowered programs are kept (inside the compilation cache), or None when caching is off."""
    from .._setup import cache_enabled as _cache_enabled

    if not _cache_enabled():
        return None
    base = jax.config.jax_compilation_cache_dir
    return Path(base) / "drivecal-traced" if base else None


#: Held while the fingerprint is read: by one thread, the others waiting.
_FINGERPRINT_LOCK = threading.Lock()


def _fingerprint() -> str:
    """What every trace depends on: drivecal's source (every module of every sub-package) and the traced libraries' versions.

    Read once, by one thread: a fit and its score tests compiled ahead key their first programs at once, and two
    threads reading the ~130 files together trade the GIL at every read (~0.1 s of a warm fit, against ~6 ms).
    """
    with _FINGERPRINT_LOCK:
        return _read_fingerprint()


@functools.lru_cache(maxsize=1)
def _read_fingerprint() -> str:
    h = hashlib.sha256(f"drivecal traced v{_FORMAT}\n{_versions(_TRACED_LIBRARIES)}".encode())
    root = package_root()
    for path in source_files():
        h.update(path.relative_to(root).as_posix().encode() + b"\n" + path.read_bytes() + b"\n")
    return h.hexdigest()


def _versions(dists: tuple[str, ...]) -> str:
    """``"name==version\\n"`` per distribution (``-`` for one not installed)."""
    out = ""
    for dist in dists:
        try:
            version = metadata.version(dist)
        except metadata.PackageNotFoundError:
            version = "-"
        out += f"{dist}=={version}\n"
    return out


def package_root() -> Path:
    """The drivecal package's folder (this module lives in its ``model`` sub-package)."""
    return Path(__file__).resolve().parents[1]


def source_files() -> list[Path]:
    """Every Python source file of the package, in every sub-package, sorted: what the key's fingerprint reads."""
    return sorted(package_root().rglob("*.py"))


def _settings() -> str:
    c = jax.config
    device = jax.devices()[0]
    return repr((device.platform, device.device_kind, device.client.platform_version, c.jax_enable_x64,
                 c.jax_default_matmul_precision, c.jax_debug_nans, c.jax_debug_infs, c.jax_numpy_rank_promotion,
                 c.jax_numpy_dtype_promotion))


#: (name, tree, static arguments, leaf shapes and dtypes) -> key: hashing the key anew costs ~1 ms a call.
_KEYS: dict[tuple, str] = {}


def _key(name: str, leaves: list, treedef: Any, static: dict[str, Any]) -> str:
    try:
        quick = (name, treedef, tuple(sorted(static.items())),
                 tuple((np.shape(x), getattr(x, "dtype", type(x)), getattr(x, "weak_type", False)) for x in leaves))
        hash(quick)
    except TypeError:  # an unhashable static argument: no memo
        return _full_key(name, leaves, treedef, static)
    if quick not in _KEYS:
        _KEYS[quick] = _full_key(name, leaves, treedef, static)
    return _KEYS[quick]


def _full_key(name: str, leaves: list, treedef: Any, static: dict[str, Any]) -> str:
    h = hashlib.sha256(_fingerprint().encode())
    h.update(_settings().encode())
    h.update(f"\n{name}\n{treedef}\n{sorted(static.items())!r}\n".encode())
    for leaf in leaves:
        h.update(f"{jax.typeof(leaf)};".encode())
    return h.hexdigest()


def _prune(folder: Path, keep: int | None = None) -> None:
    """Drop the least recently used entries beyond ``keep`` (default ``_MAX_ENTRIES``)."""
    keep = _MAX_ENTRIES if keep is None else keep
    entries = []
    for p in folder.glob("*.pkl"):
        try:
            entries.append((p.stat().st_mtime, p))
        except OSError:
            pass
    for _, p in sorted(entries)[: max(len(entries) - keep, 0)]:
        p.unlink(missing_ok=True)


def result_key(kind: str, material: bytes, libraries: tuple[str, ...] = ()) -> str:
    """The key of a computed result kept on disk (:func:`kept_result`): what it depends on, hashed.

    ``material``: the computation's inputs, serialised (equal bytes for equal inputs). The key adds what every
    trace depends on (drivecal's source, the traced libraries' versions, the JAX settings, ``XLA_FLAGS``) and
    the versions of ``libraries`` (those the computation runs besides, e.g. ``("jaxonomy",)``)."""
    h = hashlib.sha256(f"{_fingerprint()}\n{_settings()}\n{os.environ.get('XLA_FLAGS', '')}\n{kind}\n"
                       f"{_versions(libraries)}".encode())
    h.update(material)
    return h.hexdigest()


def kept_result(kind: str, key: str) -> bytes | None:
    """The bytes :func:`keep_result` kept under ``key`` (marked recently used), or None: absent, unreadable, or
    caching off. They live in the compilation cache's folder (one per host kind) beside the traced programs."""
    folder = directory()
    if folder is None:
        return None
    path = folder.parent / f"drivecal-{kind}" / f"{key}.pkl"
    try:
        data = path.read_bytes()
        os.utime(path)  # recently used: kept by _prune
    except OSError:
        return None
    return data


def keep_result(kind: str, key: str, data: bytes, entries: int = 64) -> None:
    """Keep ``data`` under ``key`` for :func:`kept_result` (written whole or not at all; the least recently used
    beyond ``entries`` of this ``kind`` go). Does nothing where caching is off; a failure to write is logged."""
    folder = directory()
    if folder is None:
        return
    path = folder.parent / f"drivecal-{kind}" / f"{key}.pkl"
    try:
        _write(path, data)
        _prune(path.parent, entries)
    except OSError as exc:
        logger.debug("drivecal: cannot keep %s (%s)", path, exc)


def _write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)  # atomic: a concurrent reader sees all of it or nothing
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@functools.lru_cache(maxsize=1)
def _initialize_lapack() -> None:
    """Load JAX's CPU LAPACK kernels, as lowering a linear-algebra op would.

    A program lowered in another process calls them with none of their lowering rules run here: uninitialised, they
    crash it (jax-ml/jax#29610). From SciPy's BLAS and LAPACK, without ``scipy.linalg``'s ``__init__`` (``_apart``).
    """
    try:
        from jax._src.lib import lapack

        from .._apart import import_apart
        with import_apart("scipy.linalg", ("cython_blas", "cython_lapack")):
            lapack.prepare_lapack_call("getrf_ffi", np.dtype(np.float64))
    except Exception:
        import jax.numpy as jnp

        jax.jit(jnp.linalg.inv).lower(jax.ShapeDtypeStruct((2, 2), jnp.float64))


def _runner(exported: Any, options: dict | None = None, lapack: bool = True) -> Callable:
    """The exported program as a jitted call, compiled with XLA ``options`` (``call``'s ``compiler_options``).

    ``lapack``: whether the program may call LAPACK (:func:`_initialize_lapack` first)."""
    if lapack:
        _initialize_lapack()
    return jax.jit(lambda *leaves: exported.call(*leaves), compiler_options=options or None)


def _compiled(exported: Any, leaves: list, options: dict | None) -> tuple[Callable, Any]:
    """The program compiled for ``leaves``, and its serialised executable (None where it cannot be kept).

    Kept only where it has at most ``_setup.MAX_CACHED_OBJECTS`` object files (as the compilation cache:
    more crash the process that loads them). Where the compilation cache supplied the kernel, its bytes
    are those the cache read (:data:`_setup.KERNELS`), not jaxlib's serialisation of the loaded kernel.
    Where this process compiled it, they are those serialised for the compilation cache's check, which
    then writes no copy of its own (a cold ``drivecal demo --out``: 1.2 -> 0.5 s of its threads' time).
    """
    from .._setup import KERNELS, MAX_CACHED_OBJECTS

    KERNELS.latest, KERNELS.keeping = None, True
    try:
        compiled = _runner(exported, options).lower(*leaves).compile()
    finally:
        KERNELS.keeping = False
    hit, KERNELS.latest = KERNELS.latest, None
    try:
        payload, in_tree, out_tree = _serialize(compiled, hit)
    except Exception as exc:
        logger.debug("drivecal: executable not serialisable (%s)", exc)
        return compiled, None
    return compiled, ((payload, in_tree, out_tree) if 0 < payload.count(b"\x7fELF") <= MAX_CACHED_OBJECTS else None)


def _serialize(compiled: Any, hit: tuple | None) -> tuple[bytes, Any, Any]:
    """``jax.experimental.serialize_executable.serialize(compiled)``, with the kernel ``hit[0]`` written as the
    bytes ``hit[1]``; an executable loaded from the compilation cache that is not ``hit[0]`` raises."""
    import io

    from jax.experimental import serialize_executable
    from jax._src.lib import xla_client

    class Pickler(serialize_executable._JaxPjrtPickler):
        def persistent_id(self, obj):
            if hit is not None and obj is hit[0]:
                return ("exec", hit[1])
            if isinstance(obj, xla_client.LoadedExecutable) and hit is not None:
                raise ValueError("a kernel of the compilation cache other than the one read")
            return super().persistent_id(obj)

    unloaded = getattr(compiled._executable, "_unloaded_executable", None)
    if unloaded is None or compiled._params.const_args or getattr(getattr(unloaded, "mut", None), "in_mut", None):
        raise ValueError("compilation does not support serialisation")
    args_info, in_tree = jax.tree_util.tree_flatten(compiled.args_info)
    with io.BytesIO() as file:
        Pickler(file).dump((unloaded, args_info, compiled._no_kwargs))
        return file.getvalue(), in_tree, compiled.out_tree


def _executable(kept: tuple, lapack: bool = True) -> Callable:
    """A kept executable, loaded: called with the leaves of the arguments it was compiled for (``lapack``: it may
    call LAPACK, :func:`_initialize_lapack` first)."""
    from jax.experimental import serialize_executable

    if lapack:
        _initialize_lapack()
    return serialize_executable.deserialize_and_load(*kept)


def _load(path: Path) -> tuple[Callable, Any] | None | bool:
    """The entry at ``path``: (runner, out_tree), None (not kept), or False (absent or unreadable)."""
    try:
        data = path.read_bytes()
    except OSError:
        return False
    if data == _UNKEPT:
        return None
    try:
        data = zlib.decompress(data)
        # A program that calls LAPACK names its kernels (``lapack_dgetrf_ffi``, ...); one that names none loads
        # without initialising them: importing SciPy's BLAS for them took ~0.1 s of a warm fit, none of whose
        # programs calls LAPACK.
        lapack = b"lapack" in data
        exported, out_tree, kept, options = pickle.loads(data)
        run = None
        if kept is not None:
            try:
                run = _executable(kept, lapack)
            except Exception as exc:  # the program is still good: lower it, as without an executable
                logger.debug("drivecal: kept executable of %s not loadable (%s)", path, exc)
        entry = (run if run is not None else _runner(exported, options, lapack)), out_tree
    except Exception as exc:  # a stale or damaged entry: trace again and overwrite it
        logger.debug("drivecal: ignoring cache entry %s (%s)", path, exc)
        return False
    try:
        os.utime(path)  # recently used: kept by _prune
    except OSError:
        pass
    return entry


def _export(fn: Callable, name: str, leaves: list, treedef: Any, static: dict[str, Any],
            path: Path, options: dict | None = None) -> tuple[Callable, Any] | None:
    """Trace and lower ``fn`` for these arguments and keep the program at ``path``; None: use the plain call."""
    import dataclasses

    from jax import export

    out_tree = []
    # The function the jit wraps, traced once inside the export's own jit (JAX refuses a nested jit with
    # compiler options; the options go to _runner's jit).
    body = getattr(fn, "__wrapped__", fn)

    def flat(*flat_args):
        out = body(*jax.tree_util.tree_unflatten(treedef, flat_args), **static)
        out_leaves, tree = jax.tree_util.tree_flatten(out)
        out_tree.append(tree)
        return out_leaves

    try:
        _initialize_lapack()  # here, without scipy.linalg's __init__, not by a linear-algebra op's lowering rule
        exported = export.export(jax.jit(flat))(*leaves)
        _traced()
        # The VJP hook is a closure (not needed: these calls are never differentiated).
        exported = dataclasses.replace(exported, _get_vjp=None)
        # Only an output structure that comes back intact from pickling is kept (tuples,
        # lists, dicts, None, drivecal's module-level dataclasses): anything else is not.
        if pickle.loads(pickle.dumps(out_tree[0])) != out_tree[0]:
            raise TypeError(f"the output structure {out_tree[0]} does not survive pickling")
        run, kept = _compiled(exported, leaves, options)
        data = zlib.compress(pickle.dumps((exported, out_tree[0], kept, options)), 1)
    except Exception as exc:
        logger.debug("drivecal: %s cannot be exported (%s); tracing it every run", name, exc)
        try:
            _write(path, _UNKEPT)
        except OSError:
            pass
        return None  # the plain call, as in every later process
    try:
        _write(path, data)
        _prune(path.parent)
    except OSError as exc:
        logger.debug("drivecal: could not save %s (%s)", path, exc)
    return run, out_tree[0]


def _strongly_typed(leaf: Any) -> Any:
    """``leaf`` with a strong dtype: a Python float becomes a float64 scalar, a weakly typed JAX array a plain one.

    ``jit`` compiles a program anew for each weak/strong pattern of its arguments, and a motor's fields are
    Python floats where a file or ``replace`` set them, float64 arrays where a fit did: without this, a model
    selection compiled its sensitivity Jacobian (~9 s) twice for every candidate model. Same dtype, same numbers.
    """
    if isinstance(leaf, float):
        return np.float64(leaf)
    if getattr(leaf, "weak_type", False) and isinstance(leaf, jax.Array):
        return jax.lax.convert_element_type(leaf, leaf.dtype)
    return leaf


def _load_kept(key: str, path: Path) -> threading.Lock:
    """Put ``key``'s entry kept at ``path`` in ``_LOADED`` unless it is there (none kept: nothing); the key's lock."""
    with _KEY_LOCKS_GUARD:
        lock = _KEY_LOCKS.setdefault(key, threading.Lock())
    with lock:
        if key not in _LOADED:
            entry = _load(path)
            if entry is not False:
                _LOADED[key] = entry
    return lock


def _load_or_export(key: str, path: Path, export: Callable[[Path], Any]) -> None:
    """Put ``key``'s entry in ``_LOADED``: kept at ``path``, else ``export(path)``, once across threads.

    A thread waits for its turn to trace (``model._ahead``) before it takes the key's lock, not while
    holding it: a thread that needs the program now never waits behind the queue of work ahead of need
    for it. Nor does it keep its turn while another thread exports the same program (a first fit's own
    sensitivity kernel, which its score tests use too): it waits for that program without it.
    """
    lock = _load_kept(key, path)
    while key not in _LOADED:
        with _turn():
            if lock.acquire(blocking=False):
                try:
                    if key not in _LOADED:
                        _LOADED[key] = export(path)
                finally:
                    lock.release()
                return
        with lock:  # exported by another thread now: wait for it, then look again
            pass


def _plain(fn: Callable, options: dict | None, static: dict[str, Any]) -> Callable:
    """``fn`` as the plain call: jitted with the XLA ``options`` where there are some (one jit per function,
    options and static names), so that the numbers are those of the kept program with or without the cache."""
    if not options:
        return fn
    key = (fn, tuple(sorted(options.items())), tuple(sorted(static)))
    if key not in _PLAIN:
        _PLAIN[key] = jax.jit(getattr(fn, "__wrapped__", fn), static_argnames=tuple(sorted(static)),
                              compiler_options=options)
    return _PLAIN[key]


def call(fn: Callable, name: str, *args: Any, compiler_options: dict | None = None, **static: Any) -> Any:
    """``fn(*args, **static)``, traced once per machine rather than once per process.

    Args:
        fn: a function of arrays (pytrees of them) ``args``, traceable by ``jax.jit``,
            that returns arrays in tuples, lists or dicts (not in custom pytree nodes).
        name: names ``fn`` in the cache key (unique per function).
        args: the traced arguments.
        compiler_options: XLA options ``fn`` is compiled with (``jax.jit(..., compiler_options=...)``): the
            exported program does not carry them, so the kept one is compiled with them again, and the
            plain call (caching off) jits the function ``fn`` wraps with them.
        static: arguments fixed at trace time; their ``repr`` is part of the key.

    Where ``fn`` is a jitted function, the function it wraps (``fn.__wrapped__``) is what is traced and kept:
    one jit, not one inside another (a cold ``drivecal fit examples/bench.csv`` took ~1 s less).
    """
    if jax.config.jax_disable_jit:
        return fn(*args, **static)
    leaves, treedef = jax.tree_util.tree_flatten(args)
    if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        return fn(*args, **static)
    leaves = [_strongly_typed(leaf) for leaf in leaves]
    args = jax.tree_util.tree_unflatten(treedef, leaves)
    folder = directory()
    if folder is None:
        return _plain(fn, compiler_options, static)(*args, **static)
    try:
        key = _key(name, leaves, treedef,
                   {**static, " compiler_options": tuple(sorted(compiler_options.items()))} if compiler_options
                   else static)
    except Exception as exc:  # e.g. a leaf JAX cannot type: not a traced call at all
        logger.debug("drivecal: no cache key for %s (%s)", name, exc)
        return _plain(fn, compiler_options, static)(*args, **static)
    path = folder / f"{name}-{key[:32]}.pkl"
    noted(key, path, _load_kept)  # loaded ahead or not: the next process that starts as this one loads it ahead
    if key not in _LOADED:
        _load_or_export(key, path, lambda path: _export(fn, name, leaves, treedef, static, path, compiler_options))
    entry = _LOADED[key]
    if entry is None:
        return _plain(fn, compiler_options, static)(*args, **static)
    run, out_tree = entry
    if _OUTPUTS_UNUSED.get() and isinstance(run, jax.stages.Compiled):
        return jax.tree_util.tree_unflatten(out_tree, [np.zeros(a.shape, a.dtype) for a in
                                                       jax.tree_util.tree_leaves(run.out_info)])
    try:
        out = run(*leaves)
    except Exception as exc:  # the kept program does not fit after all: never use it again here
        logger.debug("drivecal: cached %s failed (%s); tracing it", name, exc)
        _LOADED[key] = None
        return _plain(fn, compiler_options, static)(*args, **static)
    return jax.tree_util.tree_unflatten(out_tree, out)
