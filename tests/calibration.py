"""Middlebury ``calib.txt`` text for the tests that read or upload one (the depth, batch and
API tests): the file's layout in one place, each test stating only its cameras."""

from __future__ import annotations


def middlebury_calib(
    focal: float,
    cx: tuple[float, float],
    cy: float,
    doffs: float,
    baseline: float,
    size: tuple[int, int],
    ndisp: int,
    **extra: float,
) -> str:
    """A Middlebury 2014 ``calib.txt``: both cameras' matrices (``cx`` left and right), the
    scalars, ``size`` as (width, height), then ``extra`` lines (``isint``, ``vmin``, ...).

    Numbers are written as Python writes them (``500``, ``3979.911``), as the files do.
    """

    def number(value: float) -> str:
        return str(int(value)) if float(value).is_integer() else str(value)

    f, y = number(focal), number(cy)
    lines = [f"cam{i}=[{f} 0 {number(x)}; 0 {f} {y}; 0 0 1]" for i, x in enumerate(cx)]
    width, height = size
    fields = dict(doffs=doffs, baseline=baseline, width=width, height=height, ndisp=ndisp, **extra)
    lines += [f"{key}={number(value)}" for key, value in fields.items()]
    return "\n".join(lines) + "\n"
