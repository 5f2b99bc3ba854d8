"""The Lua sources shipped beside this package: each budget or slot step runs as one script
inside Redis, so concurrent workers never see a half-done update."""

from __future__ import annotations

from importlib.resources import files


def load_script(*names: str) -> str:
    """The source of the named ``.lua`` files of this package, joined in order.

    Parameters
    ----------
    names : str
        File stems, shared pieces first (``now`` defines the server clock, ``expire`` the
        function that charges lapsed reservations).

    Returns
    -------
    str
        One script, ready for ``redis.Redis.register_script``.
    """
    folder = files(__package__)
    return "".join(folder.joinpath(f"{name}.lua").read_text(encoding="utf-8") for name in names)
