"""The watchdog: what a dead worker held goes back to its queue, and an active job whose work
is lost or stalled gets it sent again, so a job finishes (or fails with a reason) within a
couple of minutes of any process dying instead of waiting for the 6-hour visibility timeout.

Each round (a few seconds: :attr:`Watchdog.period`) it first re-queues the unacknowledged
messages of workers that stopped sending heartbeats (``workers/liveness.py``: exactly what the
dead worker held; a live worker's long tasks are never touched). Then it looks at every queued
and running job: one without progress for ``watchdog_lost_seconds`` none of whose tasks is in a
queue or held by a live worker lost them (the API died before sending its start, or Redis lost
them): its start, or its level's unsolved bundles, are sent again at once. A running job whose
progress has not moved for ``watchdog_stall_seconds`` although its tasks exist gets its
unsolved bundles re-sent, skipping those a live worker is solving.

Re-sending is safe because results are idempotent: solved bundles are kept in the store by first
row (``JobStore.save_bundles``), and the level's fan-in assembles from them and runs at most once.
What cannot be resumed (a level that was never launched, or whose inputs are gone) restarts the
job from its uploads; bundle seeds are per bundle, so the result is the undisturbed run's. After
``watchdog_max_resends`` attempts without progress the job fails with a reason. A job whose
solver queue still holds messages and has a consumer is waiting its turn, not stalled. Each round
also cancels and stops the estimates nobody polled for ``estimate_abandon_seconds``
(``workers.estimates.sweep_abandoned``); a job being priced is the pricing worker's (acks late).

It runs as a thread of every worker that consumes the control queue; a Redis lock makes one of
them act at a time. Re-sent chunks are counted by ``workers.telemetry`` (``/metrics``:
``qhsm_watchdog_resends_total``); ``resend_count`` reads that count.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import redis
from celery import Celery

from shared.bundles import bundle_key
from shared.inference import inference_for
from workers import estimates, fair, liveness, orchestration
from workers.app import LEVEL_DONE, PLAN_LEVEL, SOLVE_BUNDLES, START_JOB, send_first_task
from workers.chunks import group_bundles, is_planned, rows_per_task
from workers.queues import solver_queue, solver_queues
from workers.records import JobRecord, JobState
from workers.records import now as utc_now
from workers.redis_client import text
from workers.store import JobStore
from workers.telemetry import Telemetry

log = logging.getLogger(__name__)

#: Redis key (under the service's prefix) of the lock that lets one watchdog act.
LOCK_KEY = "watchdog:lock"
PAGE = 500


def resend_count(store: JobStore) -> int:
    """Chunks (and fan-ins, restarts) the watchdog re-sent so far, all jobs (the metric's value)."""
    telemetry = Telemetry(store.redis, store.prefix)
    return int(store.redis.get(telemetry.key("watchdog_resends")) or 0)


def interval(stall_seconds: float) -> float:
    """How often the watchdog looks: a few times per stall period, at most every 30 s."""
    return max(0.5, min(30.0, stall_seconds / 4))


@dataclass
class _Seen:
    signature: tuple
    since: float
    attempts: int = 0
    checked: float = 0.0  # when its messages were last looked for


@dataclass
class Watchdog:
    celery: Celery
    store: JobStore
    name: str
    clock: Callable[[], float] = time.monotonic
    seen: dict[str, _Seen] = field(default_factory=dict)

    @property
    def telemetry(self) -> Telemetry:
        return Telemetry(self.store.redis, self.store.prefix)

    @property
    def stall(self) -> float:
        return self.store.settings.watchdog_stall_seconds

    @property
    def lost_after(self) -> float:
        return self.store.settings.watchdog_lost_seconds

    def active(self) -> Iterator[JobRecord]:
        """Every pricing, queued or running job (records that fail to load are skipped)."""
        index = self.store.key("jobs", "active")
        ids = sorted(text(raw) for raw in self.store.redis.hkeys(index))
        for start in range(0, len(ids), PAGE):
            page = ids[start : start + PAGE]
            raws = self.store.redis.mget([self.store.key("job", job_id) for job_id in page])
            for raw in raws:
                if raw is None:
                    continue
                try:
                    record = JobRecord.model_validate_json(raw)
                except ValueError:
                    continue
                if record.state in (JobState.PRICING, JobState.QUEUED, JobState.RUNNING):
                    yield record

    def signature(self, record: JobRecord) -> tuple:
        """What moves while a job progresses: its state, level, levels done, bundles solved."""
        solved = self.store.solved_count(record.id, record.level - 1) if record.level else 0
        return (record.state, record.level, len(record.levels), solved)

    def leader(self) -> bool:
        """Hold (or renew) the lock that lets one watchdog act at a time."""
        key, ttl = self.store.key(LOCK_KEY), max(2, int(3 * self.period) + 1)
        redis_ = self.store.redis
        if redis_.set(key, self.name, nx=True, ex=ttl):
            return True
        if redis_.get(key) == self.name.encode():
            redis_.expire(key, ttl)
            return True
        return False

    @property
    def period(self) -> float:
        """How often the watchdog looks: often enough to notice a dead worker within a few
        heartbeats, and a stalled job a few times per stall period."""
        heartbeat = self.store.settings.worker_heartbeat_seconds
        return max(0.5, min(interval(self.stall), 2.5 * heartbeat))

    def tick(self) -> list[tuple[str, str]]:
        """Look at every active job once; returns (job id, action) for those it acted on.

        A job without progress for ``watchdog_lost_seconds`` none of whose tasks is anywhere
        (no queue holds one, no live worker: :meth:`messages`) lost them, with the process that
        died holding them or a Redis restart: its work is sent again at once. One that did not
        move for ``watchdog_stall_seconds`` although its tasks exist is handled as stalled."""
        now = self.clock()
        actions = []
        active = set()
        messages: bytes | None = None
        for record in self.active():
            active.add(record.id)
            signature = self.signature(record)
            seen = self.seen.get(record.id)
            if seen is None or seen.signature != signature:
                self.seen[record.id] = _Seen(signature, now, checked=now)
                continue
            idle = now - seen.since
            action = None
            if record.state in (JobState.PRICING, JobState.QUEUED):  # its first task, only
                if idle >= self.lost_after and now - seen.checked >= self.lost_after:
                    seen.checked = now
                    messages = self.messages() if messages is None else messages
                    if record.id.encode() in messages:
                        pass
                    elif not record.dispatched and record.started_at is None:
                        action = self.abandon(record)
                    else:
                        action = self.start_again(record)
            elif idle >= self.stall:
                seen.since = seen.checked = now
                action = self.recover(record, seen.attempts + 1)
            elif idle >= self.lost_after and now - seen.checked >= self.lost_after:
                seen.checked = now
                messages = self.messages() if messages is None else messages
                if record.id.encode() not in messages:
                    log.warning(
                        "job %s: none of its tasks is queued or held by a live worker; "
                        "sending its work again", record.id,
                    )  # fmt: skip
                    action = self.recover(record, seen.attempts + 1, lost=True)
            if action is None:
                continue
            if action not in ("in-flight", "waiting"):
                seen.attempts += 1
            actions.append((record.id, action))
        for job_id in set(self.seen) - active:
            del self.seen[job_id]
        return actions

    def messages(self) -> bytes:
        """Every task message in the broker now, as one blob to look job ids up in: the queues
        (their priority lists included) and the unacknowledged ones of live workers (a task's
        header names its job: ``argsrepr``)."""
        redis_ = self.store.redis
        keys = [key for queue in self.queue_names() for key in self.queue_keys(queue)]
        with redis_.pipeline(transaction=False) as pipe:
            for key in keys:
                pipe.lrange(key, 0, -1)
            pipe.hvals(liveness.unacked_keys(self.store.prefix)[0])
            found = pipe.execute()
        return b"\0".join(item for batch in found for item in batch)

    def queue_keys(self, queue: str) -> list[str]:
        """kombu's Redis lists of a queue: the queue's, and one per priority step."""
        base = self.store.key(queue)
        return [base, *(f"{base}\x06\x16{priority}" for priority in (3, 6, 9))]

    def queue_names(self) -> list[str]:
        """The control queue and every solver queue, with its users' queues."""
        solvers = fair.with_user_queues(self.store.redis, self.store.prefix, solver_queues())
        settings = self.store.settings
        return [settings.control_queue, settings.pricing_queue, *solvers]

    def abandon(self, record: JobRecord) -> str:
        """A queued job whose start the API never sent (its submit failed after the record
        was written, and its removal failed too: a full disk): fail it, never start it, so
        the client's retry of the submit is the job's only run."""
        log.warning("job %s: its submit did not complete (start never sent); failing it", record.id)
        self.store.fail(
            record.id,
            "the submit of this job did not complete (the service could not queue it, e.g. "
            "its storage was full) and it was not run; submit it again",
        )
        return "abandoned"

    def start_again(self, record: JobRecord) -> str:
        """A queued (or pricing) job whose start (or pricing) task is nowhere (the API died
        before it was sent, or it was lost with Redis): send it again (both are idempotent)."""
        pricing = record.state is JobState.PRICING
        log.warning(
            "job %s: %s but its first task is nowhere; sending it again", record.id,
            record.state.value,
        )  # fmt: skip
        send_first_task(self.celery, self.store.settings, record.id, pricing=pricing)
        self.telemetry.resent(1)
        return "priced again" if pricing else "started"

    def recover(self, record: JobRecord, attempt: int, lost: bool = False) -> str:
        settings = self.store.settings
        solver = record.config.solver
        if not lost:
            consumed = self.consumed_queues()
            queue = solver_queue(solver)
            if consumed is not None and queue in consumed and self.queue_length(queue) > 0:
                return "waiting"  # its tasks may be behind others in a busy queue: not stalled
        if attempt > settings.watchdog_max_resends:
            reason = (
                f"no progress for {self.stall:g} s even after {attempt - 1} re-sends of its "
                f"unsolved work; {self.queue_hint(record.config.solver)} Resubmit the job"
            )
            self.store.fail(record.id, reason)
            log.warning("job %s: failed by the watchdog: %s", record.id, reason)
            return "failed"
        index = record.level - 1
        resumable = (
            record.level > 0
            and len(record.levels) == index
            and self.store.has_level(record.id, index)
        )
        return self.resend(record, index) if resumable else self.restart(record)

    def resend(self, record: JobRecord, index: int) -> str:
        """Re-send the level's unsolved bundles (with a fan-in), or just the fan-in."""
        settings = self.store.settings
        config = record.config
        inputs, _ = self.store.load_level(record.id, index)
        if not is_planned(inputs):  # its plan task (solver queue) was lost
            if self.planning(record.id, index):
                return "in-flight"
            log.warning("job %s: re-sending the plan of level %d", record.id, index + 1)
            orchestration.send_plan(self.celery, settings, record.id, index, config.solver)
            self.telemetry.resent(1)
            return "resent"
        solved = self.store.solved_rows(record.id, index)
        expected = [bundle.as_list() for bundle in inference_for(config).planned(inputs, config)]
        missing = [b for b in expected if bundle_key(b) not in solved]
        busy = self.in_flight(record.id, index)
        if busy is not None and missing and all(bundle_key(b) in busy for b in missing):
            return "in-flight"  # live workers are solving them: slow, not stalled
        missing = [b for b in missing if busy is None or bundle_key(b) not in busy]
        if not missing:
            log.warning(
                "job %s: level %d solved but not assembled; re-sending its fan-in",
                record.id,
                index + 1,
            )
            self.celery.send_task(
                LEVEL_DONE, args=([], record.id, index), queue=settings.control_queue
            )
            self.telemetry.resent(1)
            return "fan-in"
        chunks = group_bundles(missing, config, rows_per_task(settings, config.solver))
        log.warning(
            "job %s: no progress for %g s; re-sending %d unsolved bundles of level %d",
            record.id, self.stall, len(missing), index + 1,
        )  # fmt: skip
        orchestration.fan_out(self.celery, self.store, record, index, chunks)
        self.telemetry.resent(len(chunks))
        return "resent"

    def restart(self, record: JobRecord) -> str:
        """Start the job again from its uploads (nothing of the stalled level can be resumed)."""
        if not self.store.apply(record.id, JobRecord.restarted, utc_now(), record.level).changed:
            return "none"
        for key in self.store.redis.scan_iter(match=self.store.key("job", record.id, "level", "*")):
            self.store.redis.delete(key)
        self.store.redis.delete(self.store.key("job", record.id, "chunks"))
        log.warning(
            "job %s: no progress for %g s at level %d; restarting it",
            record.id,
            self.stall,
            record.level,
        )
        self.celery.send_task(START_JOB, args=(record.id,), queue=self.store.settings.control_queue)
        self.telemetry.resent(1)
        return "restarted"

    def in_flight(self, job_id: str, index: int) -> set[str] | None:
        """``bundle_key`` of the level's bundles that live workers are solving or hold (None
        when the workers cannot be asked)."""
        try:
            inspect = self.celery.control.inspect(timeout=self.store.settings.inspect_timeout)
            replies = [inspect.active() or {}, inspect.reserved() or {}]
        except Exception as error:
            log.warning("watchdog: cannot ask the workers what they run: %s", error)
            return None
        rows: set[str] = set()
        for reply in replies:
            for tasks in reply.values():
                for task in tasks:
                    args = task.get("args") or []
                    if task.get("name") == SOLVE_BUNDLES and args[:2] == [job_id, index]:
                        rows.update(bundle_key(spec) for spec in args[2])
        return rows

    def planning(self, job_id: str, index: int) -> bool:
        """Whether a live worker is planning (or holds the plan task of) the job's level."""
        try:
            inspect = self.celery.control.inspect(timeout=self.store.settings.inspect_timeout)
            replies = [inspect.active() or {}, inspect.reserved() or {}]
        except Exception as error:
            log.warning("watchdog: cannot ask the workers what they run: %s", error)
            return True  # unknown: leave it alone this time
        return any(
            task.get("name") == PLAN_LEVEL and (task.get("args") or [])[:2] == [job_id, index]
            for reply in replies
            for tasks in reply.values()
            for task in tasks
        )

    def consumed_queues(self) -> set[str] | None:
        """Queues some live worker consumes (None when the workers cannot be asked)."""
        try:
            inspect = self.celery.control.inspect(timeout=self.store.settings.inspect_timeout)
            replies = inspect.active_queues() or {}
        except Exception:
            return None
        return {queue["name"] for queues in replies.values() for queue in queues}

    def queue_length(self, queue: str) -> int:
        """Messages waiting in a solver's queue and its users' queues (kombu's Redis lists:
        each queue's, and its priorities')."""
        names = fair.with_user_queues(self.store.redis, self.store.prefix, [queue])
        keys = [key for name in names for key in self.queue_keys(name)]
        with self.store.redis.pipeline() as pipe:
            for key in keys:
                pipe.llen(key)
            return sum(pipe.execute())

    def queue_hint(self, solver: str) -> str:
        """Whether any worker consumes the solver's queue (the usual cause of a stall)."""
        consumed = self.consumed_queues()
        if consumed is not None and solver not in consumed:
            return f"no worker consumes the {solver!r} queue."
        return ""

    @property
    def estimates(self) -> estimates.EstimateStore:
        return estimates.EstimateStore(self.store.redis, self.store.settings)

    def run(self, stop: threading.Event) -> None:
        """Every :attr:`period` until ``stop``: put back what dead workers held, look at the
        jobs, and stop the estimates their clients abandoned; errors (Redis down) are logged
        and the next round tries again."""
        while not stop.wait(self.period):
            try:
                if self.leader():
                    restored = liveness.restore_orphans(
                        self.celery, self.store.redis, self.store.settings
                    )
                    if restored:
                        self.telemetry.resent(restored)
                    self.tick()
                    estimates.sweep_abandoned(self.celery, self.estimates)
            except redis.RedisError as error:
                log.warning("watchdog: Redis unavailable (%s); trying again", error)
            except Exception:
                log.exception("watchdog tick failed")


def start_thread(celery: Celery, store: JobStore, name: str) -> threading.Event:
    """Run a watchdog in a daemon thread; set the returned event to stop it."""
    stop = threading.Event()
    watchdog = Watchdog(celery, store, name)
    threading.Thread(target=watchdog.run, args=(stop,), name="qhsm-watchdog", daemon=True).start()
    log.info("watchdog started (stall %g s)", watchdog.stall)
    return stop
