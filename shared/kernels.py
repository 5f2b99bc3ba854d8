"""The kernels of :mod:`shared.grid_kernels`, :mod:`shared.trws_kernels` and
:mod:`shared.volume_kernels` as the rest of the code calls them: from their ahead-of-time
compiled module when one was built for this source (``qhsm build-kernels``,
:mod:`shared.kernel_build`), else just in time by numba.

Why: a process that jit-calls a kernel pays numba's import (0.3 s CPU) and, at its first call,
numba's target set-up with SciPy's import (0.4-0.5 s), even when the compiled code is cached;
``qhsm match`` on Tsukuba takes about 2.5 s in all (issue 28, item 3). A compiled module imports
in a millisecond.

A compiled function converts its arguments without checking their types (a wrong dtype reads
memory as another type), so each call is checked here against the signature it was compiled for
(:data:`SIGNATURES`); any other call (strided views, other dtypes) goes to numba, which compiles
what it needs. Both compile the same source with the same numba: the results are the same, as
long as no variable changes type between assignments (numba's JIT and pycc typed one such
variable differently: spell the types out, as ``_trws_pass``'s score does).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import platform
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, Final

import numpy as np

from shared import chains_native, median_native, native, volume_native

#: An argument: ``(dtype, ndim)`` for a C-contiguous, writeable array, else a scalar type name.
Argument = tuple[str, int] | str

#: Each exported kernel's signature: its result (pycc notation) and its arguments.
SIGNATURES: Final[dict[str, tuple[str, tuple[Argument, ...]]]] = {
    "_chains_windows": (
        "float64[::1]",
        (
            ("float32", 3), "float64", ("float32", 3), "float64", ("int32", 2),
            ("float64", 2), "float64", "float64", ("int32", 2), "boolean",
        ),
    ),
    "_chains_general": (
        "float64[::1]",
        (
            ("float32", 3), "float64", ("float32", 3), "float64", ("int32", 3),
            ("float64", 2), "float64", "float64", ("int32", 2), "boolean",
        ),
    ),
    "_grid_energy": (
        "float64[::1]",
        (
            ("float32", 3), ("int32", 3), ("int32", 2), "boolean", ("float64", 2),
            ("float64", 2), "float64", "float64", ("int32", 2),
        ),
    ),
    "_neighbour_costs": (
        "none",
        (
            ("int32", 3), ("int32", 2), "boolean", ("float64", 2), ("float64", 2), "float64",
            "float64", ("int32", 2), "boolean", ("float32", 3),
        ),
    ),
    "_disagreements": ("int64", (("int32", 2), ("int32", 2))),
    "_subgradient_step": (
        "none",
        (("float32", 3), ("float32", 3), ("int32", 2), ("int32", 2), "float32"),
    ),
    "_trws_pass": (
        "float64",
        (
            ("float32", 3), ("int32", 3), ("int32", 2), "boolean", ("float64", 2),
            ("float64", 2), "float64", "float64", ("float32", 3), ("float32", 3),
            ("float32", 3), ("float32", 3), "boolean", ("int32", 2),
        ),
    ),
    "gradient_exponents": (
        "none",
        (("float32", 2), ("float32", 2), ("float32", 2), ("float32", 2), "int64", "int64",
         ("float32", 3)),
    ),
    "census_aggregate": (
        "none",
        (
            ("uint32", 2), ("uint32", 2), ("float32", 3), ("float32", 1), "int64", "int64",
            "int64", ("float32", 3),
        ),
    ),
    "census_window": (
        "none",
        (
            ("uint32", 2), ("uint32", 2), ("float32", 3), ("float32", 1), "int64", "int64",
            "int64", ("int32", 2), ("float32", 3),
        ),
    ),
    "lowest_costs": (
        "none",
        (("float32", 3), ("int64", 2), "boolean", ("int64", 2), ("float32", 2)),
    ),
    "window_minima": (
        "none",
        (("float32", 3), "int64", ("int32", 2), "int64", ("float32", 3)),
    ),
    "least_costs": ("none", (("float32", 3), ("float32", 3), ("int32", 3))),
    "census_codes": ("none", (("float32", 2), ("uint32", 2))),
}  # fmt: skip

#: The modules that define the kernels, in the order :func:`dispatcher` looks them up.
MODULES: Final = ("shared.grid_kernels", "shared.trws_kernels", "shared.volume_kernels")
SOURCES: Final = tuple(Path(__file__).with_name(f"{m.rpartition('.')[2]}.py") for m in MODULES)
BUILD: Final = Path(__file__).with_name("kernel_build.py")
#: The x86-64 levels' features as Linux's /proc/cpuinfo names them (``pni``: SSE3; ``abm``:
#: LZCNT), each level's beyond the one before; the highest the CPU has all of is the target.
X86_64_LEVELS: Final = (
    ("x86-64-v2", frozenset(("cx16", "lahf_lm", "popcnt", "pni", "ssse3", "sse4_1", "sse4_2"))),
    (
        "x86-64-v3",
        frozenset(("avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave")),
    ),
    ("x86-64-v4", frozenset(("avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"))),
)


def pycc_signature(name: str) -> str:
    """The signature of kernel ``name`` in numba's notation, e.g. ``int64(int32[:, ::1], ...)``."""
    result, arguments = SIGNATURES[name]
    written = [f"{a[0]}[{':, ' * (a[1] - 1)}::1]" if isinstance(a, tuple) else a for a in arguments]
    return f"{result}({', '.join(written)})"


