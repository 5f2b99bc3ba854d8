"""QUBO codecs: the costs of a bundle to a ``dimod.BinaryQuadraticModel`` and a sample back to
labels. Each codec module exposes the same five functions; ``get_codec`` picks one by name."""

from __future__ import annotations

from types import ModuleType

from shared.config import Encoding
from shared.encodings import domain_wall, onehot
from shared.encodings.base import Decoded

CODECS: dict[Encoding, ModuleType] = {
    Encoding.ONE_HOT: onehot,
    Encoding.DOMAIN_WALL: domain_wall,
}


def get_codec(encoding: Encoding | str) -> ModuleType:
    """The codec module for an encoding name (``one-hot`` or ``domain-wall``).

    Parameters
    ----------
    encoding : Encoding or str
        ``one-hot`` or ``domain-wall``.

    Returns
    -------
    module
        :mod:`shared.encodings.onehot` or :mod:`shared.encodings.domain_wall`.

    Raises
    ------
    ValueError
        If the name is not an encoding.
    """
    return CODECS[Encoding(encoding)]


__all__ = ["CODECS", "Decoded", "get_codec"]
