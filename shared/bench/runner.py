"""The bench loop: each variant on each scene, scored, imaged and reported.

Failures of one run are recorded in its :class:`~shared.bench.scoring.Run`, never raised, so the
other runs go on. The one module of :mod:`shared.bench` that reads the solver registry (a
variant's availability and recommended encoding).
"""

from __future__ import annotations

import json
import os
import platform
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict
from datetime import UTC, datetime

import numpy as np

from shared.baselines import heidari, sgbm
from shared.bench.experiments import (
    PAPER_FIGURES,
    BenchError,
    BenchOptions,
    Variant,
    match_config,
    paper_figure,
    variants,
)
from shared.bench.report import log_line, markdown, write_images
from shared.bench.scene_runners import RunOutput, SceneRunner, local_runner, remote_runner
from shared.bench.scoring import Run, averages, score
from shared.config import AUTO
from shared.datasets import Scene, find_scenes
from shared.images import to_gray
from shared.provenance import qhsm_version
from shared.solvers import SolverUnavailableError, UnknownSolverError
from shared.solvers.registry import resolve


def encoding_for(solver: str, options: BenchOptions) -> str | None:
    """The encoding a solver's runs use.

    Parameters
    ----------
    solver
        Registry name of the solver.
    options
        The bench options (``encoding``: the one asked for, if any).

    Returns
    -------
    str or None
        The asked-for encoding, else the solver's recommended one (the registry's: domain-wall
        for the annealers), else None: the run's preset decides.
    """
    return options.encoding or resolve(solver).spec.encoding


def _skip_reason(variant: Variant, remote: bool) -> str | None:
    """Why a pipeline variant cannot run here (local runs only; a service checks its own)."""
    if variant.method != "pipeline" or remote:
        return None
    try:
        availability = resolve(variant.solver or "").sampler.available()
    except UnknownSolverError as error:
        return str(error)
    except Exception as error:  # a broken adapter must not stop the other runs
        return f"the adapter could not be loaded ({type(error).__name__}: {error})"
    return None if availability.ok else availability.reason or "not available"


def run_one(
    variant: Variant,
    scene: Scene,
    images: tuple[np.ndarray, np.ndarray],
    gt: np.ndarray | None,
    options: BenchOptions,
    runner: SceneRunner,
    cache: dict[str, tuple[str, RunOutput]] | None = None,
) -> Run:
    """Run one variant on one scene, score it and write its images; failures are recorded.

    Parameters
    ----------
    variant, scene
        What runs, on which scene.
    images
        The scene's left and right views as loaded.
    gt
        The stored ground truth, or None.
    options
        The bench options.
    runner
        Runs the pipeline variants (:func:`local_runner` or :func:`remote_runner`).
    cache
        Maps a pipeline config (JSON) to an earlier run of it on this scene, so the ablations'
        full method reuses the solver comparison's run of the same solver.

    Returns
    -------
    Run
        Status ok (scored, images written), skipped or failed, with the reason.
    """
    run = Run(
        scene=scene.name,
        experiment=variant.experiment,
        variant=variant.name,
        method=variant.method,
        solver=variant.solver,
        status="ok",
        paper=paper_figure(variant, scene.name),
    )
    reason = _skip_reason(variant, remote=options.url is not None)
    if reason is not None:
        run.status, run.reason = "skipped", reason
        return run
    left, right = images
    try:
        if variant.method == "pipeline":
            config = match_config(
                variant, scene, options, encoding_for(variant.solver or "", options)
            )
            run.config = config.model_dump(mode="json")
            key = config.model_dump_json()
            if cache is not None and key in cache:
                earlier, output = cache[key]
                run.reason = f"same configuration as {earlier}: figures and images reused"
            else:
                output = runner(scene, left, right, config)
                if cache is not None:
                    cache[key] = (variant.key, output)
        elif variant.method == "heidari":
            result = heidari(to_gray(left), to_gray(right), scene.max_disparity)
            output = RunOutput(result.disparity, result.seconds, info=result.info)
        else:
            result = sgbm(left, right, scene.max_disparity)
            output = RunOutput(result.disparity, result.seconds, info=result.info)
    except SolverUnavailableError as error:  # found out only when solving (e.g. licence size)
        run.status, run.reason = "skipped", str(error)
        return run
    except Exception as error:  # a benchmark records a failing run and carries on
        run.status, run.reason = "failed", f"{type(error).__name__}: {error}"
        return run
    run.seconds, run.levels, run.info = output.seconds, output.levels, output.info
    if variant.method != "pipeline" and options.url is not None:
        run.reason = "ran locally (baselines are not service jobs)"
    try:
        score(run, output.disparity, scene, gt)
    except ValueError as error:  # e.g. a border or mask that leaves no pixel, a wrong size
        run.status, run.reason = "failed", f"evaluation: {error}"
        return run
    write_images(run, output.disparity, scene, gt, options.out)
    return run


