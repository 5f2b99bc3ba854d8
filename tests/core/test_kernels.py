"""The ahead-of-time compiled kernels (issue 28, item 3): the same results as numba's, used only
for calls that fit their signature, and a module of another source never loaded."""

from __future__ import annotations

import numpy as np
import pytest

import shared.grid_kernels
import shared.volume_kernels
from shared import kernel_build, kernels, native
from shared.chains_native import NativeChains
from shared.kernel_build import build

VOLUME_KERNELS = (
    "gradient_exponents", "census_aggregate", "census_window", "window_minima", "least_costs",
)  # fmt: skip


@pytest.fixture(scope="module")
def directory(tmp_path_factory):
    built = tmp_path_factory.mktemp("kernels")
    build(built, names=("_disagreements", "_grid_energy", "_chains_windows", *VOLUME_KERNELS))
    return built


@pytest.fixture(scope="module")
def compiled(directory):
    return kernels.load_compiled(directory)


def _energy_arguments(seed: int, windows: bool) -> tuple:
    rng = np.random.default_rng(seed)
    height, width, count = 5, 7, 4
    first = rng.integers(0, 9, (height, width), dtype=np.int32)
    candidates = (
        first[:, :, None] + np.arange(count, dtype=np.int32)
        if windows
        else rng.integers(0, 9, (height, width, count), dtype=np.int32)
    )
    return (
        rng.random((height, width, count), dtype=np.float32),
        candidates,
        first if windows else np.zeros((1, 1), dtype=np.int32),
        windows,
        rng.random((height, width - 1)),
        rng.random((height - 1, width)),
        0.7,
        2.5,
        rng.integers(0, count, (height, width), dtype=np.int32),
    )


def test_the_compiled_kernel_gives_numbas_floats(compiled):
    kernel = kernels.Kernel("_grid_energy", compiled)
    assert kernel.compiled is not None
    for seed, windows in zip(range(4), (False, True) * 2, strict=True):
        arguments = _energy_arguments(seed, windows)
        assert np.array_equal(
            kernel.compiled(*arguments), shared.grid_kernels._grid_energy(*arguments)
        )


