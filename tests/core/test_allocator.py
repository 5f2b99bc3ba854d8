"""``qhsm match`` keeps the memory its arrays free for the next ones (``shared.allocator``):
an array freed and allocated again is not faulted in page by page again."""

from __future__ import annotations

import subprocess
import sys

import pytest

from shared.allocator import keep_freed_memory

#: A 16 MiB array (4096 pages) freed, allocated again and written; prints the page faults the
#: second allocation took. argv[1]: "keep" calls keep_freed_memory first.
SCRIPT = """
import resource, sys
import numpy as np
from shared.allocator import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
first = np.ones(1 << 22, np.float32)
del first
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
second = np.ones(1 << 22, np.float32)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> int:
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, check=True
    )
    return int(done.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_arrays_are_reused_without_page_faults():
    if not keep_freed_memory():  # this process too: harmless, and says whether glibc is here
        pytest.skip("not glibc: the allocator keeps its own policy")
    assert _faults("default") >= 4000  # returned to the kernel, faulted in again
    assert _faults("keep") < 400
