"""The generalisation benchmark (issue 17): named matcher configurations against SGBM, every scene.

Every scene found below the given folders (by folder layout: :func:`shared.datasets.find_datasets`)
runs each pipeline variant and the SGBM baseline (:func:`shared.baselines.sgbm`) with the range
given: the ceil of its ground truth's maximum. The main figure is the bad-pixel percentage
(|d - gt| > 1 px) over the non-occluded pixels with known ground truth (the dataset's nonocc mask,
else the ground truth's own left-right check within 1 px:
:meth:`shared.datasets.Scene.non_occluded`; a scene with neither, e.g. KITTI, is scored on all its
pixels with known ground truth and says so); the all-pixel RMSE and BPP under the scene's
protocol (``qhsm eval`` semantics: ground-truth scale, ignored border) are kept beside it. Runs are
:class:`~shared.bench.scoring.Run` records made by :func:`shared.bench.runner.run_one`, as in
``qhsm bench``, spread over a process pool.

Variants are named ``MatchConfig`` changes: the registry :data:`VARIANTS` (the accurate preset
and the ablation of each of its steps; extend it there) or ``NAME=KEY:VALUE,KEY:VALUE`` on the
command line (:func:`parse_variant`). ``benchmarks/generalisation.py`` is the command;
:mod:`shared.bench.generalisation_report` compares the runs and writes the report.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import platform
import re
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import imagesize
from pydantic import ValidationError

from shared.baselines import SGBM_PARAMETERS
from shared.bench.experiments import ACCURATE_ABLATIONS, BenchError, BenchOptions, Variant
from shared.bench.generalisation_report import BASELINE, compare, markdown
from shared.bench.report import log_line
from shared.bench.runner import run_one
from shared.bench.scene_runners import local_runner
from shared.bench.scoring import Run
from shared.config import MatchConfig, Preset
from shared.datasets import Scene, find_datasets

EXPERIMENT = "generalisation"
#: Named variants: ``MatchConfig`` changes to the default (``preset``/``solver`` included).
#: The accurate preset's step ablations are ``qhsm bench``'s; both benchmarks read this one table.
VARIANTS: dict[str, dict[str, Any]] = ACCURATE_ABLATIONS
DEFAULT_VARIANTS = ("accurate",)
#: Runs side by side: one per core.
DEFAULT_PROCESSES = os.cpu_count() or 1
#: ``KEY:VALUE`` items are split at commas followed by the next ``KEY:`` (so JSON lists survive).
_ITEM_SPLIT = re.compile(r",\s*(?=[A-Za-z_][A-Za-z0-9_]*\s*:)")


def make_variant(name: str, changes: dict[str, Any]) -> Variant:
    """A pipeline variant of this benchmark: ``exact`` and the accurate preset unless changed.

    Parameters
    ----------
    name
        The variant's name in the tables.
    changes
        ``MatchConfig`` fields to change (``preset`` and ``solver`` included).

    Returns
    -------
    Variant
        Checked: the changes make a valid ``MatchConfig`` (else :class:`BenchError`).
    """
    if name == BASELINE:
        raise BenchError(f"{BASELINE!r} is the baseline's name; name the variant otherwise")
    overrides = dict(changes)
    preset = Preset(overrides.pop("preset", Preset.ACCURATE))
    solver = str(overrides.pop("solver", "exact"))
    try:
        MatchConfig.model_validate({"preset": preset, "solver": solver, **overrides})
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(map(str, e['loc'])) or 'config'}: {e['msg']}" for e in error.errors()
        )
        raise BenchError(f"variant {name}: {problems}") from None
    return Variant(EXPERIMENT, name, "pipeline", solver, overrides, preset)


def parse_variant(text: str) -> Variant:
    """A variant from the command line: ``NAME=KEY:VALUE,KEY:VALUE`` (or just ``NAME=``).

    Values are JSON where they parse (``median:false``, ``lr_tolerance:2``,
    ``levels:[...]``), else strings (``solver:sa``, ``data_term:squared``).

    Parameters
    ----------
    text
        The option's value.

    Returns
    -------
    Variant
        As :func:`make_variant` makes it.
    """
    name, sep, items = text.partition("=")
    name = name.strip()
    if not sep or not name:
        raise BenchError(f"--variant expects NAME=KEY:VALUE,KEY:VALUE, got {text!r}")
    changes: dict[str, Any] = {}
    for item in _ITEM_SPLIT.split(items.strip()) if items.strip() else []:
        key, colon, value = item.partition(":")
        if not colon or not key.strip():
            raise BenchError(f"--variant {name}: expected KEY:VALUE, got {item!r}")
        try:
            changes[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            changes[key.strip()] = value.strip()
    return make_variant(name, changes)


def named_variants(names: Iterable[str]) -> list[Variant]:
    """Variants from the registry :data:`VARIANTS`.

    Parameters
    ----------
    names
        Registry names.

    Returns
    -------
    list of Variant
        In the order given; an unknown name is a :class:`BenchError` listing the known ones.
    """
    unknown = [name for name in names if name not in VARIANTS]
    if unknown:
        raise BenchError(
            f"unknown variant {', '.join(unknown)}; the registry has {', '.join(VARIANTS)} "
            "(or give one as --variant NAME=KEY:VALUE,...)"
        )
    return [make_variant(name, VARIANTS[name]) for name in names]


def select_scenes(roots: Sequence[Path], names: Sequence[str] | None = None) -> list[Scene]:
    """The scenes with ground truth below ``roots``, named ``dataset/scene``, range given.

    Parameters
    ----------
    roots
        Folders of datasets, dataset folders or scene folders.
    names
        Scenes to keep (``dataset/scene`` or a scene name unique among those found); None: all.

    Returns
    -------
    list of Scene
        Sorted by qualified name, each with ``name`` = its qualified name and ``max_disparity``
        = :meth:`~shared.datasets.Scene.ground_truth_range`.
    """
    found: dict[str, Scene] = {}
    for root in roots:
        if not Path(root).is_dir():
            raise BenchError(f"{root}: no such directory")
        for scenes in find_datasets(root).values():
            for scene in scenes.values():
                if scene.gt is None:
                    continue
                if scene.qualified_name in found:
                    raise BenchError(f"scene {scene.qualified_name} is found twice: check --data")
                found[scene.qualified_name] = scene
    if not found:
        raise BenchError(
            f"no scene with ground truth below {', '.join(map(str, roots))} (expected scene "
            "folders with left/right/gt_left or the Middlebury file names)"
        )
    chosen = sorted(found)
    if names:
        chosen = [_resolve_name(name, found) for name in names]
    return [
        replace(
            found[key],
            name=key,
            max_disparity=found[key].ground_truth_range(),
        )
        for key in chosen
    ]


def _resolve_name(name: str, found: dict[str, Scene]) -> str:
    name = name.lower()
    if name in found:
        return name
    matches = [key for key, scene in found.items() if scene.name == name]
    if len(matches) == 1:
        return matches[0]
    if matches:
        raise BenchError(f"scene {name} is in several datasets: {', '.join(matches)}")
    raise BenchError(f"scene {name} not found; found {', '.join(sorted(found))}")


@dataclass
class Options:
    """What one generalisation run does."""

    data: list[Path]
    out: Path
    variants: list[Variant] = field(default_factory=lambda: named_variants(DEFAULT_VARIANTS))
    scenes: list[str] | None = None
    #: Processes running the runs side by side (1: all in this process).
    processes: int = DEFAULT_PROCESSES
    seed: int = MatchConfig.model_fields["seed"].default


def _bench_options(options: Options) -> BenchOptions:
    """The ``qhsm bench`` options :func:`run_one` reads (output folder, seed; the defaults else)."""
    return BenchOptions(dataset=options.data[0], out=options.out, seed=options.seed)


def _run(variant: Variant, scene: Scene, options: BenchOptions) -> Run:
    """One run, in whichever process it lands (top level, so a process pool can call it);
    a scene that cannot be read fails its runs, not the benchmark."""
    try:
        images, gt = scene.load(), scene.ground_truth()
    except Exception as error:  # as run_one: record the failure, carry on
        reason = f"loading the scene: {type(error).__name__}: {error}"
        return Run(
            scene.name, EXPERIMENT, variant.name, variant.method, variant.solver, "failed", reason
        )
    return run_one(variant, scene, images, gt, options, local_runner(1))


def _cost(scene: Scene) -> float:
    """Rough work of a pipeline run (pixels x range): the longest go first, so both cores stay
    busy to the end."""
    width, height = imagesize.get(str(scene.left))
    return float(width * height * scene.max_disparity)


def run_all(
    options: Options,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> tuple[list[Scene], list[Run], float]:
    """Every variant and the baseline on every scene.

    Parameters
    ----------
    options
        Scenes, variants, processes, output folder.
    progress
        Show a progress bar on stderr (tqdm).
    log
        Receives each finished run's line (default: stderr, above the bar).

    Returns
    -------
    tuple
        The scenes, the runs (scene by scene, variants in order, the baseline last) and the
        wall time of the whole run (s).
    """
    from tqdm import tqdm

    scenes = select_scenes(options.data, options.scenes)
    baseline = Variant(EXPERIMENT, BASELINE, BASELINE)
    chosen = [*options.variants, baseline]
    names = [variant.name for variant in chosen]
    if len(set(names)) != len(names):
        raise BenchError(f"variant names must differ: {', '.join(names)}")
    bench_options = _bench_options(options)
    options.out.mkdir(parents=True, exist_ok=True)
    jobs = [(variant, scene) for scene in scenes for variant in chosen]
    jobs.sort(key=lambda job: (job[0].method != "pipeline", -_cost(job[1])))
    done: dict[tuple[str, str], Run] = {}
    bar = tqdm(total=len(jobs), unit="run", file=sys.stderr, disable=not progress)
    log = log or (lambda line: bar.write(line, file=sys.stderr))
    started = time.perf_counter()

    def finished(run: Run) -> None:
        done[run.scene, run.variant] = run
        log(log_line(run))
        bar.update()

    with bar:
        if options.processes == 1:
            for variant, scene in jobs:
                bar.set_description(f"{scene.name} {variant.name}")
                finished(_run(variant, scene, bench_options))
        else:
            # spawn: forking a process that already runs threads (OpenCV, BLAS) can deadlock
            context = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(options.processes, mp_context=context) as pool:
                futures = [pool.submit(_run, v, s, bench_options) for v, s in jobs]
                for future in as_completed(futures):
                    finished(future.result())
    wall = time.perf_counter() - started
    runs = [done[scene.name, variant.name] for scene in scenes for variant in chosen]
    return scenes, runs, wall


def _variant_description(variant: Variant) -> dict[str, Any]:
    if variant.method != "pipeline":
        return {"method": variant.method, "parameters": SGBM_PARAMETERS}
    return {"preset": variant.preset.value, "solver": variant.solver, "changes": variant.overrides}


def results(
    options: Options,
    scenes: list[Scene],
    runs: list[Run],
    wall: float,
    command: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Everything a run measured, as ``results.json`` holds it.

    Parameters
    ----------
    options
        The run's options.
    scenes, runs, wall
        What :func:`run_all` returned.
    command
        The command line, recorded.

    Returns
    -------
    dict
        JSON-ready: the command, machine, wall time, scene protocols, variants, every run and
        the comparison (:func:`compare`).
    """
    return {
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "command": list(command) if command is not None else None,
        "data": [str(path) for path in options.data],
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        },
        "processes": options.processes,
        "wall_seconds": wall,
        "baseline": BASELINE,
        "variants": {
            v.name: _variant_description(v)
            for v in [*options.variants, Variant(EXPERIMENT, BASELINE, BASELINE)]
        },
        "scenes": {scene.name: scene.protocol() for scene in scenes},
        "runs": [asdict(run) for run in runs],
        "comparison": compare(runs),
    }


def run_benchmark(
    options: Options,
    command: Sequence[str] | None = None,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run everything, write ``OUT/results.json`` and ``OUT/results.md``; return the data.

    Parameters
    ----------
    options
        What to run.
    command
        The command line, recorded in the results.
    progress
        Show a progress bar on stderr.
    log
        Receives each finished run's line.

    Returns
    -------
    dict
        The data of ``results.json``.
    """
    scenes, runs, wall = run_all(options, progress=progress, log=log)
    data = results(options, scenes, runs, wall, command)
    (options.out / "results.json").write_text(json.dumps(data, indent=2, allow_nan=False))
    (options.out / "results.md").write_text(markdown(data))
    return data
