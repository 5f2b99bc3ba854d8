"""``qhsm bench``: the paper's experiments on a folder of Middlebury-style scenes.

Experiments (each a list of variants run on every scene):

* ``accurate``: the default preset with ``--ablation-solver`` and the ablation of each of its
  steps (no left-right check, no weighted median, an image pyramid, the squared difference);
* ``solvers``: the paper's pipeline (``preset=paper``) with each requested solver (the paper's
  Gurobi / SA / hybrid / QPU table with what is available here; unavailable solvers are listed
  with the reason);
* ``ablations``: the paper's ablations with one solver: the full method, no regulariser, the
  linear regulariser, no bilateral filter, neither median nor bilateral filter;
* ``baselines``: Heidari et al. (exact per-row min-cut, cross-checked against the row DP) and
  OpenCV StereoSGBM with its invalid pixels filled (:mod:`shared.baselines`).

Every run is scored with :func:`shared.metrics.evaluate` under the scene's protocol (ground-truth
scale, ignored border; the main figures use every pixel with known ground truth outside the
border, as the paper's table does; the v2 masks ``nonocc``/``all``/``disc`` are scored as well
where the scene has them). Results go to ``OUT/results.md`` (tables, the paper's figures beside
ours), ``OUT/results.json`` (every figure) and per scene a disparity preview and an error map.

Remote runs (``--url``): the pipeline runs go through a running service. ``shared`` does not
import HTTP code; the service package provides a *runner* in the entry-point group
``qhsm.runners`` under the name ``http`` (used for http and https URLs). A runner is a callable

    runner(left: Path, right: Path, config: MatchConfig, url: str) -> RunOutput

returning a :class:`RunOutput` (or any object with ``disparity``, and optionally ``levels`` and
``seconds``; or a tuple ``(disparity, levels)``), where ``disparity`` is the full-resolution
left-view disparity in pixels and ``levels`` the per-level reports (dicts, as
``MatchResult.summary()["levels"]``). The baselines always run in this process.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

import cv2
import numpy as np

from shared.baselines import heidari, sgbm
from shared.config import (
    AUTO,
    DataTerm,
    MatchConfig,
    Preset,
    PyramidKind,
    Regularizer,
    accurate_levels,
    paper_levels,
)
from shared.datasets import Scene, find_scenes
from shared.images import preview_png, save_disparity, to_gray
from shared.metrics import error_map, evaluate
from shared.solvers import SolverUnavailable

EXPERIMENTS = ("accurate", "solvers", "ablations", "baselines")
#: The paper's solver table (Gurobi, SA, hybrid, QPU) plus the exact row DP.
DEFAULT_SOLVERS = ("exact", "gurobi", "sa", "hybrid", "qpu")
#: The paper's ablations: MatchConfig changes relative to the full method.
ABLATIONS: dict[str, dict[str, Any]] = {
    "full": {},
    "no-regularizer": {"regularizer": Regularizer.NONE},
    "linear-regularizer": {"regularizer": Regularizer.LINEAR},
    "no-bilateral": {"bilateral": False},
    "no-median-no-bilateral": {"median": False, "bilateral": False},
}
#: The accurate preset's ablations: each of its steps switched back to the paper's choice.
ACCURATE_ABLATIONS: dict[str, dict[str, Any]] = {
    "accurate": {},
    "no-lr-check": {"lr_check": False},
    "no-weighted-median": {"weighted_median": False},
    "image-pyramid": {
        "pyramid": PyramidKind.IMAGE,
        "levels": [
            accurate_levels()[0].model_copy(
                update={"downsample": level.downsample, "candidates": level.candidates}
            )
            for level in paper_levels()
        ],
    },
    "squared-difference": {"data_term": DataTerm.SQUARED},
}
BASELINES = ("heidari", "sgbm")
RUNNER_GROUP = "qhsm.runners"
#: Errors above this many pixels saturate the error-map colours.
ERROR_MAP_MAX = 4.0


@dataclass(frozen=True)
class PaperFigure:
    rmse: float | None
    bpp: float | None


#: Figures from the paper's table that we know; everything else is "n/a" (never guessed).
#: Protocol: all pixels with known ground truth outside the border (Tsukuba 18 px, Venus 10 px).
PAPER_FIGURES: dict[tuple[str, str], PaperFigure] = {
    ("gurobi", "tsukuba"): PaperFigure(1.53, 12.93),
    ("gurobi", "venus"): PaperFigure(0.96, 8.16),
    ("sa", "tsukuba"): PaperFigure(1.87, None),
}


class BenchError(ValueError):
    """A user-facing problem with the bench's arguments or environment."""


