"""Who is calling, and what they may see: the routes depend only on ``current_principal`` and
``can_see``. Keys, users and the bearer-token check live in :mod:`api.users`."""

from __future__ import annotations

from api.users import User, admin_user, current_user
from workers.records import JobRecord

#: The authenticated caller (a lab member; ``admin`` sees and cancels every job).
Principal = User
current_principal = current_user


def can_see(principal: Principal, record: JobRecord) -> bool:
    """Whether ``principal`` may read or cancel ``record``: its owner, or an admin."""
    return principal.admin or record.owner == principal.name


__all__ = ["Principal", "admin_user", "can_see", "current_principal", "current_user"]
