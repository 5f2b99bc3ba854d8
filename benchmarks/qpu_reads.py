"""QPU reads per bundle (issue 19, item 3): the energy gap of qpu-sim's best read to the bundle's
optimum, against the number of reads, on Tsukuba halved with the defaults (roof duality first,
warm start as the solver's default decides).

    python benchmarks/qpu_reads.py [--bundles 24] [--reads 5 10 20 50 100 200]

Each level's bundles are sampled evenly (64-px segments, the estimate's width before ``auto``
has run); the optimum of a row segment is the row DP's. The gap is (E - E*) / |E*| in MRF energy.
``MockDWaveSampler`` runs a steepest descent per read and ignores reverse-anneal warm starts, so
this measures the offline path; the QPU seconds are the timing model's for the same problems.
Prints markdown for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from qpu_economy import halved

from shared.config import MatchConfig
from shared.encodings import get_codec
from shared.energy import mrf_energy
from shared.inference import solve_level_in_process
from shared.pipeline import run_pipeline
from shared.solvers.exact import solve_chains
from shared.solvers.meters import qpu_time
from shared.solvers.registry import get_solver


def measure(bundles: int, reads: list[int]) -> list[str]:
    """Markdown rows: per level and read count, the gaps' median, mean, 90th percentile and
    the share of bundles at their optimum, with the model's QPU milliseconds per bundle."""
    left, right, _, _ = halved("tsukuba")
    config = MatchConfig(solver="qpu-sim", max_disparity=8, bundle_width=64)
    exact = config.model_copy(update={"solver": "exact", "bundle_width": None})
    codec = get_codec(config.encoding)
    solver = get_solver("qpu-sim")
    rows: list[str] = []

    def probe(inputs, cfg):
        level = inputs.bundles(1, 64, config.bundle_margin)
        picked = np.linspace(0, len(level) - 1, bundles).astype(int)
        gaps: dict[int, list[float]] = {r: [] for r in reads}
        charge: dict[int, list[float]] = {r: [] for r in reads}
        for index in picked:
            start, stop, first, last = level[index].as_list()
            row_costs = inputs.costs(config, start, stop)
            costs = row_costs.columns(first, last)
            bqm = codec.encode(costs, config.rectifier)
            best = mrf_energy(costs, solve_chains(costs))
            warm = inputs.starting_labels(row_costs, start, stop)[:, first:last]
            initial = codec.encode_labels(warm, costs.num_labels)
            for count in reads:
                outcome = solver.solve(bqm, seed=int(index), initial_state=initial,
                                       num_reads=count)  # fmt: skip
                energy = mrf_energy(costs, codec.decode(costs, outcome.sample).labels)
                gaps[count].append((energy - best) / max(abs(best), 1e-12))
                charge[count].append(qpu_time.charged_seconds(outcome.timing))
        for count in reads:
            gap = np.asarray(gaps[count])
            rows.append(
                f"| {inputs.plan.index} | {count} | {np.median(gap):.3%} | {gap.mean():.3%} "
                f"| {np.quantile(gap, 0.9):.3%} | {np.mean(gap <= 1e-9):.0%} "
                f"| {1e3 * np.mean(charge[count]):.1f} |"
            )
        return solve_level_in_process(inputs, cfg)

    run_pipeline(left, right, exact, probe)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bundles", type=int, default=24, help="bundles per level")
    parser.add_argument("--reads", type=int, nargs="+", default=[5, 10, 20, 50, 100, 200])
    args = parser.parse_args(argv)
    started = time.perf_counter()
    print("| level | reads | median gap | mean gap | 90th pct gap | at optimum | QPU ms/bundle |")
    print("|---|---|---|---|---|---|---|")
    for row in measure(args.bundles, args.reads):
        print(row, flush=True)
    print(f"\n({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