def _volume_arguments(seed: int) -> dict[str, tuple]:
    """Each volume kernel's arguments: random codes, gradients, exponent terms and windows."""
    rng = np.random.default_rng(seed)
    rows, width, top = 9, 13, 11
    codes = rng.integers(0, 2**24, (rows, width), dtype=np.uint32)
    shifted = rng.integers(0, 2**24, (rows, width + top), dtype=np.uint32)
    gradients = [  # x and y of the left view, then of the (shifted) right view
        rng.normal(0, 30, (rows - 4, columns)).astype(np.float32)
        for columns in (width, width, width + top, width + top)
    ]
    terms = rng.random((4, rows, width), dtype=np.float32)
    table = (0.5 + rng.random(256) / 2).astype(np.float32)
    first, width_of_bins = int(rng.integers(0, top - 3)), int(rng.integers(1, 4))
    volume = rng.random((top // width_of_bins + 1, rows - 4, width), dtype=np.float32)
    lowest = rng.integers(0, 3, (rows - 4, width), dtype=np.int32)
    window = rng.random((rows - 4, width, 3), dtype=np.float32)
    planes = rng.random((12, rows - 4, width), dtype=np.float32)
    return {
        "gradient_exponents": (*gradients, top, first, np.zeros((4, rows - 4, width), np.float32)),
        "census_aggregate": (codes, shifted, terms, table, top, first, width_of_bins, volume),
        "census_window": (
            codes, shifted, terms, table, top, first, width_of_bins, lowest, window,
        ),
        # 3 of 6 bins (2 planes each) per window, from the volume's row 2 on
        "window_minima": (planes, 2, lowest[:-2].copy(), 2, window[:-2].copy()),
        # ties among 4 cost levels; the last argument: the least four's disparities
        "least_costs": (
            np.rint(planes * 3), np.full((4, rows - 4, width), np.inf, np.float32),
            np.zeros((4, rows - 4, width), np.int32),
        ),
    }  # fmt: skip


@pytest.mark.parametrize("name", VOLUME_KERNELS)
def test_the_compiled_volume_kernels_write_numbas_floats(compiled, name):
    """The census + gradient kernels (an LLVM intrinsic among them) compile ahead of time and
    write what numba's write, into the same starting arrays."""
    kernel = kernels.Kernel(name, compiled)
    assert kernel.compiled is not None
    for seed in range(4):
        ahead, just_in_time = _volume_arguments(seed)[name], _volume_arguments(seed)[name]
        kernel(*ahead)  # fits the signature: the compiled code
        getattr(shared.volume_kernels, name)(*just_in_time)
        assert np.array_equal(ahead[-1], just_in_time[-1])
        assert not np.array_equal(ahead[-1], _volume_arguments(seed)[name][-1])  # written


def test_compiled_kernels_are_ready_without_numba(compiled, monkeypatch):
    monkeypatch.setattr(kernels, "jit_ready", lambda: False)
    built = kernels.Kernel("census_aggregate", compiled)
    missing = kernels.Kernel("census_aggregate", None)
    assert kernels.ready(built)
    assert not kernels.ready(built, missing)  # one of them would wait for numba's import
    monkeypatch.setattr(kernels, "jit_ready", lambda: True)
    assert kernels.ready(built, missing)


def test_calls_that_do_not_fit_the_signature_go_to_numba(compiled, monkeypatch):
    kernel = kernels.Kernel("_disagreements", compiled)
    taken = []
    monkeypatch.setattr(kernel, "compiled", lambda *a: taken.append("compiled") or 0)
    monkeypatch.setattr(kernel, "_jit", lambda *a: taken.append("jit") or 0)
    rows = np.zeros((3, 4), dtype=np.int32)
    kernel(rows, np.zeros((3, 4), dtype=np.int32))
    kernel(rows, np.zeros((4, 3), dtype=np.int32).T)  # strided
    kernel(rows, np.zeros((3, 4), dtype=np.int64))  # another dtype: would read garbage
    kernel(rows.astype(np.float32), np.zeros((3, 4), dtype=np.int32))
    assert taken == ["compiled", "jit", "jit", "jit"]


def test_integer_arguments_fit_int64_but_booleans_do_not():
    assert kernels._fits(3, "int64") and kernels._fits(np.int32(3), "int64")
    assert not kernels._fits(True, "int64") and not kernels._fits(3.0, "int64")


def test_a_module_of_other_kernels_is_not_loaded(directory, compiled, tmp_path, monkeypatch):
    assert compiled is not None
    for index, source in enumerate(kernels.SOURCES):  # a change in any of the modules
        changed = tmp_path / source.name
        changed.write_bytes(source.read_bytes() + b"\n# changed\n")
        sources = list(kernels.SOURCES)
        sources[index] = changed
        monkeypatch.setattr(kernels, "SOURCES", tuple(sources))
        assert kernels.load_compiled(directory) is None


def test_a_module_built_for_another_cpu_level_is_not_loaded(directory, compiled, monkeypatch):
    """A home folder shared by two machines: one without x86-64-v2 must not load the module
    the other built for it (an illegal instruction), nor the other way round."""
    assert compiled is not None
    other = "" if kernels.target_cpu() else "x86-64-v2"
    monkeypatch.setattr(kernels, "target_cpu", lambda: other)
    assert kernels.load_compiled(directory) is None


V2 = "cx16 lahf_lm popcnt pni ssse3 sse4_1 sse4_2"
V3 = "avx avx2 bmi1 bmi2 f16c fma abm movbe xsave"
V4 = "avx512f avx512bw avx512cd avx512dq avx512vl"


@pytest.mark.parametrize(
    ("machine", "flags", "target"),
    [
        ("x86_64", "fpu cx16 lahf_lm popcnt pni ssse3 sse4_1 sse4_2 avx2", "x86-64-v2"),
        ("x86_64", f"{V2} {V3}", "x86-64-v3"),
        ("x86_64", f"{V2} {V3} {V4}", "x86-64-v4"),
        ("x86_64", f"{V2} {V3} {V4}".replace(" abm", ""), "x86-64-v2"),  # no LZCNT: not v3, v4
        ("x86_64", f"{V2} {V4}", "x86-64-v2"),  # AVX-512 without v3's features
        ("x86_64", "fpu cx16 lahf_lm pni ssse3 sse4_1 sse4_2", ""),  # no POPCNT
        ("aarch64", "fp asimd cpuid", ""),
        ("x86_64", None, ""),  # no /proc/cpuinfo
    ],
)
def test_the_target_is_the_highest_x86_64_level_the_cpu_has(
    tmp_path, monkeypatch, machine, flags, target
):
    cpuinfo = tmp_path / "cpuinfo"
    if flags is not None:
        cpuinfo.write_text(f"processor\t: 0\nflags\t\t: {flags}\n\nprocessor\t: 1\n")
    monkeypatch.setattr(kernels.platform, "machine", lambda: machine)
    assert kernels.target_cpu(cpuinfo) == target


def test_the_compiled_wrappers_release_the_gil(directory):
    """The two views solve in two threads: the compiled wrappers must release the GIL around a
    kernel, as the jit ones do (``nogil``); pycc's own flags do not (a module built without
    :func:`shared.kernel_build._releasing_gil` calls no ``PyEval_SaveThread``)."""
    (built,) = directory.glob(f"{kernels.module_name()}.*")  # not the C chain kernel
    assert b"PyEval_SaveThread" in built.read_bytes()


def test_the_build_puts_the_c_kernels_beside_the_module(directory):
    """``qhsm build-kernels`` builds the C kernels too (:mod:`shared.native`); a ``.so`` named
    after the module that ``load_compiled``'s pattern does not take."""
    assert all(kernels.native_library_path(name, directory).exists() for name in native.LIBRARIES)
    library = native.load(kernels.native_library_path("chains", directory), "chains")
    assert library is not None
    assert kernels.load_compiled(directory) is not None
    chains = NativeChains(library)
    kernel = kernels.Kernel("_chains_windows", kernels.load_compiled(directory), chains)
    rng = np.random.default_rng(5)
    base, extra = rng.random((2, 7, 9, 3), dtype=np.float32)
    first = rng.integers(0, 4, (7, 9), dtype=np.int32)
    arguments = (base, 0.5, extra, -1.0, first, rng.random((7, 8)), 0.2, 0.5)
    ours, numbas = np.zeros((7, 9), np.int32), np.zeros((7, 9), np.int32)
    energies = kernel(*arguments, ours, False)
    assert np.array_equal(energies, shared.grid_kernels._chains_windows(*arguments, numbas, False))
    assert np.array_equal(ours, numbas)


def test_without_a_compiler_the_c_kernel_build_warns(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.warns(UserWarning, match="C kernels .* were not built"):
        assert kernel_build.build_native(tmp_path) == []
    assert not any(kernels.native_library_path(n, tmp_path).exists() for n in native.LIBRARIES)


def test_a_damaged_module_is_left_to_numba(tmp_path):
    (tmp_path / f"{kernels.module_name()}.cpython-311-x86_64-linux-gnu.so").write_bytes(b"no")
    assert kernels.load_compiled(tmp_path) is None
