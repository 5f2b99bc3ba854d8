"""Command-line options built from the models (``MatchConfig``, ``Settings``), so an option's
type, choices, default and help are written once, in the model's field; plus the parsing of
``qhsm match`` / ``submit`` options back into a ``MatchConfig``. Used by ``shared.cli`` and by the
service's commands (``api.cli``, ``api.admin``)."""

from __future__ import annotations

import argparse
import json
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, get_args, get_origin

from pydantic import AliasChoices, BaseModel
from pydantic.fields import FieldInfo

from shared.config import AUTO, MatchConfig

if TYPE_CHECKING:
    from shared.settings import Settings


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


def int_or_auto(text: str) -> int | str:
    """argparse ``type`` of options that take ``auto`` or a whole number.

    Parameters
    ----------
    text : str
        The option's value as typed.

    Returns
    -------
    int or str
        The integer, or ``"auto"``.

    Raises
    ------
    argparse.ArgumentTypeError
        For anything else (argparse reports it as a usage error).
    """
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
        return {"type": int_or_auto, "metavar": "auto|N"}
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
    from shared.settings import Settings, get_settings  # the service's commands only

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
    from shared.settings import Settings, get_settings

    changes = {
        name: getattr(args, name)
        for name in Settings.model_fields
        if getattr(args, name, None) is not None
    }
    return get_settings().model_copy(update=changes)


def add_json_option(parser: argparse.ArgumentParser, what: str = "the result") -> None:
    """``--json``: print ``what`` as JSON (every command that has it says the same).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    what : str, default "the result"
        What the command prints, for the help text.
    """
    parser.add_argument("--json", action="store_true", help=f"print {what} as JSON")


def add_calib_option(parser: argparse.ArgumentParser, use: str) -> None:
    """``--calib``: a calibration file in one of the formats
    :func:`shared.datasets.calibration.read_calibration` reads (every command names the same).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    use : str
        What the command does with it, for the help text.
    """
    parser.add_argument("--calib", help=f"Middlebury calib.txt or KITTI calibration: {use}")


def add_processes_option(parser: argparse.ArgumentParser) -> None:
    """``--processes``: local processes that solve the bundles (``qhsm match`` and ``bench``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The parser that receives ``--processes`` (int, default 0: one per core).
    """
    parser.add_argument(
        "--processes",
        type=int,
        default=0,
        help="local worker processes for the bundles (0: one per core)",
    )


def add_pair_arguments(parser: argparse.ArgumentParser) -> None:
    """The stereo pair, ``left`` and ``right`` (``qhsm match``, ``submit`` and ``estimate``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    """
    parser.add_argument("left", help="left view (PNG, PPM/PGM, JPEG, PFM, TIFF, BMP)")
    parser.add_argument("right", help="right view, same size, rectified")


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
    "inference",
    "grid_inference",
    "dual_iterations",
    "dual_gap",
    "certify_tiles",
    "coarse_grid",
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
    ``MatchConfig``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The parser that receives one option per :data:`MATCH_OPTIONS` field, and ``--param``.
    """
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
    """The run's ``MatchConfig`` from the parsed ``MatchConfig`` options.

    Parameters
    ----------
    args : argparse.Namespace
        The command line as parsed; its :data:`MATCH_OPTIONS` attributes and ``param`` are
        read (via :func:`match_params`).

    Returns
    -------
    MatchConfig
        The preset's values under the given options.

    Raises
    ------
    CommandError
        When the options do not make a valid configuration (the message names each field).
    """
    from pydantic import ValidationError

    try:
        return MatchConfig(**match_params(args))
    except ValidationError as error:
        raise CommandError(_validation_message(error)) from None


def match_params(args: argparse.Namespace) -> dict:
    """The ``MatchConfig`` options given on the command line (the rest keep their defaults):
    what ``qhsm submit`` sends as the job's ``params``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of a parser built with :func:`add_match_options`.

    Returns
    -------
    dict
        Field -> value of the options given; ``--param`` values under ``solver_params``.

    Raises
    ------
    CommandError
        For a ``--param`` that is not ``KEY=VALUE``.
    """
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
