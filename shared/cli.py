"""The ``qhsm`` command. Core commands live here (``match``, ``eval``, ``solvers``); the service
adds its own (``serve``, ``submit``, ...) through the ``qhsm.commands`` entry-point group, so the
core package never imports the service."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from importlib.metadata import entry_points
from pathlib import Path

from shared.config import Encoding, MatchConfig, Rectifier, Regularizer

EXIT_USAGE = 2
EXIT_FAILED = 1


class CommandError(Exception):
    """A user-facing failure: printed as ``qhsm: <message>`` with exit status 1."""


def add_match_options(parser: argparse.ArgumentParser) -> None:
    """Options that map onto ``MatchConfig`` (shared with ``qhsm submit``)."""
    parser.add_argument("--solver", default="exact", help="solver name (see `qhsm solvers`)")
    parser.add_argument("--max-disparity", type=int, default=20, help="full-resolution pixels")
    parser.add_argument("--bundle-height", type=int, default=1, help="rows per QUBO bundle")
    parser.add_argument(
        "--regularizer", choices=[r.value for r in Regularizer], default=Regularizer.TRUNCATED.value
    )
    parser.add_argument(
        "--encoding", choices=[e.value for e in Encoding], default=Encoding.ONE_HOT.value
    )
    parser.add_argument(
        "--rectifier", choices=[r.value for r in Rectifier], default=Rectifier.LOCAL.value
    )
    parser.add_argument("--no-median", action="store_true", help="skip the per-level median")
    parser.add_argument("--no-bilateral", action="store_true", help="skip the final bilateral")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="solver parameter, e.g. --param num_reads=50 (JSON values)",
    )


def _parse_param(text: str) -> tuple[str, object]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise CommandError(f"--param expects KEY=VALUE, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def config_from_args(args: argparse.Namespace) -> MatchConfig:
    from pydantic import ValidationError

    try:
        return MatchConfig(
            solver=args.solver,
            max_disparity=args.max_disparity,
            bundle_height=args.bundle_height,
            regularizer=args.regularizer,
            encoding=args.encoding,
            rectifier=args.rectifier,
            median=not args.no_median,
            bilateral=not args.no_bilateral,
            seed=args.seed,
            solver_params=dict(_parse_param(p) for p in args.param),
        )
    except ValidationError as error:
        raise CommandError(_validation_message(error)) from None


def _validation_message(error) -> str:
    return "; ".join(
        f"{'.'.join(map(str, e['loc'])) or 'config'}: {e['msg']}" for e in error.errors()
    )


def cmd_match(args: argparse.Namespace) -> int:
    from shared.images import load_pair, preview_png, save_disparity
    from shared.pipeline import run_pipeline
    from shared.solve import ProcessPoolLevelSolver
    from shared.solvers import get_solver

    config = config_from_args(args)
    solver = get_solver(config.solver)
    availability = solver.available()
    if not availability.ok:
        raise CommandError(f"solver {config.solver} is not available: {availability.reason}")
    if Path(args.output).suffix.lower() not in (".pfm", ".png", ".npy"):
        raise CommandError(f"{args.output}: the output must end in .pfm, .png or .npy")
    left, right = load_pair(args.left, args.right)

    def progress(done: int, total: int) -> None:
        if not args.json:
            print(f"level {done}/{total} done", file=sys.stderr)

    with ProcessPoolLevelSolver(args.processes) as solve_level:
        result = run_pipeline(left, right, config, solve_level, progress=progress)
    save_disparity(result.disparity, args.output)
    if args.preview:
        Path(args.preview).write_bytes(preview_png(result.disparity, config.max_disparity))
    if args.json:
        print(
            json.dumps(
                {"output": str(args.output), "solver": config.solver, **result.summary()}, indent=2
            )
        )
    else:
        print(f"wrote {args.output} ({result.seconds:.2f} s)")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from shared.images import load_disparity, load_disparity_values, load_mask
    from shared.metrics import evaluate

    disparity = load_disparity(args.disparity)
    gt = load_disparity_values(args.ground_truth)
    mask = load_mask(args.mask) if args.mask else None
    scores = evaluate(disparity, gt, scale=args.scale, border=args.border, mask=mask)
    print(json.dumps({"rmse": scores.rmse, "bpp": scores.bpp, "pixels": scores.pixels}))
    return 0


def cmd_solvers(args: argparse.Namespace) -> int:
    from shared.solvers import get_solver, solver_names

    rows = []
    for name in solver_names():
        solver = get_solver(name)
        availability = solver.available()
        rows.append(
            {
                "name": name,
                "available": availability.ok,
                "reason": availability.reason,
                "offline": solver.offline,
                "description": solver.description,
            }
        )
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for row in rows:
            mark = "yes" if row["available"] else "no "
            print(f"{row['name']:<18} {mark}  {row['reason']}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="qhsm", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)

    match = commands.add_parser("match", help="match a stereo pair in this process")
    match.add_argument("left")
    match.add_argument("right")
    match.add_argument("-o", "--output", required=True, help="OUT.pfm, OUT.png (x256) or .npy")
    add_match_options(match)
    match.add_argument("--preview", help="write a colour-mapped PNG here")
    match.add_argument("--json", action="store_true", help="print a JSON summary")
    match.add_argument(
        "--processes",
        type=int,
        default=0,
        help="local worker processes for the bundles (0: one per core)",
    )
    match.set_defaults(handler=cmd_match)

    evaluate = commands.add_parser("eval", help="score a disparity map against ground truth")
    evaluate.add_argument("disparity")
    evaluate.add_argument("ground_truth")
    evaluate.add_argument(
        "--scale",
        type=float,
        required=True,
        help="stored ground-truth value per pixel of disparity",
    )
    evaluate.add_argument("--border", type=int, default=0, help="ignored frame, pixels")
    evaluate.add_argument("--mask", help="evaluate only where this mask is non-zero")
    evaluate.set_defaults(handler=cmd_eval)

    solvers = commands.add_parser("solvers", help="list solvers and whether they can run here")
    solvers.add_argument("--json", action="store_true")
    solvers.set_defaults(handler=cmd_solvers)

    for entry in entry_points(group="qhsm.commands"):
        entry.load()(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from shared.images import ImageError
    from shared.solvers import SolverError, UnknownSolver

    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except (
        CommandError,
        ImageError,
        SolverError,
        UnknownSolver,
        ValueError,
        FileNotFoundError,
    ) as error:
        print(f"qhsm: {error}", file=sys.stderr)
        return EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