@dataclass
class RunOutput:
    """What running one scene produced: full-resolution disparity (px) and per-level reports."""

    disparity: np.ndarray
    seconds: float
    levels: list[dict] = field(default_factory=list)
    info: dict = field(default_factory=dict)


class RemoteRunner(Protocol):
    """Entry point ``qhsm.runners:http``: run one scene through the service at ``url``."""

    def __call__(self, left: Path, right: Path, config: MatchConfig, url: str) -> Any: ...


@dataclass
class Variant:
    """One configuration run on every scene: a pipeline config, or a baseline method."""

    experiment: str
    name: str
    method: str  # "pipeline", "heidari" or "sgbm"
    solver: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    preset: Preset = Preset.PAPER

    @property
    def key(self) -> str:
        return f"{self.experiment}/{self.name}"


@dataclass
class Run:
    """The outcome of one variant on one scene (``status``: ok, skipped or failed)."""

    scene: str
    experiment: str
    variant: str
    method: str
    solver: str | None
    status: str
    reason: str = ""
    rmse: float | None = None
    bpp: float | None = None
    pixels: int | None = None
    masks: dict[str, dict[str, float]] = field(default_factory=dict)
    seconds: float | None = None
    levels: list[dict] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    paper: dict | None = None
    files: dict[str, str] = field(default_factory=dict)
    config: dict | None = None


@dataclass
class BenchOptions:
    """Everything ``qhsm bench`` was asked to do."""

    dataset: Path
    out: Path
    scenes: list[str] | None = None
    solvers: list[str] = field(default_factory=lambda: list(DEFAULT_SOLVERS))
    experiments: list[str] = field(default_factory=lambda: list(EXPERIMENTS))
    ablation_solver: str = "exact"
    url: str | None = None
    bundle_height: int = 1
    encoding: str | None = None  # None: the solver's recommended one, else the preset's
    seed: int = 0
    solver_params: dict[str, dict[str, Any]] = field(default_factory=dict)
    processes: int = 0
    scale: float | None = None
    border: int | None = None
    max_disparity: int | str | None = None  # None: each scene's protocol; "auto": estimated


def parse_solver_params(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``[SOLVER:]KEY=VALUE`` items (JSON values) as {solver or "*": {key: value}}."""
    params: dict[str, dict[str, Any]] = {}
    for item in items:
        assignment, sep, _ = item.partition("=")
        if not sep or not assignment:
            raise BenchError(f"--param expects [SOLVER:]KEY=VALUE, got {item!r}")
        solver, colon, key = assignment.rpartition(":")
        value = item[len(assignment) + 1 :]
        try:
            parsed = json.loads(value)
        except json.JSONDecodeError:
            parsed = value
        params.setdefault(solver if colon else "*", {})[key] = parsed
    return params


def split_names(text: str | None) -> list[str] | None:
    """``"a, b"`` -> ``["a", "b"]``; ``None`` stays ``None``."""
    if text is None:
        return None
    return [name.strip() for name in text.split(",") if name.strip()]


def variants(options: BenchOptions) -> list[Variant]:
    """The runs each scene gets, in table order."""
    unknown = set(options.experiments) - set(EXPERIMENTS)
    if unknown:
        raise BenchError(
            f"unknown experiment {', '.join(sorted(unknown))}; choose from {', '.join(EXPERIMENTS)}"
        )
    chosen: list[Variant] = []
    if "accurate" in options.experiments:
        chosen += [
            Variant("accurate", name, "pipeline", options.ablation_solver, changes, Preset.ACCURATE)
            for name, changes in ACCURATE_ABLATIONS.items()
        ]
    if "solvers" in options.experiments:
        chosen += [Variant("solvers", name, "pipeline", name) for name in options.solvers]
    if "ablations" in options.experiments:
        chosen += [
            Variant("ablations", name, "pipeline", options.ablation_solver, changes)
            for name, changes in ABLATIONS.items()
        ]
    if "baselines" in options.experiments:
        chosen += [Variant("baselines", name, name) for name in BASELINES]
    return chosen


def encoding_for(solver: str, options: BenchOptions) -> str | None:
    """The asked-for encoding, else the solver's recommended one (the registry's: domain-wall
    for the annealers), else None: the run's preset decides."""
    from shared.solvers.registry import recommended_encoding

    return options.encoding or recommended_encoding(solver)


