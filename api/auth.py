"""Who is calling. For now every caller is anonymous; API keys and quotas (issue 5) replace
``current_principal`` and ``can_see`` without touching the routes, which only depend on them."""

from __future__ import annotations

from dataclasses import dataclass

from fastapi import Request

from workers.store import JobRecord


@dataclass(frozen=True)
class Principal:
    name: str
    anonymous: bool = True


ANONYMOUS = Principal("anonymous")


def current_principal(request: Request) -> Principal:
    """FastAPI dependency: the caller (always anonymous until API keys exist)."""
    return ANONYMOUS


def can_see(principal: Principal, record: JobRecord) -> bool:
    """Whether ``principal`` may read or cancel ``record``."""
    return principal.anonymous or record.owner == principal.name