def target_cpu(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """LLVM's CPU for the compiled module: the highest x86-64 level (:data:`X86_64_LEVELS`)
    this x86-64 Linux machine has every feature of, else ``""``, the generic target. v2's
    POPCNT counts the census bits in one instruction (Art x3 1.07x faster than generic); v4's
    AVX-512 vectorises the volume kernels wider (Aloe 1.04x, Art x3 1.03x of v2's CPU; the
    chain kernels are scalar either way). The floats are the same at every level: numba asks
    LLVM for no fused multiply-adds. Part of the module's name: a machine without a level's
    features never loads a module built for it (a shared home folder)."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return ""
    try:
        with cpuinfo.open(encoding="ascii", errors="replace") as lines:
            found = (line.partition(":")[2] for line in lines if line.startswith("flags"))
            flags = set(next(found, "").split())
    except OSError:
        return ""
    target, needed = "", set[str]()
    for level, features in X86_64_LEVELS:
        needed |= features
        if not flags >= needed:
            break
        target = level
    return target


def module_name() -> str:
    """The compiled module's name: a digest of what its code depends on (the kernels' source,
    the build and its target CPU, the signatures, numba's version, Python's), so that a stale
    module, or one built for a CPU this one is not, is never loaded."""
    digest = hashlib.sha256(b"".join(source.read_bytes() for source in SOURCES))
    digest.update(BUILD.read_bytes())  # how it was compiled
    digest.update(b"".join(library.source.read_bytes() for library in native.LIBRARIES.values()))
    digest.update(Path(native.__file__).read_bytes())  # the C kernels' flags
    digest.update(target_cpu().encode())
    digest.update(repr(SIGNATURES).encode())
    digest.update(sys.version.encode())
    spec = importlib.util.find_spec("numba")
    if spec is not None and spec.origin is not None:  # its version file, not an import
        version = Path(spec.origin).with_name("_version.py")
        digest.update(version.read_bytes() if version.exists() else b"")
    return f"_qhsm_kernels_{digest.hexdigest()[:16]}"


def cache_directory() -> Path:
    """Where compiled modules are kept: the user's cache folder (``~/.cache/qhsm/kernels``)."""
    import platformdirs

    return platformdirs.user_cache_path("qhsm", appauthor=False) / "kernels"


