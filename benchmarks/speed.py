"""Speed (issue 18): ``qhsm match`` against an OpenCV StereoSGBM script, and the service against
the CLI, whole processes, on this machine.

    python benchmarks/speed.py              # every pair, median of 3 (~15 min on 2 cores)
    python benchmarks/speed.py --quick      # Tsukuba and Aloe, one run each, service once
    python benchmarks/speed.py --pairs tsukuba,aloe --repeats 5 --no-service
    python benchmarks/speed.py --no-service --before /tmp/main-copy  # also an older checkout

Pairs (the range is given, as a user who knows it would):

* ``tsukuba``: Middlebury 2001 Tsukuba, 384x288 (0.11 MP), 16 px.
* ``aloe``: Middlebury 2006 Aloe, half size, 641x555 (0.36 MP), 106 px (its ground truth reaches
  105.5 px at that size: stored value / 2).
* ``art-x3``: Middlebury 2005 Art. Only the third-size views are here (463x370, ground truth up to
  74.7 px), so this is them upsampled x3 with ``cv2.resize(INTER_CUBIC)``: 1389x1110 (1.54 MP),
  225 px. Smoother than the real full-size views; a stand-in for a 1.5 MP / 225 px pair.
* ``synthetic-2000``: ``shared.synthetic.make_scene(2000, 2000, max_disparity=256, seed=0)``
  (4 MP, 256 px; ``--large-range`` another range), run ``--large-repeats`` times (default once)
  with its peak RSS.

``--before CHECKOUT`` also runs ``qhsm match`` from another checkout of the repository (its
``shared`` first on PYTHONPATH; this file's checkout likewise for the current code) in the same
alternation, and reports its median, its peak RSS and before / now.

Each repeat runs ``qhsm match LEFT RIGHT -o OUT --max-disparity D`` (the defaults otherwise; the
``qhsm`` script beside this interpreter, as the SGBM script runs this interpreter: not a version
manager's shim that comes first on the PATH) and the SGBM script, alternating which goes first,
each as a fresh process under ``/usr/bin/time -v`` (wall time, peak RSS). The SGBM script is the
baseline of ``shared.baselines`` (its ``SGBM_PARAMETERS``: colour, 5x5 blocks, P1 = 8*3*25,
P2 = 32*3*25, 8 paths (HH); numDisparities the next multiple of 16 above the range) in a minimal
process: read the views, compute, write the PFM. Ratios are of medians.

The service part starts what ``qhsm serve`` starts (``workers.supervisor.Stack``: a control
worker and a CPU worker, the API in a thread) and times the Tsukuba job from the POST to the
downloaded PFM, alternated with ``qhsm match`` on the same pair. The status is polled as
``qhsm submit --wait`` polls it (``Client.wait``: every 50 ms, then every 10 % of the time waited
so far), or every ``--poll`` seconds. It also reports the CPU seconds each took (the whole process
trees: the CLI's process; the API, Redis and the workers), which the other users of a shared
machine disturb far less than wall time.
Redis: QHSM_REDIS_URL when set, else an embedded one.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from shared.baselines import SGBM_PARAMETERS, sgbm_matcher
from shared.datasets import default_middlebury_dir, load_scene

#: The SGBM script each repeat runs as its own process: argv = left right out parameters(JSON).
SGBM_SCRIPT = """
import json, sys
import cv2
import numpy as np
left, right, out, parameters = sys.argv[1], sys.argv[2], sys.argv[3], json.loads(sys.argv[4])
matcher = cv2.StereoSGBM.create(**parameters)
raw = matcher.compute(cv2.imread(left), cv2.imread(right))
cv2.imwrite(out, raw.astype(np.float32) / 16.0)
"""
TIME = "/usr/bin/time"
#: How the service part polls the job's status (``Client.wait``'s arguments): the default, as
#: ``qhsm submit --wait`` polls; ``--poll 0.02`` polls every 20 ms like benchmarks/service.py.
POLL: dict[str, float] = {}


@dataclass(frozen=True)
class Pair:
    """A pair on disk and the range both methods search."""

    name: str
    left: Path
    right: Path
    max_disparity: int
    note: str

    @property
    def megapixels(self) -> float:
        height, width = cv2.imread(str(self.left), cv2.IMREAD_UNCHANGED).shape[:2]
        return height * width / 1e6


def data_root() -> Path:
    """The folder of the Middlebury datasets (``middlebury``, ``middlebury2005``, ...)."""
    return default_middlebury_dir().parent


def write_pair(folder: Path, name: str, left: np.ndarray, right: np.ndarray) -> tuple[Path, Path]:
    """``left``/``right`` (uint8, or float in [0, 1]) as PNGs in ``folder/name``."""
    where = folder / name
    where.mkdir(parents=True, exist_ok=True)
    paths = []
    for side, image in (("left", left), ("right", right)):
        if image.dtype != np.uint8:
            image = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
        cv2.imwrite(str(where / f"{side}.png"), image)
        paths.append(where / f"{side}.png")
    return paths[0], paths[1]


def make_pairs(folder: Path, names: list[str], large_range: int = 256) -> list[Pair]:
    """The benchmark's pairs (see the module doc), the derived ones written to ``folder``."""
    pairs = []
    for name in names:
        if name == "tsukuba":
            scene = load_scene(default_middlebury_dir() / "tsukuba")
            pairs.append(Pair(name, scene.left, scene.right, 16, "Middlebury 2001"))
        elif name == "aloe":
            where = data_root() / "middlebury2006" / "Aloe"
            pairs.append(
                Pair(name, where / "left.png", where / "right.png", 106, "2006, half size")
            )
        elif name == "art-x3":
            where = data_root() / "middlebury2005" / "Art"
            views = [cv2.imread(str(where / f"{side}.png")) for side in ("left", "right")]
            big = [cv2.resize(v, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC) for v in views]
            left, right = write_pair(folder, name, *big)
            pairs.append(Pair(name, left, right, 225, "2005 third size, upsampled x3 (cubic)"))
        elif name == "synthetic-2000":
            from shared.synthetic import make_scene

            scene = make_scene(2000, 2000, max_disparity=large_range, seed=0)
            left, right = write_pair(folder, name, scene.left, scene.right)
            pairs.append(Pair(name, left, right, large_range, "shared.synthetic, seed 0"))
        else:
            raise SystemExit(f"unknown pair {name!r}")
    return pairs


