"""Energy gaps of every available solver on real bundles (Tsukuba rows at each pyramid level).

Each level's inputs are the ones the pipeline really builds: ``prepare_level`` fed with the
``exact`` solver's estimate of the coarser level. From every level a sample of bundles (evenly
spaced) is solved by each solver and encoding, and compared with a reference:

* bundle height 1: the exact optimum (row dynamic programming);
* bundle height 2: the exact optimum from dwave-samplers' TreeDecompositionSolver on the
  domain-wall QUBO (a ladder has small treewidth), or with ``--tall-reference best`` the best
  energy any solver found.

Gaps are in MRF energy, (E - E_ref) / |E_ref| in %. ``gurobi`` cannot take a full row under the
size-limited pip licence, so it is compared with the row DP on row *segments* that fit the
licence (at most 200 variables).

    python benchmarks/solvers.py                       # 8 bundles per level, heights 1 and 2
    python benchmarks/solvers.py --rows 4 --heights 1 --solvers sa,tabu --markdown out.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scenes import level_inputs, load

from shared.bundles import bundle_rows, bundle_seed
from shared.config import MatchConfig
from shared.encodings import get_codec
from shared.energy import Costs, mrf_energy
from shared.solvers import SolverError
from shared.solvers.exact import solve_chains
from shared.solvers.gurobi import PIP_LICENCE_VARIABLES
from shared.solvers.registry import get_solver, solver_names

ENCODINGS = ("one-hot", "domain-wall")
#: Solvers compared in both encodings; the others run on domain-wall only (measured best).
BOTH_ENCODINGS = {"sa", "tabu", "qpu-sim", "steepest-descent"}
#: Solvers that are not run on whole bundles here (exact is the reference; gurobi: segments).
NOT_ON_BUNDLES = {"exact", "gurobi"}
#: Relative gap below which a bundle counts as solved to optimality.
AT_OPTIMUM = 1e-7


@dataclass
class Outcome:
    solver: str
    encoding: str
    height: int
    level: int
    bundle: int
    energy: float | None
    repaired: int = 0
    seconds: float = 0.0
    error: str | None = None
    info: dict = field(default_factory=dict)


def sample_bundles(height: int, bundle_height: int, count: int) -> list[tuple[int, int]]:
    """``count`` evenly spaced full-height bundles of a level (all of them if fewer)."""
    bundles = [b for b in bundle_rows(height, bundle_height) if b[1] - b[0] == bundle_height]
    # Interior positions: the first and last rows of Middlebury images are often flat borders
    # with near-zero energy, where relative gaps say little.
    picks = np.unique(((np.arange(count) + 0.5) * len(bundles) / count).astype(int))
    return [bundles[i] for i in picks]


def reference_energy(costs: Costs, mode: str) -> float | None:
    """Exact optimum of a bundle, or None where only the best found can serve."""
    if costs.shape[0] == 1:
        return mrf_energy(costs, solve_chains(costs))
    if mode != "tree":
        return None
    from dwave.samplers import TreeDecompositionSolver

    codec = get_codec("domain-wall")
    sampleset = TreeDecompositionSolver().sample(codec.encode(costs))
    best = sampleset.first.sample
    sample = np.array([best[v] for v in range(len(best))], dtype=np.int8)
    return mrf_energy(costs, codec.decode(costs, sample).labels)


def run_solver(
    name, encoding, costs, seed, params
) -> tuple[float | None, int, float, str | None, dict]:
    codec = get_codec(encoding)
    bqm = codec.encode(costs)
    started = time.perf_counter()
    try:
        result = get_solver(name).solve(bqm, seed=seed, **params)
    except SolverError as error:
        return None, 0, time.perf_counter() - started, str(error), {}
    decoded = codec.decode(costs, result.sample)
    keep = ("embedding_cache", "chain_break_fraction", "fixed_fraction", "longest_chain")
    info = {k: result.info[k] for k in keep if k in result.info}
    return mrf_energy(costs, decoded.labels), decoded.repaired, result.wall_time, None, info


def gurobi_segments(levels, config, rows: int) -> list[dict]:
    """Gurobi vs the row DP on row segments that fit the pip licence."""
    out = []
    solver = get_solver("gurobi")
    for inputs in levels:
        labels = inputs.plan.candidates
        for encoding in ENCODINGS:
            per_pixel = labels if encoding == "one-hot" else labels - 1
            width = min(inputs.shape[1], PIP_LICENCE_VARIABLES // per_pixel)
            codec = get_codec(encoding)
            for start, stop in sample_bundles(inputs.shape[0], 1, rows):
                costs = inputs.costs(config, start, stop)
                offset = (inputs.shape[1] - width) // 2
                segment = Costs(
                    candidates=costs.candidates[:, offset : offset + width],
                    unary=costs.unary[:, offset : offset + width],
                    pair_h=costs.pair_h[:, offset : offset + width - 1],
                    pair_v=costs.pair_v[:, offset : offset + width],
                )
                optimum = mrf_energy(segment, solve_chains(segment))
                result = solver.solve(codec.encode(segment), seed=0, mip_gap=0.0, time_limit=60)
                energy = mrf_energy(segment, codec.decode(segment, result.sample).labels)
                out.append(
                    {
                        "level": inputs.plan.index,
                        "encoding": encoding,
                        "width": width,
                        "gap": (energy - optimum) / abs(optimum) * 100,
                        "seconds": result.wall_time,
                        "optimal": result.info.get("optimal"),
                    }
                )
    return out


def summarise(outcomes: list[Outcome], references: dict) -> list[dict]:
    """One row per (solver, encoding, height, level)."""
    groups = defaultdict(list)
    for outcome in outcomes:
        groups[(outcome.solver, outcome.encoding, outcome.height, outcome.level)].append(outcome)
    rows = []
    for (solver, encoding, height, level), items in groups.items():
        done = [o for o in items if o.energy is not None]
        gaps = np.array(
            [
                (o.energy - references[(height, level, o.bundle)])
                / abs(references[(height, level, o.bundle)])
                * 100
                for o in done
            ]
        )
        rows.append(
            {
                "solver": solver,
                "encoding": encoding,
                "height": height,
                "level": level,
                "bundles": len(items),
                "failed": len(items) - len(done),
                "median_gap": float(np.median(gaps)) if gaps.size else None,
                "worst_gap": float(gaps.max()) if gaps.size else None,
                "at_optimum": float(np.mean(gaps <= AT_OPTIMUM * 100)) if gaps.size else None,
                "repaired": int(sum(o.repaired for o in done)),
                "median_seconds": float(np.median([o.seconds for o in items])),
                "max_seconds": float(max(o.seconds for o in items)),
                "embeddings_computed": sum(
                    o.info.get("embedding_cache") == "computed" for o in items
                ),
                "error": next((o.error for o in items if o.error), None),
            }
        )
    return sorted(rows, key=lambda r: (r["height"], r["solver"], r["encoding"], r["level"]))


def markdown(rows: list[dict], segments: list[dict], levels, reference_kind: dict) -> str:
    def pct(value):
        return "–" if value is None else f"{value:.3f}"

    lines = []
    for height in sorted({r["height"] for r in rows}):
        lines += [
            "",
            f"Bundle height {height} (reference: {reference_kind[height]})",
            "",
            "| solver | encoding | level (px) | bundles | median gap % | worst gap % "
            "| at optimum | repaired px | s/bundle (median, max) | note |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in (r for r in rows if r["height"] == height):
            inputs = levels[r["level"]]
            size = f"{r['level']} ({inputs.shape[1]}x{inputs.plan.candidates})"
            note = []
            if r["embeddings_computed"]:
                note.append(f"{r['embeddings_computed']} embedding(s) computed")
            if r["failed"]:
                note.append(f"{r['failed']} failed: {(r['error'] or '')[:90]}")
            at_opt = "–" if r["at_optimum"] is None else f"{100 * r['at_optimum']:.0f}%"
            lines.append(
                f"| {r['solver']} | {r['encoding']} | {size} | {r['bundles']} "
                f"| {pct(r['median_gap'])} | {pct(r['worst_gap'])} | {at_opt} | {r['repaired']} "
                f"| {r['median_seconds']:.3f}, {r['max_seconds']:.2f} | {'; '.join(note)} |"
            )
    if segments:
        lines += [
            "",
            f"gurobi vs row DP on centred row segments within the pip licence "
            f"(<= {PIP_LICENCE_VARIABLES} variables)",
            "",
            "| level | encoding | segment px | segments | worst gap % | all optimal | s (median) |",
            "|---|---|---|---|---|---|---|",
        ]
        groups = defaultdict(list)
        for s in segments:
            groups[(s["level"], s["encoding"], s["width"])].append(s)
        for (level, encoding, width), items in sorted(groups.items()):
            lines.append(
                f"| {level} | {encoding} | {width} | {len(items)} "
                f"| {max(s['gap'] for s in items):.2e} | {all(s['optimal'] for s in items)} "
                f"| {np.median([s['seconds'] for s in items]):.3f} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="tsukuba")
    parser.add_argument("--preset", choices=["accurate", "paper"], default="accurate")
    parser.add_argument("--max-disparity", type=int, default=16, help="the scene's range (px)")
    parser.add_argument("--rows", type=int, default=8, help="bundles sampled per level")
    parser.add_argument("--heights", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--solvers", help="comma-separated (default: every available one)")
    parser.add_argument("--tall-reference", choices=["tree", "best"], default="tree")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="SOLVER:KEY=VALUE",
        help="solver parameter, e.g. sa:num_reads=50 (JSON values)",
    )
    parser.add_argument(
        "--variant",
        action="append",
        default=["sa:preprocess=none"],
        metavar="SOLVER:KEY=VALUE[,KEY=VALUE]",
        help="also run SOLVER with these parameters as its own row "
        "(default: sa:preprocess=none, plain annealing)",
    )
    parser.add_argument("--no-gurobi-segments", action="store_true")
    parser.add_argument(
        "--embedding-timeout",
        type=float,
        default=120.0,
        help="minorminer time limit per bundle structure for qpu-sim, s (sets "
        "QHSM_EMBEDDING_TIMEOUT; embeddings persist in QHSM_DATA_DIR/embeddings)",
    )
    parser.add_argument("--markdown", type=Path, help="also write the tables here")
    parser.add_argument("--json", type=Path, help="write raw outcomes here")
    args = parser.parse_args(argv)
    os.environ["QHSM_EMBEDDING_TIMEOUT"] = str(args.embedding_timeout)

    params: dict[str, dict] = defaultdict(dict)
    for text in args.param:
        solver, _, assignment = text.partition(":")
        key, _, value = assignment.partition("=")
        try:
            params[solver][key] = json.loads(value)
        except json.JSONDecodeError:
            params[solver][key] = value
    wanted = args.solvers.split(",") if args.solvers else solver_names()
    solvers: list[tuple[str, str, dict]] = []  # (label, registry name, parameters)
    for name in wanted:
        availability = get_solver(name).available()
        if not availability.ok:
            print(f"skipping {name}: {availability.reason}", file=sys.stderr)
        elif name not in NOT_ON_BUNDLES:
            solvers.append((name, name, params[name]))
    for text in args.variant:
        name, _, assignments = text.partition(":")
        if name not in {label for label, _, _ in solvers}:
            continue
        extra = dict(params[name])
        for assignment in assignments.split(","):
            key, _, value = assignment.partition("=")
            try:
                extra[key] = json.loads(value)
            except json.JSONDecodeError:
                extra[key] = value
        solvers.append((f"{name} ({assignments})", name, extra))

    started = time.perf_counter()
    config = MatchConfig(preset=args.preset, max_disparity=args.max_disparity)
    _, left, right = load(args.scene)
    levels = level_inputs(left, right, config.model_copy(update={"bundle_height": 1}))
    print(f"levels ready ({time.perf_counter() - started:.1f} s)", file=sys.stderr)
    outcomes: list[Outcome] = []
    references: dict = {}
    reference_kind = {}
    for height in args.heights:
        exact_tall = height == 1 or args.tall_reference == "tree"
        reference_kind[height] = (
            "row DP optimum"
            if height == 1
            else "TreeDecompositionSolver optimum"
            if exact_tall
            else "best energy found by any solver"
        )
        for inputs in levels:
            for number, (start, stop) in enumerate(
                sample_bundles(inputs.shape[0], height, args.rows)
            ):
                costs = inputs.costs(config, start, stop)
                tick = time.perf_counter()
                exact = reference_energy(costs, args.tall_reference)
                if exact is not None:
                    references[(height, inputs.plan.index, number)] = exact
                seed = bundle_seed(config.seed, inputs.plan.index, start)
                for label, name, solver_params in solvers:
                    encodings = ENCODINGS if name in BOTH_ENCODINGS else ("domain-wall",)
                    for encoding in encodings:
                        energy, repaired, seconds, error, info = run_solver(
                            name, encoding, costs, seed, solver_params
                        )
                        outcomes.append(
                            Outcome(
                                label,
                                encoding,
                                height,
                                inputs.plan.index,
                                number,
                                energy,
                                repaired,
                                seconds,
                                error,
                                info,
                            )
                        )
                if exact is None:
                    found = [
                        o.energy
                        for o in outcomes
                        if (o.height, o.level, o.bundle) == (height, inputs.plan.index, number)
                        and o.energy is not None
                    ]
                    references[(height, inputs.plan.index, number)] = min(found)
                print(
                    f"h={height} level {inputs.plan.index} bundle {number} rows {start}-{stop} "
                    f"({time.perf_counter() - tick:.1f} s)",
                    file=sys.stderr,
                )
    segments = (
        []
        if args.no_gurobi_segments
        or "gurobi" not in wanted
        or not get_solver("gurobi").available().ok
        else gurobi_segments(levels, config, args.rows)
    )
    rows = summarise(outcomes, references)
    text = markdown(rows, segments, levels, reference_kind)
    print(text)
    print(f"total {time.perf_counter() - started:.0f} s", file=sys.stderr)
    if args.markdown:
        args.markdown.write_text(text)
    if args.json:
        args.json.write_text(
            json.dumps(
                {"rows": rows, "segments": segments, "outcomes": [asdict(o) for o in outcomes]},
                indent=1,
                default=float,
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