def load_compiled(directory: Path | None = None) -> ModuleType | None:
    """The compiled module built for this source, or None when there is none (or it does not
    load).

    Parameters
    ----------
    directory : pathlib.Path, optional
        Where to look (default: :func:`cache_directory`).
    """
    name = module_name()
    found = sorted((directory or cache_directory()).glob(f"{name}.*"))
    if not found:
        return None
    spec = importlib.util.spec_from_file_location(name, found[0])
    if spec is None or spec.loader is None:
        return None
    try:
        module = importlib.util.module_from_spec(spec)  # an extension is loaded here
        spec.loader.exec_module(module)
    except (ImportError, OSError):  # built for another machine, or damaged: numba compiles
        return None
    return module


def native_library_path(name: str, directory: Path | None = None) -> Path:
    """Where C library ``name`` (:data:`shared.native.LIBRARIES`) built for this source is:
    beside the compiled module, named after it (not matched by its ``name.*`` pattern)."""
    return (directory or cache_directory()) / f"{module_name()}_{name}.so"


def _fits(value: Any, argument: tuple[np.dtype, int] | str) -> bool:
    """Whether ``value`` is what the compiled code reads for ``argument`` (an array's dtype
    object, not its name: ``dtype.name`` is computed in Python at every call)."""
    if isinstance(argument, tuple):
        return (
            type(value) is np.ndarray
            and value.dtype == argument[0]
            and value.ndim == argument[1]
            and value.flags.c_contiguous
            and value.flags.writeable
            and value.flags.aligned
        )
    if argument == "float64":
        return isinstance(value, float)  # numba types np.float64 as float64 too
    if argument == "float32":
        return isinstance(value, np.float32)
    if argument == "int64":  # pycc's wrapper takes any Python or NumPy integer
        return isinstance(value, int | np.integer) and not isinstance(value, bool)
    return type(value) is bool or isinstance(value, np.bool_)


def dispatcher(name: str) -> Callable[..., Any]:
    """Numba's dispatcher of kernel ``name``, from the first of :data:`MODULES` defining it."""
    for module in MODULES:
        found = getattr(importlib.import_module(module), name, None)
        if found is not None:
            return found
    raise AttributeError(f"no kernel {name} in {', '.join(MODULES)}")


class Kernel:
    """One kernel: compiled when the call fits its signature, else numba's dispatcher; a
    ``native`` implementation (C, the same results) first when there is one and the call fits
    (it returns NotImplemented for a call it leaves to the others)."""

    def __init__(
        self,
        name: str,
        compiled: ModuleType | None,
        native: Callable[..., Any] | None = None,
    ) -> None:
        self.name = name
        self.native = native
        self.arguments = [
            (np.dtype(a[0]), a[1]) if isinstance(a, tuple) else a for a in SIGNATURES[name][1]
        ]
        self.compiled: Callable[..., Any] | None = getattr(compiled, name, None)
        self._jit: Callable[..., Any] | None = None

    def jit(self) -> Callable[..., Any]:
        """Numba's dispatcher of the kernel (imports numba on first use)."""
        if self._jit is None:
            preloading = _preloading
            if preloading is not None and preloading is not threading.current_thread():
                preloading.join()  # numba's set-up there, without SciPy (shared.numba_start)
            self._jit = dispatcher(self.name)
        return self._jit

    def __call__(self, *args: Any) -> Any:
        fits = (
            (self.native is not None or self.compiled is not None)
            and len(args) == len(self.arguments)
            and all(_fits(a, kind) for a, kind in zip(args, self.arguments, strict=True))
        )
        if fits and self.native is not None:
            result = self.native(*args)
            if result is not NotImplemented:
                return result
        if fits and self.compiled is not None:
            return self.compiled(*args)
        return self.jit()(*args)


