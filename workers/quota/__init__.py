"""Per-user QPU-time budgets and the lab-wide limit on QPU problems in flight, in Redis.

One D-Wave token serves the whole lab; this package rations it per user. Before a metered bundle
(QPU or hybrid) is sent, the worker takes a *slot* from the lab-wide semaphore and *reserves*
the bundle's estimated time from the owner's budget; afterwards it *settles* the reservation with
the time the sample set reports (``qpu_access_time``; hybrid: ``charge_time``) and frees the
slot. Each step is one Lua script (the ``.lua`` files beside the modules), so concurrent workers
see consistent budgets and the budget can only be overspent by what in-flight bundles use beyond
their estimates. A worker killed mid-bundle cannot leak anything: its slot and its reservation
expire after ``Settings.qpu_slot_ttl`` (+ the bundle's estimate). Times are seconds; the clock
is Redis's (``TIME``), not the workers'. What is reserved is :mod:`shared.solvers.meters.qpu_time`'s
estimate, what is charged the solver's meter's reading (:mod:`shared.solvers.meters`); this package
only settles them.

Modules:

- :mod:`~workers.quota.ledger`     per-user accounting: budgets, reservations, charges, usage
- :mod:`~workers.quota.semaphore`  the lab-wide (and per-user) limit on problems in flight
- :mod:`~workers.quota.meter`      slot + reservation + settlement around each metered bundle
- :mod:`~workers.quota.scripts`    reads the Lua sources shipped with the package
"""

from shared.solvers.meters.qpu_time import bundle_estimate  # the amount reserved, re-exported
from workers.quota.ledger import (
    LOCAL_USER,
    JobUsage,
    QuotaExceededError,
    QuotaLedger,
    QuotaStatus,
    Reservation,
    UserUsage,
)
from workers.quota.meter import Charge, QpuMeter, solve_metered
from workers.quota.semaphore import NoQpuSlotError, QpuSemaphore

__all__ = [
    "LOCAL_USER",
    "Charge",
    "JobUsage",
    "NoQpuSlotError",
    "QpuMeter",
    "QpuSemaphore",
    "QuotaExceededError",
    "QuotaLedger",
    "QuotaStatus",
    "Reservation",
    "UserUsage",
    "bundle_estimate",
    "solve_metered",
]
