"""`qhsm --help` and every subcommand's help (issue 10, items 17 and 18): a whole description
without markup, defaults shown, positional arguments documented, defaults that match the code
and the README (`qhsm bench`: domain-wall for annealers, one process per core)."""

from __future__ import annotations

import argparse
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
    assert "--json print a JSON summary --processes" in match  # a switch: no "(default: False)"
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
