"""Compile the kernels of :mod:`shared.grid_kernels`, :mod:`shared.trws_kernels` and
:mod:`shared.volume_kernels` ahead of time (numba's ``pycc``) into the module
:mod:`shared.kernels` loads, and the C kernels' libraries beside it (:mod:`shared.native`):
``qhsm build-kernels`` once after installing or upgrading (about 15 s of CPU here; needs a C
compiler), or ``qhsm match`` in a terminal in the background (:mod:`shared.kernel_background`).
Without it everything works, each process then compiles or loads the kernels through numba
(issue 28, item 3).

Numba 0.68 still ships ``numba.pycc`` (deprecated since 0.57 without a replacement); should it
go, the build fails with that message and the kernels stay just-in-time.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import sysconfig
import tempfile
import warnings
from collections.abc import Mapping
from pathlib import Path

from shared import native
from shared.kernels import (
    SIGNATURES,
    cache_directory,
    dispatcher,
    module_name,
    native_library_path,
    pycc_signature,
    target_cpu,
)


def compiler_command(environ: Mapping[str, str] = os.environ) -> list[str]:
    """The C compiler's command ``numba.pycc`` calls (setuptools' Unix compiler: ``$CC``, else
    Python's own build ``CC``), which the C kernels are built with too; [] when none is
    named."""
    return shlex.split(environ.get("CC") or sysconfig.get_config_var("CC") or "")


def _releasing_gil(flags: type) -> type:
    """``flags`` (numba's compiler flags) with ``release_gil`` on by default."""

    class ReleasingGil(flags):
        def __init__(self, *args: object, **kwargs: object) -> None:
            super().__init__(*args, **kwargs)
            self.release_gil = True

    return ReleasingGil


def build(directory: Path | None = None, names: tuple[str, ...] | None = None) -> Path:
    """Compile the kernels and put the module where :func:`shared.kernels.load_compiled` looks.

    Parameters
    ----------
    directory : pathlib.Path, optional
        Destination (default: :func:`shared.kernels.cache_directory`).
    names : tuple of str, optional
        A subset of :data:`shared.kernels.SIGNATURES` (default: all); the others stay
        just-in-time.

    Returns
    -------
    pathlib.Path
        The compiled module's file. With a kernel of :data:`shared.native.KERNELS` among
        ``names`` (or all) the C kernels are built beside it (:func:`build_native`).
    """
    with warnings.catch_warnings():  # pycc's deprecation notice: said in the module doc
        warnings.simplefilter("ignore")
        import numba.pycc.compiler
        from numba.pycc import CC

    import shared.grid_kernels

    directory = directory or cache_directory()
    directory.mkdir(parents=True, exist_ok=True)
    name = module_name()
    flags = numba.pycc.compiler.Flags
    with contextlib.ExitStack() as stack:
        # pycc's Python wrappers keep the GIL, the kernels' ``nogil`` notwithstanding: its flags
        # with ``release_gil`` set, as the jit wrappers have (two views solve in two threads)
        setattr(numba.pycc.compiler, "Flags", _releasing_gil(flags))  # noqa: B010 (a type)
        stack.callback(setattr, numba.pycc.compiler, "Flags", flags)
        scratch = stack.enter_context(tempfile.TemporaryDirectory(dir=directory))
        cc = CC(name, source_module=shared.grid_kernels)
        cc.output_dir = scratch
        cc.target_cpu = target_cpu()  # the highest x86-64 level the CPU has (v2: POPCNT, SSE4)
        for kernel in names or tuple(SIGNATURES):
            source = dispatcher(kernel).py_func  # type: ignore[attr-defined]
            cc.export(kernel, pycc_signature(kernel))(source)
        cc.compile()
        built = next(Path(scratch).glob(f"{name}.*"))
        target = directory / built.name
        os.replace(built, target)  # atomic: a process loading it sees all or nothing
    if names is None or set(names) & set(native.KERNELS):
        build_native(directory)
    return target


def build_native(directory: Path) -> list[Path]:
    """The C kernels' libraries (:data:`shared.native.LIBRARIES`) into ``directory``; one that
    cannot be built is left out with a warning saying why (numba's kernel or OpenCV's filter
    then runs: the same results)."""
    command = compiler_command() or ["cc"]
    built = []
    for name in native.LIBRARIES:
        try:
            target = native_library_path(name, directory)
            built.append(native.compile_library(command, target, target_cpu(), name))
        except (OSError, RuntimeError) as error:
            warnings.warn(f"the C kernels ({name}) were not built: {error}", stacklevel=2)
    return built