def match_config(variant: Variant, scene: Scene, options: BenchOptions) -> MatchConfig:
    assert variant.solver is not None
    return MatchConfig(
        preset=variant.preset,
        solver=variant.solver,
        max_disparity=AUTO if options.max_disparity == AUTO else scene.max_disparity,
        bundle_height=options.bundle_height,
        encoding=encoding_for(variant.solver, options),
        seed=options.seed,
        solver_params={
            **options.solver_params.get("*", {}),
            **options.solver_params.get(variant.solver, {}),
        },
        **variant.overrides,
    )


def paper_figure(variant: Variant, scene: str) -> dict | None:
    """The paper's figure for this run, if known; ``source`` says which of the paper's rows.

    The exact row DP is the optimum of single-row bundles, so it sits beside the paper's Gurobi
    (optimal) figures; the ablations' full method beside its solver's.
    """
    if variant.method != "pipeline" or variant.name not in (variant.solver, "full"):
        return None
    solver = "gurobi" if variant.solver == "exact" else variant.solver
    figure = PAPER_FIGURES.get((solver or "", scene))
    if figure is None:
        return None
    return {"rmse": figure.rmse, "bpp": figure.bpp, "source": solver}


# --- running ---------------------------------------------------------------------------------

SceneRunner = Callable[[Scene, np.ndarray, np.ndarray, MatchConfig], RunOutput]


def local_runner(processes: int = 0) -> SceneRunner:
    """Run the one pipeline here: ``processes`` 1 in this process, else a local process pool
    (0: one process per core)."""
    from shared.pipeline import run_pipeline

    def run(scene: Scene, left: np.ndarray, right: np.ndarray, config: MatchConfig) -> RunOutput:
        if processes != 1:
            from shared.solve import ProcessPoolLevelSolver

            with ProcessPoolLevelSolver(processes) as solve_level:
                result = run_pipeline(left, right, config, solve_level)
        else:
            result = run_pipeline(left, right, config)
        summary = result.summary()
        return RunOutput(
            result.disparity,
            result.seconds,
            summary["levels"],
            info={"disparity_range": summary["max_disparity"]},
        )

    return run


def remote_runner(url: str) -> SceneRunner:
    """Resolve the service's runner from the ``qhsm.runners`` entry points (see module doc)."""
    scheme = urlsplit(url).scheme.lower()
    if scheme not in ("http", "https"):
        raise BenchError(f"--url must be an http(s) URL, got {url!r}")
    found = entry_points(group=RUNNER_GROUP, name="http")
    if not found:
        raise BenchError(
            "--url needs the service package installed: no 'http' runner is registered in the "
            f"entry-point group {RUNNER_GROUP!r} (pip install -e . in the repository)"
        )
    runner: RemoteRunner = next(iter(found)).load()

    def run(scene: Scene, left: np.ndarray, right: np.ndarray, config: MatchConfig) -> RunOutput:
        started = time.perf_counter()
        outcome = runner(scene.left, scene.right, config, url)
        return _as_output(outcome, time.perf_counter() - started)

    return run


def _as_output(outcome: Any, elapsed: float) -> RunOutput:
    """Accept the runner return shapes documented in the module docstring."""
    if isinstance(outcome, RunOutput):
        return outcome
    if isinstance(outcome, tuple):
        disparity, levels = outcome
        return RunOutput(np.asarray(disparity, np.float32), elapsed, list(levels))
    levels = getattr(outcome, "levels", [])
    levels = [level if isinstance(level, dict) else asdict(level) for level in levels]
    seconds = getattr(outcome, "seconds", None)
    return RunOutput(
        np.asarray(outcome.disparity, np.float32), elapsed if seconds is None else seconds, levels
    )


def _skip_reason(variant: Variant, remote: bool) -> str | None:
    """Why a pipeline variant cannot run here (local runs only; a service checks its own)."""
    from shared.solvers import UnknownSolver, get_solver

    if variant.method != "pipeline" or remote:
        return None
    try:
        availability = get_solver(variant.solver or "").available()
    except UnknownSolver as error:
        return str(error)
    except Exception as error:  # a broken adapter must not stop the other runs
        return f"the adapter could not be loaded ({type(error).__name__}: {error})"
    return None if availability.ok else availability.reason or "not available"


def _score(run: Run, disparity: np.ndarray, scene: Scene, gt: np.ndarray | None) -> None:
    if gt is None:
        return
    main = evaluate(disparity, gt, scale=scene.scale, border=scene.border)
    run.rmse, run.bpp, run.pixels = main.rmse, main.bpp, main.pixels
    for name in sorted(scene.masks):
        mask = scene.mask(name)
        run.masks[name] = evaluate(
            disparity, gt, scale=scene.scale, border=scene.border, mask=mask
        ).as_dict()


