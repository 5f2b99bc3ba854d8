"""Service commands of ``qhsm`` (plugged in through the ``qhsm.commands`` entry point):

qhsm serve    API + workers for every solver that runs here (+ an embedded Redis)
qhsm demo     the same, then one job end to end on a sample scene, then stop
qhsm api      the API alone
qhsm worker   one worker of a running service, on any host (``workers/cli.py``)
qhsm embeddings warm   the QPU tile shapes embedded ahead of time (``workers/embeddings_cli.py``)
qhsm submit   the client: upload a pair, show progress, download the disparity map
qhsm wait     follow a submitted job (again) and download its result
qhsm cancel   cancel a submitted job
qhsm estimate a job's estimated QPU (or hybrid) seconds, without running it
qhsm submit-batch  a folder of pairs as one batch (``api/batch_cli.py``)
qhsm usage    your QPU budget in its period, and what your jobs were charged

One function per command and its parser; they share the settings options and the client. The
commands that start the service (serve, demo, api) are in :mod:`api.serve_cli`, the worker in
:mod:`workers.cli`, user administration in :mod:`api.admin`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from api import batch_cli
from api.cli_client import KEY_OPTION, api_client
from api.serve_cli import cmd_api, cmd_demo, cmd_serve
from shared.cli_options import (
    CommandError,
    add_calib_option,
    add_json_option,
    add_match_options,
    add_pair_arguments,
    config_from_args,
    match_params,
    model_option,
    setting_option,
    settings_from_args,
)
from shared.config import MatchConfig
from shared.exit_codes import interrupted
from workers import cli as worker_cli
from workers import embeddings_cli

if TYPE_CHECKING:
    pass


def register(commands: argparse._SubParsersAction) -> None:
    serve = commands.add_parser("serve", help="run the API and workers (embedded Redis if unset)")
    _stack_options(serve)
    _log_level_option(serve)
    serve.set_defaults(handler=cmd_serve)

    demo = commands.add_parser("demo", help="start the service, run one demo job, stop")
    _stack_options(demo, port_help="API port (default: a free port, printed at start)")
    model_option(demo, MatchConfig, "solver", with_default=True, help="solver of the demo job")
    demo.add_argument(
        "--scene",
        choices=["auto", "tsukuba", "synthetic"],
        default="auto",
        help="auto: Middlebury Tsukuba when present, else a synthetic scene",
    )
    demo.add_argument("--keep-running", action="store_true", help="keep serving after the job")
    demo.set_defaults(handler=cmd_demo)

    api = commands.add_parser("api", help="run the HTTP API only (uvicorn)")
    setting_option(api, "api_host", "--host")
    setting_option(api, "api_port", "--port")
    _log_level_option(api)
    api.set_defaults(handler=cmd_api)

    submit = commands.add_parser("submit", help="send a stereo pair to a running service")
    add_pair_arguments(submit)
    add_match_options(submit)
    submit.add_argument("--label", help="your name for the job, shown in job lists")
    submit.add_argument(
        "--tag", action="append", help="a tag for the job (repeatable); GET /v1/jobs?tag= lists"
    )
    add_calib_option(submit, "the job then serves depth and PLY")
    submit.add_argument("--ground-truth", help="left ground truth, to get RMSE and BPP back")
    submit.add_argument(
        "--gt-scale",
        type=float,
        help="stored value per pixel of disparity (default: inferred from the views, with a "
        "warning; refused when they do not tell)",
    )
    submit.add_argument(
        "--gt-border", type=int, help="ignored frame, pixels (default: the service's)"
    )
    submit.add_argument(
        "--wait",
        action="store_true",
        help="show progress (stderr), then download to -o, else to JOB_ID.pfm here",
    )
    _result_options(submit, "implies --wait")
    _client_options(submit)
    submit.set_defaults(handler=cmd_submit)

    batch_cli.register(commands, _client_options)

    wait = commands.add_parser(
        "wait", help="follow a submitted job (progress on stderr) and download its result"
    )
    wait.add_argument("job", help="the job's id (what `qhsm submit` printed)")
    _result_options(wait, "default: JOB_ID.pfm here")
    _client_options(wait)
    wait.set_defaults(handler=cmd_wait)

    cancel = commands.add_parser("cancel", help="cancel a submitted job")
    cancel.add_argument("job", help="the job's id (what `qhsm submit` printed)")
    add_json_option(cancel, "the cancelled job's status")
    _client_options(cancel, json=False)
    cancel.set_defaults(handler=cmd_cancel)

    estimate = commands.add_parser(
        "estimate", help="print a job's estimated QPU (or hybrid) seconds without running it"
    )
    add_pair_arguments(estimate)
    add_match_options(estimate)
    _client_options(estimate, json=False)
    estimate.add_argument(
        "--local",
        action="store_true",
        help="estimate in this process, without a service (embeddings known to this machine's "
        "cache in QHSM_DATA_DIR; no budget check)",
    )
    add_json_option(estimate, "the estimate")
    estimate.set_defaults(handler=cmd_estimate)

    worker_cli.register(commands)
    embeddings_cli.register(commands)


def _result_options(parser: argparse.ArgumentParser, output_default: str) -> None:
    parser.add_argument("-o", "--output", help=f"OUT.pfm, .png or .npy ({output_default})")
    parser.add_argument("--preview", help="also download a colour preview PNG here")


def _client_options(parser: argparse.ArgumentParser, json: bool = True) -> None:
    """--url, --key (and --json) of the commands that talk to a running service."""
    setting_option(parser, "api_url", "--url")
    if json:
        parser.add_argument(
            "--json",
            action="store_true",
            help="print the job (or, waiting, its final status) as JSON on stdout; progress "
            "still goes to stderr",
        )
    parser.add_argument(
        "--key", help="API key (QHSM_API_KEY; default: the local admin key of `qhsm serve`)"
    )


def _log_level_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--log-level",
        choices=["debug", "info", "warning", "error"],
        default="info",
        help="API log level; debug also shows every poll of a job's status and health check",
    )


def _stack_options(parser: argparse.ArgumentParser, port_help: str | None = None) -> None:
    """Options of serve and demo; the defaults shown are the settings' (environment included)."""
    setting_option(parser, "api_host", "--host")
    if port_help:  # demo: not the settings' port
        parser.add_argument("--port", dest="api_port", type=int, metavar="PORT", help=port_help)
    else:
        setting_option(parser, "api_port", "--port")
    setting_option(parser, "data_dir")
    setting_option(parser, "worker_concurrency", "--concurrency")