def select_scenes(options: BenchOptions) -> list[Scene]:
    """The scenes the bench runs on, with the protocol overrides applied.

    Parameters
    ----------
    options
        The dataset folder, the scenes asked for (None: all) and the protocol overrides.

    Returns
    -------
    list of Scene
        In the order asked for, else sorted by name.
    """
    found = find_scenes(
        options.dataset,
        scale=options.scale,
        border=options.border,
        max_disparity=None if options.max_disparity == AUTO else options.max_disparity,
    )
    if not found:
        raise BenchError(
            f"{options.dataset}: no scenes found (expected folders with left/right, "
            "im2/im6 or scene1.row3.col3/col4 images)"
        )
    if not options.scenes:
        return list(found.values())
    missing = [name for name in options.scenes if name.lower() not in found]
    if missing:
        raise BenchError(
            f"scene {', '.join(missing)} not in {options.dataset}; found {', '.join(found)}"
        )
    return [found[name.lower()] for name in options.scenes]


def run_bench(
    options: BenchOptions,
    log: Callable[[str], None] | None = None,
    command: Sequence[str] | None = None,
    progress: bool = False,
) -> dict:
    """Run every variant on every scene, write ``results.md``/``results.json``; return the data.

    Parameters
    ----------
    options
        What to run, where from and where to write.
    log
        Receives each finished run's line (default: stderr, above the progress bar).
    command
        The command line, recorded in the results.
    progress
        Show a progress bar on stderr (tqdm) with the run in hand.

    Returns
    -------
    dict
        The data written to ``results.json``.
    """
    from tqdm import tqdm

    chosen = variants(options)
    scenes = select_scenes(options)
    runner = remote_runner(options.url) if options.url else local_runner(options.processes)
    options.out.mkdir(parents=True, exist_ok=True)
    runs: list[Run] = []
    bar = tqdm(total=len(scenes) * len(chosen), unit="run", file=sys.stderr, disable=not progress)
    log = log or (lambda line: bar.write(line, file=sys.stderr))
    with bar:
        for scene in scenes:
            images = scene.load()
            gt = scene.ground_truth() if scene.gt is not None else None
            cache: dict[str, tuple[str, RunOutput]] = {}
            for variant in chosen:
                bar.set_description(f"{scene.name} {variant.key}")
                run = run_one(variant, scene, images, gt, options, runner, cache)
                runs.append(run)
                log(log_line(run))
                bar.update()
    results = {
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "version": qhsm_version(),  # each run's full config is in its "config"
        "command": list(command) if command is not None else None,
        "dataset": str(options.dataset),
        "url": options.url,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "options": {
            "solvers": options.solvers,
            "experiments": options.experiments,
            "ablation_solver": options.ablation_solver,
            "bundle_height": options.bundle_height,
            "encoding": options.encoding,
            "seed": options.seed,
            "solver_params": options.solver_params,
            "processes": options.processes,
        },
        "scenes": {scene.name: scene.protocol() for scene in scenes},
        "runs": [asdict(run) for run in runs],
        "averages": averages(runs),
        "paper": [
            {"solver": solver, "scene": scene, "rmse": fig.rmse, "bpp": fig.bpp}
            for (solver, scene), fig in PAPER_FIGURES.items()
        ],
    }
    (options.out / "results.json").write_text(json.dumps(results, indent=2, allow_nan=False))
    (options.out / "results.md").write_text(markdown(results))
    return results
