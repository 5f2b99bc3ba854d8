"""``qhsm admin``: users, API keys and QPU budgets, straight in the service's Redis.

    qhsm admin create-user NAME [--qpu-seconds N] [--admin]   prints the new key ONCE
    qhsm admin list-users
    qhsm admin rotate-key NAME                                 prints the new key ONCE
    qhsm admin revoke NAME
    qhsm admin set-quota NAME SECONDS                          ("unlimited" lifts the limit)
    qhsm admin usage [NAME] [--json | --csv]

It talks to Redis directly, so it needs no API key (whoever can reach the service's Redis
administers it anyway): --redis-url, else QHSM_REDIS_URL / REDIS_URL, else the data directory's
embedded Redis (--data-dir / QHSM_DATA_DIR) -- the running `qhsm serve`'s, or one started for the
command. A data directory no `qhsm serve` has used is refused (only create-user may start a new
store there, and says so). It always says which store it used (on stderr).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
from collections.abc import Iterator

from shared.cli_options import CommandError, setting_option
from shared.settings import BudgetPeriod


@contextlib.contextmanager
def _store(args: argparse.Namespace, creates: bool = False) -> Iterator:
    """The user store of the service's Redis, saying which Redis that is.

    --redis-url, else QHSM_REDIS_URL, else the data directory's embedded Redis: the running
    `qhsm serve`'s, or one started here for this command (never a Redis that merely answers on
    the default port). A data directory that never held a store is refused, unless the command
    ``creates`` something (``create-user``), which says it starts a new one."""
    import redis

    from api.users import UserStore
    from shared.config import get_settings
    from workers.embedded_redis import (
        EMBEDDED_URL_FILE,
        PASSWORD_FILE,
        DataDirBusyError,
        DataDirLock,
        EmbeddedRedis,
        safe_url,
    )
    from workers.redis_client import connect

    settings = get_settings()
    if args.data_dir is not None:
        settings = settings.model_copy(update={"data_dir": args.data_dir})
    data_dir = settings.data_dir.resolve()
    lock, server = None, None
    try:
        configured: str | None = args.redis_url or settings.redis_url
        if configured:
            url = configured
            source = "--redis-url" if args.redis_url else "QHSM_REDIS_URL"
            where = f"Redis at {safe_url(url)} (from {source})"
        elif DataDirLock(data_dir).held_by_other():
            try:
                url = (data_dir / EMBEDDED_URL_FILE).read_text().strip()
            except OSError:
                raise CommandError(
                    f"{data_dir} is in use by a starting `qhsm serve`; try again in a moment"
                ) from None
            where = f"the embedded Redis of the running `qhsm serve` (data dir {data_dir})"
        else:
            new = not (data_dir / "redis" / PASSWORD_FILE).is_file()
            if new and not creates:
                raise CommandError(
                    f"no store in the data directory {data_dir}: no `qhsm serve` has used it "
                    "(serve prints its data directory). Pass --data-dir DIR or set "
                    "QHSM_DATA_DIR to that directory, or --redis-url for a deployment's Redis"
                )
            try:
                lock = DataDirLock(data_dir).acquire()
            except DataDirBusyError as error:
                raise CommandError(str(error)) from None
            server = EmbeddedRedis(data_dir / "redis").start()
            url = server.url
            where = (
                f"a NEW, empty store in data dir {data_dir} (no `qhsm serve` has used it yet; "
                "started for this command)"
                if new
                else f"the embedded Redis of data dir {data_dir} (started for this command)"
            )
        print(f"store: {where}", file=sys.stderr)
        client = connect(url, socket_connect_timeout=2)
        try:
            client.ping()
        except redis.RedisError as error:
            raise CommandError(
                f"cannot reach Redis at {safe_url(url)} ({error}): set QHSM_REDIS_URL, pass "
                "--redis-url, or --data-dir for the embedded one"
            ) from None
        yield UserStore.from_settings(settings, client)
    finally:
        if server is not None:
            server.stop()
        if lock is not None:
            lock.release()


def _call(action):
    """Run a store action, turning ``UserError`` into a one-line CLI error."""
    from api.users import UserError

    try:
        return action()
    except UserError as error:
        raise CommandError(str(error)) from None


def _seconds(value: str) -> float | None:
    if value.lower() in ("unlimited", "none", "inf"):
        return None
    try:
        seconds = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected seconds or 'unlimited', got {value!r}"
        ) from None
    if not math.isfinite(seconds) or seconds < 0:
        raise argparse.ArgumentTypeError(
            f"seconds must be a finite number >= 0 (or 'unlimited'), got {value!r}"
        )
    return seconds


def _print_key(name: str, key: str) -> None:
    print(key)
    print(
        f"(API key of {name}: shown once, store it now; send it as `Authorization: Bearer KEY`, "
        "or set QHSM_API_KEY for `qhsm submit`)",
        file=sys.stderr,
    )


def cmd_create_user(args: argparse.Namespace) -> int:
    with _store(args, creates=True) as store:
        # --qpu-seconds not given: the store's default budget of new users
        budget = {"qpu_seconds": args.qpu_seconds} if "qpu_seconds" in args else {}
        user, key = _call(lambda: store.create_user(args.name, admin=args.admin, **budget))
        _print_key(user.name, key)
        return 0


def cmd_list_users(args: argparse.Namespace) -> int:
    with _store(args) as store:
        rows = []
        for user in store.list_users():
            budget = store.ledger.status(user.name)
            rows.append({**user.model_dump(mode="json"), **budget.as_dict()})
        if args.json:
            print(json.dumps(rows, indent=2))
            return 0
        print(
            f"{'name':<20} {'admin':<5} {'state':<8} {'key id':<9} {'used s':>10} {'limit s':>10}"
        )
        for row in rows:
            limit = "unlimited" if row["limit_seconds"] is None else f"{row['limit_seconds']:.3f}"
            print(
                f"{row['name']:<20} {'yes' if row['admin'] else 'no':<5} "
                f"{'revoked' if row['revoked'] else 'active':<8} {row['key_id'] or '-':<9} "
                f"{row['used_seconds']:>10.3f} {limit:>10}"
            )
        return 0


def cmd_rotate_key(args: argparse.Namespace) -> int:
    with _store(args) as store:
        key = _call(lambda: store.rotate_key(args.name))
        _print_key(args.name, key)
        return 0


def cmd_revoke(args: argparse.Namespace) -> int:
    with _store(args) as store:
        _call(lambda: store.revoke(args.name))
        print(f"revoked the key of {args.name} (rotate-key issues a new one)")
        return 0


def cmd_set_quota(args: argparse.Namespace) -> int:
    with _store(args) as store:
        _call(lambda: store.require(args.name))
        store.ledger.set_limit(args.name, args.seconds)
        if args.period is not None:
            store.ledger.set_period(args.name, None if args.period == "default" else args.period)
        status = store.ledger.status(args.name)
        limit = "unlimited" if status.limit is None else f"{status.limit:g} s"
        print(
            f"{args.name}: QPU budget {limit}, used {status.used:.3f} s {status.period.this} "
            f"({status.period.describe()})"
        )
        return 0


def usage_line(entry: dict) -> str:
    """One user's budget as ``qhsm admin usage`` and ``qhsm usage`` print it: used and left in
    the period, and when it resets."""
    limit = entry["limit_seconds"]
    line = (
        f"{entry['user']}: used {entry['used_seconds']:.3f} s of "
        f"{'unlimited' if limit is None else f'{limit:g} s'}"
        f" ({entry['reserved_seconds']:.3f} s reserved"
    )
    if entry["remaining_seconds"] is not None:
        line += f", {entry['remaining_seconds']:.3f} s left"
    if not entry.get("resets_at"):
        return f"{line})"
    return (
        f"{line}; {entry['period']} since {entry['period_start']}, resets at "
        f"{entry['resets_at']}; {entry['total_used_seconds']:.3f} s in total)"
    )


def cmd_usage(args: argparse.Namespace) -> int:
    from workers.quota.ledger import usage_csv

    with _store(args) as store:
        if args.name:
            _call(lambda: store.require(args.name))
            names = [args.name]
        else:
            names = sorted({u.name for u in store.list_users()} | set(store.ledger.users()))
        ledger = [store.ledger.usage(name) for name in names]
        if args.csv:
            print(usage_csv(ledger), end="")
            return 0
        usage = [entry.as_dict() for entry in ledger]
        if args.json:
            print(json.dumps(usage, indent=2))
            return 0
        print_usage(usage)
        return 0


def print_usage(usage: list[dict]) -> None:
    """Each user's budget line (:func:`usage_line`), its warning and its jobs' charges."""
    for entry in usage:
        print(usage_line(entry))
        if entry["warning"]:
            print(f"  warning: {entry['warning']}")
        for job in entry["jobs"]:
            when = job["last_charged_at"] or "-"
            print(f"  {job['id']}  {job['qpu_seconds']:.6f} s  {job['problems']} problems  {when}")


def register(subparsers) -> None:
    """Entry point of the ``qhsm.commands`` group: adds ``qhsm admin``."""
    admin = subparsers.add_parser("admin", help="manage users, API keys and QPU budgets")
    setting_option(
        admin,
        "redis_url",
        help="the service's Redis (default: QHSM_REDIS_URL, else the data directory's embedded "
        "Redis: the running `qhsm serve`'s, or started for the command)",
    )
    setting_option(admin, "data_dir", help="data directory of the embedded Redis")
    commands = admin.add_subparsers(dest="admin_command", required=True)

    create = commands.add_parser("create-user", help="add a user; prints their key once")
    create.add_argument("name", help="user name: letters, digits, '_', '.', '@' or '-'")
    create.add_argument(
        "--qpu-seconds",
        type=_seconds,
        default=argparse.SUPPRESS,  # not given: api.users' default budget of new users
        help="QPU/hybrid budget in seconds or 'unlimited' (default: QHSM_DEFAULT_QPU_SECONDS)",
    )
    create.add_argument("--admin", action="store_true", help="may see every job and all usage")
    create.set_defaults(handler=cmd_create_user)

    listing = commands.add_parser("list-users", help="users, key ids, budgets")
    listing.add_argument("--json", action="store_true")
    listing.set_defaults(handler=cmd_list_users)

    for command, about, whose, handler in (
        ("rotate-key", "replace a user's key; prints it once", "replaced", cmd_rotate_key),
        ("revoke", "disable a user's key", "disabled", cmd_revoke),
    ):
        keyed = commands.add_parser(command, help=about)
        keyed.add_argument("name", help=f"user whose key is {whose}")
        keyed.set_defaults(handler=handler)

    quota = commands.add_parser("set-quota", help="set a user's QPU budget (per period)")
    quota.add_argument("name", help="user whose budget is set")
    quota.add_argument("seconds", type=_seconds, help="seconds per period, or 'unlimited'")
    quota.add_argument(
        "--period",
        choices=[*(period.value for period in BudgetPeriod), "default"],
        help="the user's own budget period ('default': QHSM_BUDGET_PERIOD's; not given: unchanged)",
    )
    quota.set_defaults(handler=cmd_set_quota)

    usage = commands.add_parser("usage", help="QPU time used, per user and job")
    usage.add_argument("name", nargs="?", help="one user (default: every user)")
    usage.add_argument("--json", action="store_true")
    usage.add_argument(
        "--csv", action="store_true", help="one row per user and job, with the charge dates"
    )
    usage.set_defaults(handler=cmd_usage)
