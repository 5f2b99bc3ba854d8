"""``qhsm build-kernels`` writes the byte code of qhsm's packages (shared/bytecode.py), even
where the environment forbids Python to write it on import (``PYTHONDONTWRITEBYTECODE``)."""

from __future__ import annotations

import importlib.util
import sys

from shared.bytecode import compile_packages


def test_every_module_of_a_package_gets_its_byte_code_and_absent_ones_are_skipped(
    tmp_path, monkeypatch
):
    package = tmp_path / "qhsm_probe"
    (package / "inner").mkdir(parents=True)
    for module in ("__init__.py", "views.py", "inner/__init__.py", "inner/costs.py"):
        (package / module).write_text("VALUE = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    assert compile_packages(("qhsm_probe", "qhsm_not_installed")) == ["qhsm_probe"]
    for module in ("views.py", "inner/costs.py"):
        assert (package / importlib.util.cache_from_source(module)).exists()
