"""The ``qhsm`` command. Core commands live here (``match``, ``eval``, ``solvers``); the service
adds its own (``serve``, ``submit``, ...) through the ``qhsm.commands`` entry-point group, so the
core package never imports the service."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from enum import Enum
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

from pydantic import AliasChoices, BaseModel
from pydantic.fields import FieldInfo

from shared.config import AUTO, Encoding, MatchConfig, Settings, get_settings

EXIT_USAGE = 2
EXIT_FAILED = 1


DESCRIPTION = (
    "Quantum-hybrid stereo matching: disparity maps from rectified stereo pairs, in this process "
    "(match, eval, bench) or through the job service (serve, submit, admin). "
    "`qhsm COMMAND --help` shows a command's options."
)
#: ``qhsm bench --encoding auto``: each solver's recommended encoding, else the preset's.
AUTO_ENCODING = "auto"


class CommandError(Exception):
    """A user-facing failure: printed as ``qhsm: <message>`` with exit status 1."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default, except where there is none to show (unset, off, empty) or
    the help text already says it."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        default = action.default
        nothing = default is None or default is False or default == [] or default == "==SUPPRESS=="
        if nothing or "default" in (action.help or "").lower():  # or the help says it
            return action.help
        return super()._get_help_string(action)


class Parser(argparse.ArgumentParser):
    """``qhsm``'s parser: every subcommand (they inherit the class) shows its defaults."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


def _default_text(field: FieldInfo) -> str | None:
    """A field's default as help shows it: None when unset (the text says what unset means)."""
    if field.is_required():  # filled by the preset
        return "from --preset"
    default = field.get_default(call_default_factory=True)
    if default is None:
        return None
    if isinstance(default, bool):
        return "on" if default else "off"
    return str(default.value if isinstance(default, Enum) else default)


def _plain(description: str | None) -> str:
    """A field's description without the "(from preset)" remark the help states as a default."""
    return (description or "").replace(" (from preset)", "")


def field_help(model: type[BaseModel], name: str, text: str = "") -> str:
    """Help of option ``name`` of ``model``: its description (or ``text``) and its default,
    both read from the model, never repeated.

    Parameters
    ----------
    model : type[BaseModel]
        The pydantic model that declares the option (``MatchConfig``, ``Settings``, ...).
    name : str
        The field's name.
    text : str, optional
        Help text to use instead of the field's description.

    Returns
    -------
    str
        The help text, ending in ``(default: ...)`` unless the default is unset or the text
        already speaks of it (an option the preset fills always says so).
    """
    field = model.model_fields[name]
    text = text or _plain(field.description)
    default = _default_text(field)
    if default is None or ("default" in text.lower() and not field.is_required()):
        return text
    return f"{text} (default: {default})"


def _int_or_auto(text: str) -> int | str:
    if text == AUTO:
        return AUTO
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto or an integer, got {text!r}") from None


def _option_kind(annotation: Any) -> dict[str, Any]:
    """argparse keywords for a field's type: a switch for a bool, the values of an enum, ..."""
    kinds = {kind for kind in get_args(annotation) or (annotation,) if kind is not type(None)}
    if bool in kinds:
        return {"action": argparse.BooleanOptionalAction}
    for kind in kinds:
        if isinstance(kind, type) and issubclass(kind, Enum):
            return {"choices": [member.value for member in kind]}
    if int in kinds and any(get_origin(kind) is Literal for kind in kinds):
        return {"type": _int_or_auto, "metavar": "auto|N"}
    for kind in (int, float, Path):
        if kind in kinds:
            return {"type": kind}
    return {}


def model_option(
    parser: argparse.ArgumentParser,
    model: type[BaseModel],
    name: str,
    *flags: str,
    with_default: bool = False,
    **kwargs: Any,
) -> argparse.Action:
    """Add an option for field ``name`` of ``model``: type, choices and help come from the
    field. Its default is ``None`` (not given: the model decides), or with ``with_default`` the
    model's default (for commands that always pass the value on).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        Where the option goes.
    model : type[BaseModel]
        The pydantic model that declares the option.
    name : str
        The field's name; also the option's ``dest``.
    *flags : str
        The option strings (default: ``--name-with-dashes``).
    with_default : bool, optional
        Parse to the model's default when the option is not given.
    **kwargs
        ``argparse`` keywords that override the derived ones (``help``, ``dest``, ...).

    Returns
    -------
    argparse.Action
        The added option.
    """
    field = model.model_fields[name]
    options: dict[str, Any] = {"dest": name, **_option_kind(field.annotation)}
    if with_default:
        options["default"] = field.get_default(call_default_factory=True)
    options["help"] = field_help(model, name, kwargs.pop("help", ""))
    options.update(kwargs)
    return parser.add_argument(*(flags or ("--" + name.replace("_", "-"),)), **options)


def setting_option(
    parser: argparse.ArgumentParser, name: str, *flags: str, **kwargs: Any
) -> argparse.Action:
    """Add an option that overrides ``Settings.name``: help names its environment variable and
    the value in force (the environment included); not given, the settings decide.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        Where the option goes.
    name : str
        The ``Settings`` field; also the option's ``dest`` (:func:`settings_from_args` reads it).
    *flags : str
        The option strings (default: ``--name-with-dashes``).
    **kwargs
        ``argparse`` keywords that override the derived ones (``help``, ...).

    Returns
    -------
    argparse.Action
        The added option.
    """
    field = Settings.model_fields[name]
    alias = field.validation_alias
    env = alias.choices[0] if isinstance(alias, AliasChoices) else alias
    env = env or (Settings.model_config.get("env_prefix", "") + name).upper()
    text = kwargs.pop("help", "") or field.description or ""
    value = getattr(get_settings(), name)
    if value is not None and "default" not in text.lower():
        text = f"{text} ({env}; default: {value})"
    elif env not in text:
        text = f"{text} ({env})"
    flags = flags or ("--" + name.replace("_", "-"),)
    options: dict[str, Any] = {"dest": name, **_option_kind(field.annotation), "help": text}
    if "choices" not in options and "action" not in options:  # --port PORT, not API_PORT
        options["metavar"] = flags[-1].lstrip("-").replace("-", "_").upper()
    return parser.add_argument(*flags, **options, **kwargs)