_COMPILED = load_compiled()
_NATIVE = {name: native.load(native_library_path(name), name) for name in native.LIBRARIES}
_NATIVE_CHAINS = (
    chains_native.NativeChains(_NATIVE["chains"]) if _NATIVE["chains"] is not None else None
)
_NATIVE_NEIGHBOURS = (
    chains_native.NativeNeighbourCosts(_NATIVE["chains"]) if _NATIVE["chains"] is not None else None
)
#: OpenCV's weighted median in C on every core (:mod:`shared.median_native`), when built.
native_median = (
    median_native.NativeMedian(_NATIVE["median"]) if _NATIVE["median"] is not None else None
)
_NATIVE_LEAST = (
    volume_native.NativeLeastCosts(_NATIVE["volume"]) if _NATIVE["volume"] is not None else None
)


def compiled_module() -> ModuleType | None:
    """The compiled module this process loaded, if any (:mod:`shared.kernel_background`)."""
    return _COMPILED


chains_windows = Kernel("_chains_windows", _COMPILED, _NATIVE_CHAINS)
chains_general = Kernel("_chains_general", _COMPILED)
grid_energy = Kernel("_grid_energy", _COMPILED)
neighbour_costs = Kernel("_neighbour_costs", _COMPILED, _NATIVE_NEIGHBOURS)
disagreements = Kernel("_disagreements", _COMPILED)
subgradient_step = Kernel("_subgradient_step", _COMPILED)
trws_pass = Kernel("_trws_pass", _COMPILED)
gradient_exponents = Kernel("gradient_exponents", _COMPILED)
census_aggregate = Kernel("census_aggregate", _COMPILED)
census_window = Kernel("census_window", _COMPILED)
lowest_costs = Kernel("lowest_costs", _COMPILED)
window_minima = Kernel("window_minima", _COMPILED)
least_costs = Kernel("least_costs", _COMPILED, _NATIVE_LEAST)
census_codes = Kernel("census_codes", _COMPILED)


_preloading: threading.Thread | None = None


def preload() -> None:
    """Load numba and the kernels' cache in a background thread, once per process, when some
    kernel has no compiled module: numba's import and target set-up (~0.4 s CPU without
    SciPy, mostly Python holding the GIL) then overlap the work before the first level's
    solve (reading the views, their check, the cost volumes: OpenCV and NumPy release the
    GIL), instead of following it. A kernel called meanwhile waits for the preload (a jit
    kernel joins it: :meth:`Kernel.jit`); a failure here is left to that call to raise."""
    global _preloading
    if _preloading is not None or all(kernel.compiled is not None for kernel in _ALL):
        return
    _preloading = threading.Thread(target=_load_jit, name="qhsm-kernel-preload", daemon=True)
    _preloading.start()


def ready(*chosen: Kernel) -> bool:
    """Whether the ``chosen`` kernels run now, without waiting for numba's import: compiled
    ahead of time, or numba loaded (:func:`jit_ready`)."""
    return all(kernel.compiled is not None for kernel in chosen) or jit_ready()


def jit_ready() -> bool:
    """Whether numba is loaded in this process (the preload done, or imported otherwise): a
    caller with a NumPy path as good (:func:`ready`) takes numba's only then, rather than wait
    for its import."""
    if _preloading is not None and _preloading.is_alive():
        return False
    return "numba" in sys.modules


def _load_jit() -> None:
    """numba's set-up and one kernel's cached code (every later kernel then loads in ms)."""
    from shared.numba_start import without_scipy

    try:
        with without_scipy():  # 0.2 s of CPU for BLAS decisions no kernel needs
            one = np.zeros((1, 1), dtype=np.int32)
            disagreements.jit()(one, one)
    except Exception:  # the first real call raises it where it matters
        return


_ALL = (
    chains_windows, chains_general, grid_energy, neighbour_costs, disagreements,
    subgradient_step, trws_pass, gradient_exponents, census_aggregate, census_window,
    lowest_costs, window_minima, least_costs, census_codes,
)  # fmt: skip