# --- submit ----------------------------------------------------------------------------------


def _existing(paths: list[str]) -> list[Path]:
    """The command's input files, refused with a message when one is missing."""
    files = [Path(path) for path in paths]
    for path in files:
        if not path.is_file():
            raise CommandError(f"{path}: no such file")
    return files


def cmd_submit(args: argparse.Namespace) -> int:
    config_from_args(args)  # refuse bad options before uploading anything
    params = match_params(args)
    url = settings_from_args(args).api_url
    files = _existing([args.left, args.right] + ([args.ground_truth] if args.ground_truth else []))
    calib = _existing([args.calib])[0].read_bytes() if args.calib else None
    with api_client(args, key_source=KEY_OPTION) as client:
        job = client.submit(
            files[0].read_bytes(),
            files[1].read_bytes(),
            params,
            ground_truth=files[2].read_bytes() if args.ground_truth else None,
            gt_scale=args.gt_scale,
            gt_border=args.gt_border,
            names=(files[0].name, files[1].name),
            label=args.label,
            tags=args.tag,
            calib=calib,
        )
        shown: set[str] = set()
        _print_warnings(job, shown)
        if not (args.wait or args.output):
            # the views are checked when the job starts: wait a moment for that check's warning
            _print_warnings(client.started(job["id"]), shown)
            if args.json:
                print(json.dumps({**job, "url": f"{url.rstrip('/')}{job['links']['self']}"}))
            else:
                print(f"{job['id']} {job['state']}  {url.rstrip('/')}{job['links']['self']}")
            print(f"follow it: {_job_commands(job['id'], args)}", file=sys.stderr)
            return 0
        print(f"job {job['id']} {job['state']}", file=sys.stderr)
        return _follow(client, job["id"], args, shown)


def cmd_wait(args: argparse.Namespace) -> int:
    """``qhsm wait JOB``: the progress of a job submitted earlier, then its result."""
    with api_client(args, key_source=KEY_OPTION) as client:
        shown: set[str] = set()
        _print_warnings(client.status(args.job), shown)
        return _follow(client, args.job, args, shown)


def cmd_cancel(args: argparse.Namespace) -> int:
    """``qhsm cancel JOB``: stop a queued or running job (its running tasks are killed)."""
    with api_client(args, key_source=KEY_OPTION) as client:
        status = client.cancel(args.job)
    if args.json:
        print(json.dumps(status, indent=2))
    else:
        print(f"job {args.job} {status['state']}")
    return 0


def _print_warnings(job: dict, shown: set[str]) -> None:
    """A job's warnings (views that look swapped, an inferred scale) not in ``shown`` yet, one
    line each on stderr (the views' check adds its warning when the job starts)."""
    for warning in job.get("warnings", []):
        if warning not in shown:
            shown.add(warning)
            print(f"qhsm: warning: {warning}", file=sys.stderr)


def _job_commands(job_id: str, args: argparse.Namespace) -> str:
    """``qhsm wait X`` / ``qhsm cancel X``, with the --url given (the key is not repeated)."""
    url = f" --url {args.api_url}" if getattr(args, "api_url", None) else ""
    return f"`qhsm wait {job_id}{url}` (progress, then the result), `qhsm cancel {job_id}{url}`"