def timed(command: list[str], checkout: Path | None = None) -> tuple[float, float, float]:
    """Wall seconds, peak RSS (MiB) and CPU seconds (user + system) of ``command`` run to
    completion as its own process (with ``checkout`` first on its PYTHONPATH when given)."""
    wrapped = [TIME, "-v", *command] if Path(TIME).exists() else command
    env = None if checkout is None else {**os.environ, "PYTHONPATH": str(checkout)}
    started = time.perf_counter()
    # run in the checkout: ``python -c`` puts the working directory before the PYTHONPATH
    done = subprocess.run(wrapped, capture_output=True, text=True, env=env, cwd=checkout)
    seconds = time.perf_counter() - started
    if done.returncode:
        raise RuntimeError(f"{command[:3]} failed ({done.returncode}): {done.stderr[-2000:]}")
    peak = re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)
    cpu = re.findall(r"(?:User|System) time \(seconds\): ([\d.]+)", done.stderr)
    return (
        seconds,
        int(peak[1]) / 1024 if peak else float("nan"),
        sum(map(float, cpu)) if cpu else float("nan"),
    )


def installed_qhsm() -> str | None:
    """The ``qhsm`` script of this interpreter's environment (beside ``sys.executable``, as the
    SGBM script runs that interpreter), else the first on the PATH: a version manager's shim
    first on the PATH (pyenv's: a bash script, ~70 ms a start here) is not qhsm's time."""
    beside_python = Path(sys.executable).with_name("qhsm")
    return str(beside_python) if beside_python.exists() else shutil.which("qhsm")


def qhsm_command(pair: Pair, out: Path, on_path: bool = True) -> list[str]:
    """``qhsm match`` on the pair with the defaults and the range given (``on_path`` False: the
    CLI of whatever ``shared`` the PYTHONPATH finds first, not the installed script)."""
    qhsm = installed_qhsm() if on_path else None
    # what the script runs (console; main in checkouts from before it)
    entry = "import shared.cli as c; raise SystemExit(getattr(c, 'console', c.main)())"
    program = [qhsm] if qhsm else [sys.executable, "-c", entry]
    views = [str(pair.left), str(pair.right)]
    return [*program, "match", *views, "-o", str(out), "--max-disparity", str(pair.max_disparity)]


def sgbm_command(pair: Pair, out: Path) -> list[str]:
    """The SGBM script on the pair (the parameters of ``shared.baselines``)."""
    parameters = {
        **SGBM_PARAMETERS,
        "minDisparity": 0,
        "numDisparities": sgbm_matcher(pair.max_disparity).getNumDisparities(),
    }
    left, right = str(pair.left), str(pair.right)
    return [sys.executable, "-c", SGBM_SCRIPT, left, right, str(out), json.dumps(parameters)]


