"""The ``qhsm`` command. Core commands live here (``match``, ``eval``, ``solvers``); the service
adds its own (``serve``, ``submit``, ...) through the ``qhsm.commands`` entry-point group, so the
core package never imports the service. The options come from the models
(:mod:`shared.cli_options`)."""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from shared.exit_codes import EXIT_BROKEN_PIPE, EXIT_FAILED, interrupted

if TYPE_CHECKING:
    from shared.config import MatchConfig

# Nothing heavy at import time: main() is then in charge from the first instant (a Ctrl-C while
# pydantic or numpy load is one line too), and `qhsm --help` starts fast.


DESCRIPTION = (
    "Quantum-hybrid stereo matching: disparity maps from rectified stereo pairs, in this process "
    "(match, eval, bench) or through the job service (serve, submit, admin). "
    "`qhsm COMMAND --help` shows a command's options."
)
_python_showwarning = warnings.showwarning

#: ``qhsm bench --encoding auto``: each solver's recommended encoding, else the preset's.
AUTO_ENCODING = "auto"


def cmd_match(args: argparse.Namespace) -> int:
    """``qhsm match``: run the pipeline on the pair ``left``, ``right`` in this process and save
    the disparity map to ``output`` (.pfm, .png or .npy), with the ``MatchConfig`` options,
    ``preview``, ``json`` and ``processes``; 0 on success. A solver not available here or an
    unsupported output suffix is a ``CommandError``."""
    from shared import kernel_background, kernels
    from shared.activity import reporting
    from shared.allocator import keep_freed_memory
    from shared.cli_options import CommandError, config_from_args
    from shared.config import Inference
    from shared.images import PNG_MAX_DISPARITY as PNG_MAX
    from shared.images import load_pair, preview_png, save_maps
    from shared.pipeline import run_pipeline
    from shared.process_pool import ProcessPoolLevelSolver
    from shared.progress_bar import LevelBar
    from shared.provenance import provenance
    from shared.solvers.base import Availability
    from shared.solvers.registry import resolve

    config = config_from_args(args)
    keep_freed_memory()  # one pair, then the process ends: freed arrays are reused, not faulted
    if config.inference is Inference.GRID:
        kernels.preload()  # numba's start beside reading the views and the first level's work
    solver = resolve(config)
    solver.bundle_width_setting()  # a width the solver cannot use: say so before any work
    # a row solver (exact) runs here on the CPU: no sampler built for it (that imports dimod)
    availability = Availability(True) if solver.spec.row_solver else solver.sampler.available()
    if not availability.ok:
        raise CommandError(f"solver {config.solver} is not available: {availability.reason}")
    if Path(args.output).suffix.lower() not in (".pfm", ".png", ".npy"):
        raise CommandError(f"{args.output}: the output must end in .pfm, .png or .npy")
    if args.ply and not args.calib:
        raise CommandError("--ply needs --calib (Middlebury calib.txt or a KITTI calibration)")
    top = config.max_disparity
    if Path(args.output).suffix.lower() == ".png" and isinstance(top, int) and top > PNG_MAX:
        raise CommandError(
            f"{args.output}: a 16-bit PNG holds disparities up to {PNG_MAX:.3f} px (x256) and the "
            f"range is {top}; write .pfm or .npy"
        )
    kernel_background.start_if_missing()  # in a terminal, once: the next runs start sooner
    left, right = load_pair(args.left, args.right)
    bar = LevelBar(leave=False)  # stderr, in every mode: with --json stdout is JSON alone
    try:
        with ProcessPoolLevelSolver(args.processes) as solve_level, reporting(bar.show_phase):
            result = run_pipeline(
                left, right, config, solve_level, progress=bar.update, force=args.force
            )
    finally:
        bar.close()
    args.output = save_result(result.disparity, args.output)
    if args.preview:
        top = result.disparity_range.max_disparity
        Path(args.preview).write_bytes(preview_png(result.disparity, top))
    summary = {"output": str(args.output), "solver": config.solver, **result.summary()}
    summary["maps"] = save_maps(
        result.validity, result.confidence, args.output, result.provenance_map
    )
    if args.ply:
        from shared.datasets.calibration import read_calibration
        from shared.depth import ply_bytes, point_cloud

        calibration = read_calibration(args.calib)
        points, colours = point_cloud(result.disparity, calibration, left, result.validity)
        Path(args.ply).write_bytes(ply_bytes(points, colours))
        summary["maps"]["ply"] = str(args.ply)
    summary["provenance"] = provenance(config)
    sidecar = Path(f"{args.output}.json")  # what made the map, beside it
    summary["sidecar"] = str(sidecar)
    sidecar.write_text(json.dumps(summary, indent=2))
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {args.output} ({result.seconds:.2f} s)")
    return 0