def settings_from_args(args: argparse.Namespace) -> Settings:
    """The settings of the environment with the options of :func:`setting_option` given.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments; attributes named like ``Settings`` fields and not None override them.

    Returns
    -------
    Settings
        A copy of :func:`shared.config.get_settings` with the overrides.
    """
    changes = {
        name: getattr(args, name)
        for name in Settings.model_fields
        if getattr(args, name, None) is not None
    }
    return get_settings().model_copy(update=changes)


def add_json_option(parser: argparse.ArgumentParser, what: str = "the result") -> None:
    """``--json``: print ``what`` as JSON (every command that has it says the same)."""
    parser.add_argument("--json", action="store_true", help=f"print {what} as JSON")


def add_processes_option(parser: argparse.ArgumentParser) -> None:
    """``--processes``: local processes that solve the bundles (``qhsm match`` and ``bench``)."""
    parser.add_argument(
        "--processes",
        type=int,
        default=0,
        help="local worker processes for the bundles (0: one per core)",
    )


#: ``MatchConfig`` options of ``qhsm match``, ``submit`` and ``estimate`` (``--param`` aside).
MATCH_OPTIONS = (
    "preset",
    "solver",
    "max_disparity",
    "bundle_height",
    "bundle_width",
    "bundle_margin",
    "regularizer",
    "encoding",
    "rectifier",
    "data_term",
    "pyramid",
    "median",
    "bilateral",
    "lr_check",
    "weighted_median",
    "warm_start",
    "subpixel",
    "seed",
)


def add_match_options(parser: argparse.ArgumentParser) -> None:
    """Options that map onto ``MatchConfig`` (shared with ``qhsm submit``), built from its
    fields. Every default is ``None`` here: an option not given is left to the preset and
    ``MatchConfig``."""
    for name in MATCH_OPTIONS:
        model_option(parser, MatchConfig, name)
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
        return MatchConfig(**match_params(args))
    except ValidationError as error:
        raise CommandError(_validation_message(error)) from None


def match_params(args: argparse.Namespace) -> dict:
    """The ``MatchConfig`` options given on the command line (the rest keep their defaults):
    what ``qhsm submit`` sends as the job's ``params``."""
    params = {
        name: getattr(args, name) for name in MATCH_OPTIONS if getattr(args, name) is not None
    }
    if args.param:
        params["solver_params"] = dict(_parse_param(p) for p in args.param)
    return params


def _validation_message(error) -> str:
    return "; ".join(
        f"{'.'.join(map(str, e['loc'])) or 'config'}: {e['msg']}" for e in error.errors()
    )


def cmd_match(args: argparse.Namespace) -> int:
    from shared.images import load_pair, preview_png, save_disparity
    from shared.pipeline import run_pipeline
    from shared.solve import ProcessPoolLevelSolver, bundle_width_setting
    from shared.solvers import get_solver

    config = config_from_args(args)
    solver = get_solver(config.solver)
    bundle_width_setting(config)  # a width the solver cannot use: say so before any work
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
        top = result.max_disparity.max_disparity
        Path(args.preview).write_bytes(preview_png(result.disparity, top))
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


def cmd_bench(args: argparse.Namespace) -> int:
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
    from shared.bench import split_names
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
    from shared.datasets import find_scenes

    scenes = find_scenes(args.directory)
    rows = [{"name": name, **scene.protocol()} for name, scene in scenes.items()]
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for row in rows:
            print(
                f"{row['name']:<12} {row['layout']:<24} scale {row['scale']:g}  border "
                f"{row['border']}  max disparity {row['max_disparity']}  "
                f"masks {','.join(row['masks']) or '-'}"
            )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="qhsm", description=DESCRIPTION)
    commands = parser.add_subparsers(dest="command", required=True)

    match = commands.add_parser("match", help="match a stereo pair in this process")
    match.add_argument("left", help="left view (PNG, PPM/PGM, JPEG, PFM, TIFF, BMP)")
    match.add_argument("right", help="right view, same size, rectified")
    match.add_argument("-o", "--output", required=True, help="OUT.pfm, OUT.png (x256) or .npy")
    add_match_options(match)
    match.add_argument("--preview", help="write a colour-mapped PNG here")
    match.add_argument("--json", action="store_true", help="print a JSON summary")
    add_processes_option(match)
    match.set_defaults(handler=cmd_match)

    evaluate = commands.add_parser("eval", help="score a disparity map against ground truth")
    evaluate.add_argument("disparity", help="disparity map to score (.pfm, .png x256, .npy)")
    evaluate.add_argument("ground_truth", help="ground truth (stored value = disparity x --scale)")
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
    model_option(bench, MatchConfig, "bundle_height", with_default=True)
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
        type=_int_or_auto,
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
    listing.add_argument("directory", help="folder of scene folders")
    add_json_option(listing, "the scenes")
    listing.set_defaults(handler=cmd_datasets_list)

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