def compare(pair: Pair, folder: Path, repeats: int, before: Path | None = None) -> dict:
    """Alternated runs of both methods (and of the ``before`` checkout's ``qhsm match``) on
    ``pair``: medians, ratio, peak RSS."""
    runs: dict[str, list[tuple[float, float, float]]] = {"qhsm": [], "sgbm": []}
    commands = {
        "qhsm": qhsm_command(pair, folder / f"{pair.name}-qhsm.pfm"),
        "sgbm": sgbm_command(pair, folder / f"{pair.name}-sgbm.pfm"),
    }
    checkouts: dict[str, Path | None] = {"qhsm": None, "sgbm": None}
    if before is not None:
        runs["before"] = []
        commands["qhsm"] = qhsm_command(pair, folder / f"{pair.name}-qhsm.pfm", on_path=False)
        commands["before"] = qhsm_command(pair, folder / f"{pair.name}-before.pfm", False)
        checkouts.update(qhsm=Path(__file__).resolve().parents[1], before=before)
    methods = list(runs)
    for repeat in range(repeats):
        order = methods if repeat % 2 == 0 else methods[::-1]
        for method in order:
            runs[method].append(timed(commands[method], checkouts[method]))
            seconds, peak, cpu = runs[method][-1]
            print(
                f"{pair.name} {method}: {seconds:.2f} s, {cpu:.2f} s CPU, {peak:.0f} MiB",
                file=sys.stderr,
            )
    qhsm = statistics.median(s for s, _, _ in runs["qhsm"])
    sgbm = statistics.median(s for s, _, _ in runs["sgbm"])
    earlier = {}
    if before is not None:
        before_s = statistics.median(s for s, _, _ in runs["before"])
        before_cpu = statistics.median(c for _, _, c in runs["before"])
        qhsm_cpu = statistics.median(c for _, _, c in runs["qhsm"])
        earlier = {
            "before_s": round(before_s, 2),
            "before_over_now": round(before_s / qhsm, 2),
            "before_cpu_s": round(before_cpu, 2),
            "qhsm_cpu_s": round(qhsm_cpu, 2),
            "before_over_now_cpu": round(before_cpu / qhsm_cpu, 2),
            "before_peak_rss_mib": round(max(p for _, p, _ in runs["before"])),
        }
    return {
        "pair": pair.name,
        "note": pair.note,
        "megapixels": round(pair.megapixels, 2),
        "max_disparity": pair.max_disparity,
        "qhsm_s": round(qhsm, 2),
        "sgbm_s": round(sgbm, 2),
        "ratio": round(qhsm / sgbm, 2),
        "qhsm_peak_rss_mib": round(max(p for _, p, _ in runs["qhsm"])),
        "sgbm_peak_rss_mib": round(max(p for _, p, _ in runs["sgbm"])),
        "repeats": repeats,
        **earlier,
    }


@contextmanager
def served(folder: Path):
    """What ``qhsm serve`` runs (Redis, a control and a CPU worker, the API) and a client."""
    from api.client import Client
    from api.server import ApiThread
    from api.users import UserStore, ensure_local_admin
    from shared.config import get_settings
    from workers.embedded_redis import free_port
    from workers.supervisor import Stack

    settings = get_settings().model_copy(
        update={
            "key_prefix": f"qhsm-speed-{uuid.uuid4().hex[:8]}",
            "data_dir": folder / "data",
            "api_port": free_port(),
        }
    )
    stack = Stack(settings, supervise=False).start()
    api = None
    try:
        api = ApiThread(stack.settings).start()
        key, _ = ensure_local_admin(UserStore.from_settings(stack.settings), settings.data_dir)
        client = Client(api.url, key=key)
        try:
            yield client
        finally:
            client.close()
    finally:
        if api:
            api.stop()
        stack.stop()


def service_job(client, pair: Pair) -> Callable[[], float]:
    """A function timing one job on ``pair`` from the POST to the downloaded PFM."""
    raw = pair.left.read_bytes(), pair.right.read_bytes()
    names = (pair.left.name, pair.right.name)
    params = {"max_disparity": pair.max_disparity}

    def run() -> float:
        started = time.perf_counter()
        job = client.submit(*raw, params, names=names)
        status = client.wait(job["id"], **POLL)
        if status["state"] != "succeeded":
            raise RuntimeError(f"service job {status['state']}: {status.get('error')}")
        client.disparity(job["id"], "pfm")
        return time.perf_counter() - started

    return run