def _follow(client, job_id: str, args: argparse.Namespace, shown: set[str]) -> int:
    """Show the job's progress until it ends, then download its result; Ctrl-C leaves it
    running on the service and says how to cancel it or follow it again."""
    from api.client import progress_bar, scores_text, write_result

    status: dict | None = None
    seen: dict = {}  # the last status polled
    bar = progress_bar()  # stderr, in every mode

    def show(polled: dict) -> None:
        seen.update(polled)
        _print_warnings(polled, shown)
        bar(polled)

    try:
        status = client.wait(job_id, on_progress=show)
        if status["state"] != "succeeded":
            raise CommandError(f"job {job_id} {status['state']}: {status['error']}")
        output = Path(args.output or f"{job_id}.pfm").resolve()
        write_result(client, job_id, output)
        if args.preview:
            Path(args.preview).write_bytes(client.preview(job_id))
    except KeyboardInterrupt:
        bar.close()
        if status is not None:  # it ended; interrupted while downloading
            print(
                f"qhsm: interrupted; job {job_id} {status['state']}: `qhsm wait {job_id}` "
                "downloads its result",
                file=sys.stderr,
            )
        else:
            metered = seen.get("qpu_seconds") is not None
            charged = " (and its QPU time is charged)" if metered else ""
            print(
                f"qhsm: interrupted; job {job_id} is still {seen.get('state', 'queued')} on the "
                f"service{charged}: {_job_commands(job_id, args)}",
                file=sys.stderr,
            )
        return interrupted()
    scores = f"; {scores_text(status)}" if status.get("metrics") else ""
    where = "" if args.output else " (no -o given: named after the job, in this directory)"
    line = f"wrote {output}{where}{scores}"
    if args.json:
        print(line, file=sys.stderr)
        print(json.dumps({"output": str(output), **status}, indent=2))
    else:
        print(line)
    return 0


# --- estimate --------------------------------------------------------------------------------


def cmd_estimate(args: argparse.Namespace) -> int:
    """The service's estimate (the one its 403 uses), or with ``--local`` this process's."""
    config = config_from_args(args)
    files = _existing([args.left, args.right])
    if args.local:
        from shared.cli import local_estimate

        result = local_estimate(config, files[0], files[1])
    else:
        params = match_params(args)
        with api_client(args, hint=" (or use --local)") as client:
            result = client.estimate(
                files[0].read_bytes(),
                files[1].read_bytes(),
                params,
                names=(files[0].name, files[1].name),
            )
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_estimate(result))
    return 0


def format_estimate(result: dict) -> str:
    """The estimate as a few lines of text: the total, then one line per level."""
    solver = result["solver"]
    if not result["metered"]:
        line = f"{solver}: not metered (no QPU or hybrid time is charged)"
        return "\n".join([line, *memory_lines(result)])
    kind = "QPU access" if result["levels"][0]["qubits_per_bundle"] is not None else "hybrid"
    sent = result.get("bundles_sent", result["bundles"])
    lines = [
        f"{solver}: {result['seconds']:.2f} s of {kind} time estimated "
        f"({result['bundles']} bundles, {len(result['levels'])} levels, "
        f"max disparity {result['max_disparity']}); "
        f"{1 - sent / max(result['bundles'], 1):.0%} of the bundles solved classically "
        "(the host's settling, roof duality), the rest sent"
    ]
    for level in result["levels"]:
        qubits = ""  # none for a level that sends nothing (every bundle solved on the host)
        if level["qubits_per_bundle"] is not None and level.get("bundles_sent", 1):
            source = "embedding" if level["embedding_known"] else "assumed"
            qubits = f", {level['qubits_per_bundle']} qubits ({source})"
        settled = ""
        if level.get("pixels_certified") is not None:
            settled = (
                f", {level['pixels_certified']} pixels certified on the host, "
                f"{level['pixels_sent']} in the tiles sent"
            )
        lines.append(
            f"  level {level['index']}: {level['height']}x{level['width']}, "
            f"{level['bundles']} bundles of {level['variables_per_bundle']} variables, "
            f"{level.get('bundles_sent', level['bundles'])} sent with "
            f"{level.get('variables_share', 1.0):.0%} of the variables{qubits}{settled}: "
            f"{level['seconds']:.2f} s"
        )
    if "fits" in result:
        remaining = result["remaining_seconds"]
        left = "unlimited" if remaining is None else f"{remaining:.2f} s"
        verdict = "fits" if result["fits"] else "does NOT fit: submitting it would be refused (403)"
        lines.append(f"your budget: {left} remaining; this job {verdict}")
    return "\n".join(lines + memory_lines(result))


def memory_lines(result: dict) -> list[str]:
    """The job's estimated peak memory against a worker's budget (the service's estimate)."""
    if result.get("memory_mb") is None:
        return []
    budget = result.get("memory_budget_mb")
    room = "no limit" if budget is None else f"a worker's budget {budget} MiB"
    over = budget is not None and result["memory_mb"] > budget
    refused = "; submitting it would be refused (413)" if over else ""
    return [f"memory: about {result['memory_mb']} MiB at its peak ({room}){refused}"]
