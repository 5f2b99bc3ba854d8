"""``qhsm match`` with ``exact`` (the default) imports no QUBO machinery (issue 28): dimod, and
networkx with it, cost a third of a second of CPU at every start."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from shared.synthetic import make_scene

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import sys
from shared.cli import main
code = main(sys.argv[1:])
heavy = ("dimod", "networkx", "celery", "fastapi", "dwave", "pydantic_settings")
heavy = sorted(m for m in heavy if m in sys.modules)
print("HEAVY", ",".join(heavy))
sys.exit(code)
"""


def _write_views(folder: Path, seed: int) -> list[str]:
    """A small synthetic pair as 8-bit PNGs in ``folder``: the paths ``qhsm match`` is given."""
    scene = make_scene(20, 28, max_disparity=4, seed=seed)
    views = []
    for name, view in (("left", scene.left), ("right", scene.right)):
        path = folder / f"{name}.png"
        cv2.imwrite(str(path), np.round(np.clip(view, 0, 1) * 255).astype(np.uint8))
        views.append(str(path))
    return views


def _python(
    code: str, *args: str, timeout: int, cache: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """``code`` run by a fresh interpreter with this tree on its path (and ``cache`` as its
    cache folder): what it imports is what a fresh ``qhsm`` process would."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if cache is not None:
        env["XDG_CACHE_HOME"] = str(cache)
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=timeout,
    )


def test_match_with_exact_imports_neither_dimod_nor_networkx(tmp_path):
    views = _write_views(tmp_path, seed=0)
    output = tmp_path / "d.pfm"
    done = _python(PROBE, "match", *views, "-o", str(output), "--max-disparity", "4", timeout=120)
    assert done.returncode == 0, done.stderr
    assert output.exists()
    assert "HEAVY \n" in done.stdout


def test_match_with_compiled_kernels_imports_no_numba_and_gives_the_same_map(tmp_path):
    """With the kernels built ahead of time (``qhsm build-kernels``) neither numba nor SciPy is
    imported, and the map is the just-in-time one's, byte for byte; without them numba starts
    without SciPy (:mod:`shared.numba_start`)."""
    from shared.kernel_build import build

    views = _write_views(tmp_path, seed=1)
    probe = PROBE.replace('"dwave", ', '"dwave", "numba", "scipy", ')
    assert probe != PROBE
    maps = []
    for cache in (tmp_path / "none", tmp_path / "built"):
        if cache.name == "built":
            build(cache / "qhsm" / "kernels")
        output = tmp_path / f"{cache.name}.pfm"
        args = ("match", *views, "-o", str(output), "--max-disparity", "4")
        done = _python(probe, *args, timeout=300, cache=cache)
        assert done.returncode == 0, done.stderr
        maps.append(output.read_bytes())
        heavy = "HEAVY numba\n" if cache.name == "none" else "HEAVY \n"  # numba_start
        assert heavy in done.stdout
    assert maps[0] == maps[1]


def test_preload_loads_the_jit_kernels_in_one_background_thread(tmp_path):
    """Without a compiled module, ``kernels.preload`` imports numba and loads a kernel in a
    thread of its own, once per process, so that the first level's solve finds them loaded."""
    probe = """
import sys
from shared import kernels
assert "shared.grid_kernels" not in sys.modules
kernels.preload()
started = kernels._preloading
kernels.preload()
assert kernels._preloading is started and started.daemon
started.join(120)
print("LOADED", "shared.grid_kernels" in sys.modules, kernels.disagreements._jit is not None)
"""
    done = _python(probe, timeout=180, cache=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "LOADED True True" in done.stdout


def test_the_preload_imports_no_scipy_and_the_kernels_give_the_same_floats(tmp_path):
    """numba started by the preload (SciPy refused to its thread) and numba started with SciPy
    give the same kernel results; SciPy stays importable by the other threads meanwhile."""
    probe = """
import sys, threading, hashlib
import numpy as np
from shared import kernels, numba_start
if sys.argv[1] == "preload":
    kernels.preload()
    kernels._preloading.join(120)
    assert "scipy" not in sys.modules, "the preload imported SciPy"
    with numba_start.without_scipy():
        other = threading.Thread(target=lambda: __import__("scipy.linalg"))
        other.start()
        other.join()
    assert "scipy.linalg" in sys.modules
else:
    import scipy.linalg
rng = np.random.default_rng(0)
h, w, k = 6, 9, 5
args = (
    rng.random((h, w, k), dtype=np.float32), rng.integers(0, 9, (h, w, k), dtype=np.int32),
    np.zeros((1, 1), dtype=np.int32), False, rng.random((h, w - 1)), rng.random((h - 1, w)),
    0.7, 2.5, rng.integers(0, k, (h, w), dtype=np.int32),
)
print("ENERGY", hashlib.sha256(kernels.grid_energy.jit()(*args).tobytes()).hexdigest())
"""
    done = [_python(probe, how, timeout=180, cache=tmp_path) for how in ("preload", "scipy")]
    assert all(d.returncode == 0 for d in done), [d.stderr for d in done]
    energies = [d.stdout.split("ENERGY ")[1] for d in done]
    assert energies[0] == energies[1]


def _fresh_import(probe: str, unset: tuple[str, ...], extra: dict[str, str]) -> str:
    """What ``probe`` prints in a fresh interpreter, run with this checkout on the path, the
    variables ``unset`` removed from this environment and ``extra`` added."""
    env = {k: v for k, v in os.environ.items() if k not in unset}
    done = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**env, **extra, "PYTHONPATH": str(ROOT)},
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_numpy_gets_no_huge_page_hint_unless_the_environment_asks():
    """``shared`` precedes numpy's import with NUMPY_MADVISE_HUGEPAGE=0 (the page faults of
    MADV_HUGEPAGE arrays cost Aloe seconds of system time); a value already set wins."""
    probe = "import shared, numpy; print(numpy._core.multiarray._get_madvise_hugepage())"
    for given, expected in ((None, "False"), ("1", "True")):
        extra = {} if given is None else {"NUMPY_MADVISE_HUGEPAGE": given}
        assert _fresh_import(probe, ("NUMPY_MADVISE_HUGEPAGE",), extra) == expected


def _threads_after_numpy(extra: dict[str, str]) -> int:
    """Threads of a fresh process that imported ``shared``, then numpy (OpenBLAS starts its own
    at load), with ``extra`` in an environment that sets no thread count."""
    names = ("GOTO_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "QHSM_USER_THREADS")
    probe = "import os, shared, numpy; print(len(os.listdir('/proc/self/task')))"
    return int(_fresh_import(probe, names, extra))


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc (Linux)")
def test_numpy_blas_runs_on_one_thread_unless_the_environment_asks():
    """``shared`` precedes numpy's import with GOTO_NUM_THREADS=1: OpenBLAS starts no thread of
    its own (it spun on the run's other core after each luma product); a user's
    OPENBLAS_NUM_THREADS wins."""
    assert _threads_after_numpy({}) == 1
    if (os.cpu_count() or 1) >= 2:
        assert _threads_after_numpy({"OPENBLAS_NUM_THREADS": "2"}) == 2
