"""`qhsm --help` and every subcommand's help (issue 10, items 17 and 18): a whole description
without markup, defaults shown, positional arguments documented, defaults that match the code
and the README (`qhsm bench`: domain-wall for annealers, one process per core)."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from shared import bench
from shared.cli import build_parser, main

README = (Path(__file__).resolve().parents[2] / "README.md").read_text()


def parsers(parser: argparse.ArgumentParser, path: str = "qhsm"):
    """Every (command path, parser) of the tree."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from parsers(child, f"{path} {name}")


def test_top_level_description_is_whole_and_plain(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    description = build_parser().description
    assert description.rstrip().endswith(".") and "``" not in description
    assert " ".join(description.split()) in " ".join(text.split())


def test_every_positional_argument_is_documented():
    for path, parser in parsers(build_parser()):
        for action in parser._actions:
            if not action.option_strings and not isinstance(action, argparse._SubParsersAction):
                assert action.help, f"`{path}`: positional {action.dest!r} has no help"


def test_help_shows_defaults_and_nothing_for_unset_options():
    for path, parser in parsers(build_parser()):
        assert "(default: None)" not in parser.format_help(), path
    match = " ".join(dict(parsers(build_parser()))["qhsm match"].format_help().split())
    assert "--processes PROCESSES local worker processes for the bundles (0: one per core) " in (
        match
    )
    assert "(default: 0)" in match  # added by the formatter
    assert "--json print a summary as JSON --processes" in match  # a switch: no "(default: False)"
    assert "(default: exact)" in match


def test_demo_help_states_its_real_port_default(capsys):
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--port PORT API port (default: a free port" in text
    assert "8000" not in text


def test_bench_defaults_follow_the_readme_recommendation():
    options = dict(parsers(build_parser()))["qhsm bench"].parse_args(["DATA"])
    assert options.encoding == "auto" and options.processes == 0
    assert bench.BenchOptions(Path("d"), Path("o")).processes == 0
    assert bench.encoding_for("sa", bench.BenchOptions(Path("d"), Path("o"))) == "domain-wall"
    assert bench.encoding_for("qpu", bench.BenchOptions(Path("d"), Path("o"))) == "domain-wall"
    assert bench.encoding_for("exact", bench.BenchOptions(Path("d"), Path("o"))) is None  # preset
    asked = bench.BenchOptions(Path("d"), Path("o"), encoding="one-hot")
    assert bench.encoding_for("sa", asked) == "one-hot"
    assert "`--solver sa --encoding domain-wall`" in README  # what the README recommends


# --- issue 13, item 4: one source of defaults --------------------------------------------------


def test_match_options_leave_every_default_to_the_model_and_state_it():
    """Not given, an option is None (the preset and MatchConfig decide); its help states the
    model's default, so a changed default in MatchConfig changes the help with it."""
    from shared.cli_options import MATCH_OPTIONS, config_from_args, match_params
    from shared.config import MatchConfig

    for command in ("match", "submit", "estimate"):
        parser = dict(parsers(build_parser()))[f"qhsm {command}"]
        args = parser.parse_args(["L", "R", "-o", "O"] if command != "estimate" else ["L", "R"])
        assert match_params(args) == {}, command
        assert config_from_args(args) == MatchConfig()
        helps = {a.dest: " ".join((a.help or "").split()) for a in parser._actions}
        for name in MATCH_OPTIONS:
            field = MatchConfig.model_fields[name]
            assert getattr(args, name) is None, (command, name)
            if field.is_required():
                assert helps[name].endswith("(default: from --preset)"), name
            elif isinstance(field.default, bool):
                assert helps[name].endswith(f"(default: {'on' if field.default else 'off'})")
            elif field.default is not None:
                default = getattr(field.default, "value", field.default)
                assert helps[name].endswith(f"(default: {default})"), (name, helps[name])


def test_service_options_show_and_override_the_settings(monkeypatch):
    from shared.cli_options import settings_from_args

    monkeypatch.setenv("QHSM_API_PORT", "8123")
    monkeypatch.setenv("QHSM_API_URL", "http://127.0.0.1:8123")
    tree = dict(parsers(build_parser()))
    serve = " ".join(tree["qhsm serve"].format_help().split())
    assert "--port PORT `qhsm serve` / `qhsm api` port (QHSM_API_PORT; default: 8123)" in serve
    submit = " ".join(tree["qhsm submit"].format_help().split())
    assert "(QHSM_API_URL; default: http://127.0.0.1:8123)" in submit
    estimate = " ".join(tree["qhsm estimate"].format_help().split())
    assert "(QHSM_API_URL; default: http://127.0.0.1:8123)" in estimate

    settings = settings_from_args(tree["qhsm serve"].parse_args(["--port", "9001"]))
    assert (settings.api_port, settings.api_host) == (9001, "127.0.0.1")
    assert settings_from_args(tree["qhsm serve"].parse_args([])).api_port == 8123
    submit_args = tree["qhsm submit"].parse_args(["L", "R", "--url", "http://h:1"])
    assert settings_from_args(submit_args).api_url == "http://h:1"


def test_bench_and_demo_defaults_are_the_models():
    from shared.config import MatchConfig

    tree = dict(parsers(build_parser()))
    bench_args = tree["qhsm bench"].parse_args(["DATA"])
    default = MatchConfig()
    # bundle height: unset, so each run's preset and inference decide (3-row tiles or rows)
    assert (bench_args.bundle_height, bench_args.seed) == (None, default.seed)
    assert bench_args.ablation_solver == default.solver
    assert tree["qhsm demo"].parse_args([]).solver == default.solver


def test_the_command_line_registers_the_service_commands_without_loading_celery():
    """``qhsm match`` runs in a fresh process each time: building the parser (which registers
    the service's sub-commands) must not import Celery or redis-py (~0.16 s)."""
    code = (
        "import sys\n"
        "from shared.cli import build_parser\n"
        "build_parser()\n"
        "print(sorted(m for m in ('celery', 'redis', 'workers.app') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