def _write_images(
    run: Run, disparity: np.ndarray, scene: Scene, gt: np.ndarray | None, out: Path
) -> None:
    folder = out / scene.name
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{run.experiment}-{run.variant}"
    preview = folder / f"{stem}.png"
    preview.write_bytes(preview_png(disparity, scene.max_disparity))
    raw = save_disparity(disparity, folder / f"{stem}.pfm")
    run.files = {"preview": _relative(preview, out), "disparity": _relative(raw, out)}
    if gt is not None:
        errors = folder / f"{stem}-error.png"
        errors.write_bytes(error_map_png(error_map(disparity, gt, scene.scale, scene.border)))
        run.files["error_map"] = _relative(errors, out)


def _relative(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix()


def error_map_png(errors: np.ndarray, saturation: float = ERROR_MAP_MAX) -> bytes:
    """PNG of |d - gt| (px): black where not evaluated, inferno colours up to ``saturation``."""
    known = np.isfinite(errors)
    scaled = np.clip(np.where(known, errors, 0.0) / saturation, 0.0, 1.0)
    colours = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
    colours[~known] = 0
    ok, buf = cv2.imencode(".png", colours)
    if not ok:
        raise RuntimeError("OpenCV could not encode the error map")
    return buf.tobytes()


def run_one(
    variant: Variant,
    scene: Scene,
    images: tuple[np.ndarray, np.ndarray],
    gt: np.ndarray | None,
    options: BenchOptions,
    runner: SceneRunner,
    cache: dict[str, tuple[str, RunOutput]] | None = None,
) -> Run:
    """Run one variant on one scene; failures are recorded, not raised.

    ``cache`` maps a pipeline config (JSON) to an earlier run of it on this scene, so the
    ablations' full method reuses the solver comparison's run of the same solver.
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
            config = match_config(variant, scene, options)
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
            result = sgbm(to_gray(left), to_gray(right), scene.max_disparity)
            output = RunOutput(result.disparity, result.seconds, info=result.info)
    except SolverUnavailable as error:  # found out only when solving (e.g. licence size)
        run.status, run.reason = "skipped", str(error)
        return run
    except Exception as error:  # a benchmark records a failing run and carries on
        run.status, run.reason = "failed", f"{type(error).__name__}: {error}"
        return run
    run.seconds, run.levels, run.info = output.seconds, output.levels, output.info
    if variant.method != "pipeline" and options.url is not None:
        run.reason = "ran locally (baselines are not service jobs)"
    try:
        _score(run, output.disparity, scene, gt)
    except ValueError as error:  # e.g. a border or mask that leaves no pixel, a wrong size
        run.status, run.reason = "failed", f"evaluation: {error}"
        return run
    _write_images(run, output.disparity, scene, gt, options.out)
    return run


def select_scenes(options: BenchOptions) -> list[Scene]:
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

    ``progress`` shows a progress bar on stderr (tqdm) with the run in hand; each finished
    run's line goes to ``log`` (default: stderr, above the bar)."""
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
                log(_log_line(run))
                bar.update()
    results = {
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
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


def _log_line(run: Run) -> str:
    head = f"{run.scene} {run.experiment}/{run.variant}:"
    if run.status != "ok":
        return f"{head} {run.status} ({run.reason})"
    line = f"{head} RMSE {_fmt(run.rmse)} BPP {_fmt(run.bpp)} in {_fmt(run.seconds)} s"
    found = run.info.get("disparity_range")
    if found and found["source"] != "given":
        line += f" (range {found['max_disparity']} px, {found['source']})"
    return line


# --- reporting -------------------------------------------------------------------------------


def averages(runs: list[Run]) -> list[dict]:
    """Mean RMSE, BPP, per-mask BPP and wall time per variant over the scenes that ran."""
    table: list[dict] = []
    keys = list(dict.fromkeys((run.experiment, run.variant) for run in runs))
    for experiment, variant in keys:
        done = [
            r
            for r in runs
            if (r.experiment, r.variant) == (experiment, variant)
            and r.status == "ok"
            and r.rmse is not None
        ]
        if not done:
            continue
        masks = sorted(set.intersection(*(set(r.masks) for r in done)))
        table.append(
            {
                "experiment": experiment,
                "variant": variant,
                "scenes": [r.scene for r in done],
                "rmse": _mean(r.rmse for r in done),
                "bpp": _mean(r.bpp for r in done),
                "seconds": _mean(r.seconds for r in done),
                "masks": {
                    name: {
                        "rmse": _mean(r.masks[name]["rmse"] for r in done),
                        "bpp": _mean(r.masks[name]["bpp"] for r in done),
                    }
                    for name in masks
                },
            }
        )
    return table


def _mean(values) -> float:
    values = [float(v) for v in values]
    return float(np.mean(values))


def _fmt(value: float | None, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}f}"


TABLE_HEADER = (
    "| scene | variant | RMSE | BPP % | RMSE nonocc | BPP nonocc % | BPP disc % | wall s "
    "| paper RMSE | paper BPP % | note |\n"
    "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"
)


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown(results: dict) -> str:
    """The Markdown report: one table per experiment, per-scene rows and each variant's average."""
    lines = [
        "# qhsm bench results",
        "",
        f"Dataset `{results['dataset']}`, created {results['created']}"
        + (f", service {results['url']}" if results["url"] else ", in process")
        + f"; machine: {results['machine']['platform']}, {results['machine']['cpus']} CPUs.",
    ]
    if results["command"]:
        lines += ["", "Command: `" + " ".join(results["command"]) + "`"]
    lines += [
        "",
        "Protocol: left-view disparity; RMSE and BPP (|d - gt| > 1 px, in %) over every pixel "
        "with known ground truth outside the scene's border; *nonocc*/*disc* columns use the "
        "v2 evaluation masks where the scene has them. Wall time is the whole run of the scene. "
        "Paper figures: n/a where unknown.",
        "",
        "| scene | layout | GT scale | border px | max disparity | masks |",
        "|---|---|---:|---:|---:|---|",
    ]
    for name, protocol in results["scenes"].items():
        lines.append(
            _row(
                [
                    name,
                    protocol["layout"],
                    f"{protocol['scale']:g}",
                    str(protocol["border"]),
                    str(protocol["max_disparity"]),
                    ", ".join(protocol["masks"]) or "none",
                ]
            )
        )
    averages_by_key = {(a["experiment"], a["variant"]): a for a in results["averages"]}
    for experiment in dict.fromkeys(run["experiment"] for run in results["runs"]):
        lines += ["", f"## {experiment}", "", TABLE_HEADER]
        runs = [run for run in results["runs"] if run["experiment"] == experiment]
        for variant in dict.fromkeys(run["variant"] for run in runs):
            for run in (r for r in runs if r["variant"] == variant):
                lines.append(_row(_run_cells(run)))
            average = averages_by_key.get((experiment, variant))
            if average is not None and len(results["scenes"]) > 1:
                lines.append(_row(_average_cells(average)))
    lines += ["", "Known figures of the paper (the rest of its table is not reproduced here):", ""]
    lines += ["| solver | scene | RMSE | BPP % |", "|---|---|---:|---:|"]
    for figure in results["paper"]:
        lines.append(
            _row([figure["solver"], figure["scene"], _fmt(figure["rmse"]), _fmt(figure["bpp"])])
        )
    return "\n".join(lines) + "\n"


def _run_cells(run: dict) -> list[str]:
    nonocc, disc = run["masks"].get("nonocc", {}), run["masks"].get("disc", {})
    paper = run["paper"] or {}
    note = run["reason"]
    if run["status"] != "ok":
        note = f"{run['status']}: {note}"
    if paper and paper.get("source") != run["solver"]:
        note = (note + "; " if note else "") + f"paper figure is {paper['source']}'s"
    return [
        run["scene"],
        run["variant"],
        _fmt(run["rmse"]),
        _fmt(run["bpp"]),
        _fmt(nonocc.get("rmse")),
        _fmt(nonocc.get("bpp")),
        _fmt(disc.get("bpp")),
        _fmt(run["seconds"]),
        _fmt(paper.get("rmse")),
        _fmt(paper.get("bpp")),
        note.replace("|", "/").replace("\n", " "),
    ]


def _average_cells(average: dict) -> list[str]:
    masks = average["masks"]
    return [
        "**average**",
        average["variant"],
        _fmt(average["rmse"]),
        _fmt(average["bpp"]),
        _fmt(masks.get("nonocc", {}).get("rmse")),
        _fmt(masks.get("nonocc", {}).get("bpp")),
        _fmt(masks.get("disc", {}).get("bpp")),
        _fmt(average["seconds"]),
        "n/a",
        "n/a",
        f"over {', '.join(average['scenes'])}",
    ]