def save_result(disparity, output: str) -> str:
    """Save the map to ``output``; a map a 16-bit PNG cannot hold (the range was estimated)
    goes to ``output`` with ``.pfm`` instead, with a warning line, rather than being clipped or
    lost. Returns the path written."""
    from shared.images import DisparityFormatError, save_disparity

    try:
        save_disparity(disparity, output)
    except DisparityFormatError as error:
        output = str(Path(output).with_suffix(".pfm"))
        save_disparity(disparity, output)
        print(f"qhsm: warning: {error}: wrote {output} instead", file=sys.stderr)
    return output


def cmd_build_kernels(args: argparse.Namespace) -> int:
    from shared.kernel_background import build_recording_failure
    from shared.kernels import native_library_path
    from shared.native import LIBRARIES

    print(f"wrote {build_recording_failure()}")
    for name in LIBRARIES:  # the C kernels (their failure is a warning)
        if native_library_path(name).exists():
            print(f"wrote {native_library_path(name)}")
    return 0


def local_estimate(config: MatchConfig, left_path: Path, right_path: Path) -> dict:
    """This process's estimate of a job (``qhsm estimate --local``): the pair's disparity range,
    what the classical steps leave of its bundles and the meters' walk, in the wire form of
    ``POST /v1/estimate``. ``UnknownSolverError`` lists the valid names before any work."""
    from shared.disparity_range import resolve_max_disparity
    from shared.images import load_pair
    from shared.pipeline import match_views
    from shared.residual import job_residual
    from shared.solvers.meters.qpu_time import job_seconds
    from shared.solvers.qpu.embedding_cache import default_cache
    from shared.solvers.registry import resolve

    solver = resolve(config)
    left, right = load_pair(left_path, right_path)
    top = resolve_max_disparity(*match_views(left, right, config), config.max_disparity)
    cache = default_cache()
    residual = job_residual(config, left, right, top.max_disparity, cache)
    estimate = job_seconds(solver, left.shape[:2], top.max_disparity, cache, residual)
    return {**estimate.as_dict(), "max_disparity": top.max_disparity}


def cmd_solvers(args: argparse.Namespace) -> int:
    """``qhsm solvers``: list every registered solver and whether it can run here, as a table
    or (``json``) JSON rows; 0, unavailable solvers being listed, not an error."""
    from shared.solvers.registry import get_solver, solver_names

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


def cmd_bench(args: argparse.Namespace) -> int:
    """``qhsm bench``: run the selected experiments on a dataset folder (the ``bench`` options,
    turned into ``BenchOptions``); 0 once ``results.md`` and ``results.json`` are written under
    ``--out``."""
    from shared.bench import BenchOptions, parse_solver_params, run_bench, split_names

    options = BenchOptions(
        dataset=Path(args.dataset),
        out=Path(args.out),
        scenes=split_names(args.scenes),
        solvers=split_names(args.solvers) or [],
        experiments=split_names(args.experiments) or [],
        ablation_solver=args.ablation_solver,
        url=args.url,
        bundle_height=args.bundle_height,
        encoding=None if args.encoding == AUTO_ENCODING else args.encoding,
        seed=args.seed,
        solver_params=parse_solver_params(args.param),
        processes=args.processes,
        scale=args.scale,
        border=args.border,
        max_disparity=args.max_disparity,
    )
    run_bench(options, command=["qhsm", *sys.argv[1:]], progress=True)
    print(f"wrote {options.out / 'results.md'} and {options.out / 'results.json'}")
    return 0


def cmd_datasets_fetch(args: argparse.Namespace) -> int:
    """``qhsm datasets fetch``: download the Middlebury set ``name`` (optionally some ``scenes``,
    from a ``mirror``) into ``directory``, checking the files' checksums; 0, files without a
    known checksum reported on stderr. A download that cannot connect is a ``CommandError``."""
    from shared.bench import split_names
    from shared.cli_options import CommandError
    from shared.config import get_settings
    from shared.datasets import fetch

    mirror = args.mirror or get_settings().dataset_mirror
    try:
        fetched = fetch(
            args.name,
            args.directory,
            mirror=mirror,
            scenes=split_names(args.scenes),
            progress=lambda f: print(f"{f.status:<10} {f.sha256}  {f.path}"),
        )
    except ConnectionError as error:
        raise CommandError(f"{error} (offline? use --mirror or QHSM_DATASET_MIRROR)") from None
    unverified = sum(f.status == "unverified" for f in fetched)
    if unverified:
        print(
            f"{unverified} file(s) have no known checksum: they are unverified (sha256 printed "
            "above so you can record them)",
            file=sys.stderr,
        )
    return 0


