"""The byte code of qhsm's own packages, written by ``qhsm build-kernels`` beside the sources.

An editable install (``pip install -e .``, README's) writes none at install, and where the
environment forbids writing it (``PYTHONDONTWRITEBYTECODE``, common in images and CI) every
process compiled each module again: ~0.06 s of Tsukuba's 0.9 s (docs/benchmarks.md).
"""

from __future__ import annotations

import compileall
import importlib.util

#: qhsm's top-level packages.
PACKAGES = ("shared", "qhsm", "api", "workers")


def compile_packages(packages: tuple[str, ...] = PACKAGES) -> list[str]:
    """Write the byte code of every module of ``packages``; a package not installed, or whose
    folder cannot be written, is left out.

    Parameters
    ----------
    packages : tuple of str, optional
        Top-level package names.

    Returns
    -------
    list of str
        The packages whose every module was compiled.
    """
    compiled = []
    for name in packages:
        spec = importlib.util.find_spec(name)
        folders = list(spec.submodule_search_locations or []) if spec else []
        if folders and all(compileall.compile_dir(folder, quiet=2) for folder in folders):
            compiled.append(name)
    return compiled