def tree_cpu() -> float:
    """CPU seconds used so far by this process and every process it started (the API runs in
    a thread here; Redis and the workers are children)."""
    import psutil

    total = 0.0
    me = psutil.Process()
    for process in [me, *me.children(recursive=True)]:
        try:
            times = process.cpu_times()
        except psutil.Error:  # ended meanwhile
            continue
        total += times.user + times.system
    return total


def children_cpu() -> float:
    """CPU seconds of this process's children that have ended (a finished ``qhsm match``)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def compare_service(pair: Pair, folder: Path, repeats: int) -> dict:
    """The service's end-to-end job time against ``qhsm match``, alternated, medians; and the
    CPU seconds each took (whole process trees: far less sensitive to other load than wall)."""
    command = qhsm_command(pair, folder / "service-cli.pfm")
    times: dict[str, list[float]] = {"cli": [], "service": [], "cli_cpu": [], "service_cpu": []}

    def run_cli() -> None:
        before = children_cpu()
        times["cli"].append(timed(command)[0])
        times["cli_cpu"].append(children_cpu() - before)

    with served(folder / "service") as client:
        job = service_job(client, pair)
        job()  # the workers' first job imports the solvers

        def run_service() -> None:
            before = tree_cpu()
            times["service"].append(job())
            times["service_cpu"].append(tree_cpu() - before)

        for repeat in range(repeats):
            for run in (run_service, run_cli) if repeat % 2 else (run_cli, run_service):
                run()
            service, cli = times["service"][-1], times["cli"][-1]
            print(f"service {service:.2f} s, cli {cli:.2f} s", file=sys.stderr)
    median = {name: statistics.median(values) for name, values in times.items()}
    return {
        "pair": pair.name,
        "qhsm_match_s": round(median["cli"], 2),
        "service_s": round(median["service"], 2),
        "service_over_cli": round(median["service"] / median["cli"], 2),
        "qhsm_match_cpu_s": round(median["cli_cpu"], 2),
        "service_cpu_s": round(median["service_cpu"], 2),
        "repeats": repeats,
    }


def table(rows: list[dict]) -> str:
    """The pairs as a Markdown table (docs/benchmarks.md)."""
    lines = [
        "| pair | size, range | `qhsm match` | SGBM script | ratio | peak RSS (qhsm) |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['pair']} ({row['note']}) | {row['megapixels']} MP, {row['max_disparity']} px "
            f"| {row['qhsm_s']} s | {row['sgbm_s']} s | {row['ratio']}x "
            f"| {row['qhsm_peak_rss_mib']} MiB |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", default="tsukuba,aloe,art-x3,synthetic-2000")
    parser.add_argument("--repeats", type=int, default=3, help="runs per pair (median)")
    parser.add_argument("--large-repeats", type=int, default=1, help="runs of synthetic-2000")
    parser.add_argument("--large-range", type=int, default=256, help="synthetic-2000's range")
    parser.add_argument(
        "--before", type=Path, help="another checkout whose qhsm match runs alternated too"
    )
    parser.add_argument("--service-repeats", type=int, default=3)
    parser.add_argument("--no-service", action="store_true", help="skip the service part")
    parser.add_argument("--poll", type=float, help="poll the job every POLL s (default: as qhsm)")
    parser.add_argument("--quick", action="store_true", help="Tsukuba and Aloe once; service once")
    args = parser.parse_args(argv)
    names = args.pairs.split(",")
    if args.poll:
        POLL.update(interval=args.poll, max_interval=args.poll)
    if args.quick:
        names = [n for n in names if n in ("tsukuba", "aloe")]
        args.repeats = args.large_repeats = args.service_repeats = 1
    results: dict = {"load_average_1min_at_start": round(os.getloadavg()[0], 2), "pairs": []}
    with tempfile.TemporaryDirectory(prefix="qhsm-speed-") as tmp:
        folder = Path(tmp)
        pairs = make_pairs(folder, names, args.large_range)
        for pair in pairs:
            repeats = args.large_repeats if pair.name == "synthetic-2000" else args.repeats
            results["pairs"].append(compare(pair, folder, repeats, args.before))
            print(json.dumps(results["pairs"][-1]), flush=True)
        if not args.no_service:
            tsukuba = make_pairs(folder, ["tsukuba"])[0]
            results["service"] = compare_service(tsukuba, folder, args.service_repeats)
            print(json.dumps({"service": results["service"]}), flush=True)
    results["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    print(table(results["pairs"]))
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
