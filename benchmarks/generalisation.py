"""Generalisation (issue 17): the matcher against OpenCV SGBM on every development scene, one run.

    python benchmarks/generalisation.py [--data DIR ...] [--variants accurate,no-lr-check]
        [--variant NAME=KEY:VALUE,KEY:VALUE ...] [--scenes a,b] [--processes 2] [--out DIR]

Finds every scene with ground truth below the ``--data`` folders by their layout (default: the
folder holding the Middlebury copies, ``../shared/data``: Tsukuba, Venus, Cones, the 2005
third-size and 2006 half-size scenes), runs each variant (default: ``accurate``, what
``qhsm match`` does: ``exact``, the accurate preset) and the SGBM baseline with the range given
(ceil of the ground truth's maximum), and scores them: bad pixels > 1 px on the non-occluded
pixels. Prints the Markdown report (per scene ours / SGBM / ratio / win or loss, the wins, the
averages and their ratio) and writes ``OUT/results.md``, ``OUT/results.json`` (to diff runs) and
per scene the maps (``OUT/<dataset>/<scene>/generalisation-<variant>.png``, ``-error.png``,
``.pfm``). See :mod:`shared.bench.generalisation`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from shared.bench import split_names
from shared.bench.experiments import BenchError
from shared.bench.generalisation import (
    DEFAULT_PROCESSES,
    DEFAULT_VARIANTS,
    VARIANTS,
    Options,
    named_variants,
    parse_variant,
    run_benchmark,
)
from shared.bench.generalisation_report import markdown
from shared.cli_options import model_option
from shared.config import MatchConfig
from shared.datasets import default_middlebury_dir


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data",
        type=Path,
        action="append",
        help="folder of datasets, dataset folder or scene folder (repeat for several; default: "
        f"{default_middlebury_dir().parent})",
    )
    parser.add_argument(
        "--variants",
        default=",".join(DEFAULT_VARIANTS),
        help=f"registry variants, comma-separated ({', '.join(VARIANTS)}); '' for none",
    )
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME=KEY:VALUE,...",
        help="a named MatchConfig change, e.g. rows-median=median_size:5,solver:sa (repeatable)",
    )
    parser.add_argument("--scenes", help="comma-separated dataset/scene or scene names")
    parser.add_argument(
        "--processes",
        type=int,
        default=DEFAULT_PROCESSES,
        help="runs side by side (default: one per core; 1: in this process)",
    )
    model_option(parser, MatchConfig, "seed", with_default=True)
    parser.add_argument("--out", type=Path, default=Path("out/generalisation"))
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        if args.processes < 1:
            raise BenchError("--processes must be at least 1")
        variants = named_variants(split_names(args.variants) or [])
        variants += [parse_variant(text) for text in args.variant]
        if not variants:
            raise BenchError("no variant to run: give --variants or --variant")
        options = Options(
            data=args.data or [default_middlebury_dir().parent],
            out=args.out,
            variants=variants,
            scenes=split_names(args.scenes),
            processes=args.processes,
            seed=args.seed,
        )
        given = sys.argv[1:] if argv is None else argv
        command = ["python", "benchmarks/generalisation.py", *given]
        data = run_benchmark(options, command=command, progress=True)
    except ValueError as error:  # BenchError, or a dataset's unreadable protocol.json
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