def cmd_datasets_list(args: argparse.Namespace) -> int:
    """``qhsm datasets list``: show the scenes below ``directory`` (a folder of datasets, a dataset
    folder or a scene folder) and their evaluation protocol, as a table or (``json``) JSON; 0."""
    from shared.datasets import find_datasets

    rows = [
        {"name": scene.qualified_name, **scene.protocol()}
        for scenes in find_datasets(args.directory).values()
        for scene in scenes.values()
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for row in rows:
            print(
                f"{row['name']:<26} {row['layout']:<24} scale {row['scale']:g}  border "
                f"{row['border']}  max disparity {row['max_disparity']} "
                f"({row['max_disparity_source']})  "
                f"masks {','.join(row['masks']) or '-'}  non-occluded from "
                f"{row['non_occlusion']}"
            )
    return 0


def _add_match(commands: argparse._SubParsersAction) -> None:
    """Add ``qhsm match`` to the command's sub-parsers."""
    from shared.cli_options import (
        add_calib_option,
        add_json_option,
        add_match_options,
        add_pair_arguments,
        add_processes_option,
    )

    match = commands.add_parser("match", help="match a stereo pair in this process")
    add_pair_arguments(match)
    match.add_argument("-o", "--output", required=True, help="OUT.pfm, OUT.png (x256) or .npy")
    add_match_options(match)
    match.add_argument("--preview", help="write a colour-mapped PNG here")
    match.add_argument(
        "--force",
        action="store_true",
        help="run even when the views look swapped, not rectified or identical (default: stop "
        "with the reason)",
    )
    match.add_argument(
        "--ply", help="also write a coloured point cloud (binary PLY; needs --calib)"
    )
    add_calib_option(match, "the cameras of --ply")
    add_json_option(match, "a summary")
    add_processes_option(match)
    match.set_defaults(handler=cmd_match)


def build_parser(only_match: bool = False) -> argparse.ArgumentParser:
    """``qhsm``'s parser with every command, or with ``match`` alone (``only_match``): the other
    commands' parsers import the service's modules and read the settings for their defaults,
    which a ``qhsm match`` process needs neither of (issue 28, item 3)."""
    from shared.cli_options import (
        Parser,
        add_json_option,
        add_processes_option,
        int_or_auto,
        model_option,
    )
    from shared.config import Encoding, MatchConfig
    from shared.provenance import qhsm_version

    parser = Parser(prog="qhsm", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"qhsm {qhsm_version()}")
    commands = parser.add_subparsers(dest="command", required=True)
    _add_match(commands)
    if only_match:
        return parser

    from shared import cli_results

    cli_results.register(commands)

    kernels = commands.add_parser(
        "build-kernels",
        help="compile the matcher's kernels ahead of time (once after installing, ~15 s: each "
        "qhsm match then starts about a second of CPU sooner; needs a C compiler), and qhsm's "
        "byte code",
    )
    kernels.set_defaults(handler=cmd_build_kernels)

    solvers = commands.add_parser("solvers", help="list solvers and whether they can run here")
    add_json_option(solvers, "the list")
    solvers.set_defaults(handler=cmd_solvers)

    bench = commands.add_parser(
        "bench", help="run the accurate preset's and the paper's experiments on a dataset folder"
    )
    bench.add_argument("dataset", help="folder of scene folders (or one scene folder)")
    bench.add_argument("--scenes", help="comma-separated scene names (default: all found)")
    bench.add_argument(
        "--solvers",
        default="exact,gurobi,sa,hybrid,qpu",
        help="solver comparison: comma-separated registry names (unavailable ones are skipped)",
    )
    bench.add_argument(
        "--experiments",
        default="accurate,solvers,ablations,baselines",
        help="comma-separated subset of accurate (the default preset and its ablations), "
        "solvers and ablations (the paper's tables, preset paper), baselines",
    )
    model_option(
        bench,
        MatchConfig,
        "solver",
        "--ablation-solver",
        with_default=True,
        dest="ablation_solver",
        help="solver of the ablations",
    )
    bench.add_argument("--url", help="run the pipeline through the service at this URL")
    bench.add_argument("--out", default="out/bench", help="output folder")
    model_option(bench, MatchConfig, "bundle_height")
    bench.add_argument(
        "--encoding",
        choices=[AUTO_ENCODING, *(e.value for e in Encoding)],
        default=AUTO_ENCODING,
        help="label encoding of the QUBO solvers; auto: domain-wall for the annealers (sa, tabu, "
        "steepest-descent, qpu, hybrid and their -sim stand-ins), else each run's preset's "
        "(domain-wall for accurate, one-hot for paper)",
    )
    model_option(bench, MatchConfig, "seed", with_default=True)
    bench.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="[SOLVER:]KEY=VALUE",
        help="solver parameter (JSON value), e.g. --param sa:num_reads=10",
    )
    add_processes_option(bench)
    bench.add_argument("--scale", type=float, help="override every scene's ground-truth scale")
    bench.add_argument("--border", type=int, help="override every scene's ignored border (px)")
    bench.add_argument(
        "--max-disparity",
        type=int_or_auto,
        metavar="auto|N",
        help="override every scene's search range (auto: estimated per scene, reported per run)",
    )
    bench.set_defaults(handler=cmd_bench)

    datasets = commands.add_parser("datasets", help="fetch or inspect stereo datasets")
    dataset_commands = datasets.add_subparsers(dest="datasets_command", required=True)
    fetch = dataset_commands.add_parser("fetch", help="download a Middlebury set (checksums)")
    fetch.add_argument("name", help="middlebury2001 or middlebury2003")
    fetch.add_argument("directory", help="folder that receives one sub-folder per scene")
    fetch.add_argument("--scenes", help="comma-separated subset of the set's scenes")
    fetch.add_argument(
        "--mirror", help="base URL replacing vision.middlebury.edu (also QHSM_DATASET_MIRROR)"
    )
    fetch.set_defaults(handler=cmd_datasets_fetch)
    listing = dataset_commands.add_parser("list", help="show the scenes found and their protocol")
    listing.add_argument(
        "directory", help="folder of dataset folders, one dataset folder or one scene folder"
    )
    add_json_option(listing, "the scenes")
    listing.set_defaults(handler=cmd_datasets_list)

    from importlib.metadata import entry_points  # 12 ms: not on qhsm match's path

    for entry in entry_points(group="qhsm.commands"):
        entry.load()(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the command line and run its command; expected errors become a message on stderr.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments after the program name; None reads ``sys.argv``.

    Returns
    -------
    int
        The command's exit status, or ``EXIT_FAILED`` (1) after a reported error,
        ``EXIT_INTERRUPTED`` after Ctrl-C, ``EXIT_BROKEN_PIPE`` when stdout was closed.
    """
    try:
        return _run(argv)
    except KeyboardInterrupt:  # Ctrl-C, at any point: one line, no traceback
        print("qhsm: interrupted", file=sys.stderr)
        return interrupted()
    except BrokenPipeError:
        # stdout's reader went away; later writes (the interpreter flushes stdout at exit) go
        # nowhere instead of failing again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


def console() -> int:
    """The ``qhsm`` script: :func:`main`, then the process's objects frozen for its exit. The
    interpreter's last garbage collection otherwise walks every object the modules made (47 000
    on Tsukuba): 40 ms of its 0.8 s ``qhsm match``, for memory the process's end frees anyway."""
    status = main()
    gc.freeze()
    return status


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings for the user (:class:`shared.disparity_range.ViewsWarning`) as one line, the
    rest as Python shows them."""
    from shared.disparity_range import ViewsWarning
    from shared.ground_truth import ScaleWarning
    from shared.pyramid import RangeWarning

    if issubclass(category, (ViewsWarning, ScaleWarning, RangeWarning)):
        print(f"qhsm: warning: {message}", file=file or sys.stderr)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


def _run(argv: Sequence[str] | None) -> int:
    from shared.threads import limit_threads, thread_budget

    arguments = sys.argv[1:] if argv is None else list(argv)
    only_match = arguments[:1] == ["match"]
    if only_match:
        # pydantic looks for plugins at its first model by reading every installed
        # distribution's entry points (6 ms here, more with more packages); match loads none
        os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")
    limit_threads(thread_budget())  # one process: every core, once (before numba loads)
    from shared.cli_options import CommandError
    from shared.images import ImageError
    from shared.solvers import SolverError, UnknownSolverError

    warnings.showwarning = _show_warning
    args = build_parser(only_match=only_match).parse_args(arguments)
    try:
        return args.handler(args)
    except (
        CommandError,
        ImageError,
        SolverError,
        UnknownSolverError,
        ValueError,
        FileNotFoundError,
    ) as error:
        print(f"qhsm: {error}", file=sys.stderr)
        return EXIT_FAILED


if __name__ == "__main__":
    sys.exit(console())
