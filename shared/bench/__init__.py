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

Modules, one job each:

* :mod:`~shared.bench.experiments`: the experiments' variants, :class:`BenchOptions`, the
  pipeline configuration of a variant, the paper's known figures;
* :mod:`~shared.bench.scene_runners`: where a pipeline run happens (this process, a process
  pool, or a service through the ``qhsm.runners`` entry point);
* :mod:`~shared.bench.runner`: the bench loop (scene selection, one run per variant and scene,
  ``results.json``/``results.md``);
* :mod:`~shared.bench.scoring`: a run's record and figures under the scene's protocol, and the
  per-variant averages;
* :mod:`~shared.bench.report`: per-run images (preview, PFM, error map), log lines and the
  Markdown report;
* :mod:`~shared.bench.generalisation`: the generalisation benchmark (``benchmarks/
  generalisation.py``): named variants against the SGBM baseline on every scene found, with the
  range given, scored on the non-occluded pixels, runs side by side in a process pool.
"""

from shared.bench.experiments import (
    ABLATIONS,
    ACCURATE_ABLATIONS,
    BASELINES,
    DEFAULT_SOLVERS,
    EXPERIMENTS,
    PAPER_FIGURES,
    BenchError,
    BenchOptions,
    PaperFigure,
    Variant,
    match_config,
    paper_figure,
    parse_solver_params,
    split_names,
    variants,
)
from shared.bench.report import error_map_png, markdown
from shared.bench.runner import encoding_for, run_bench, run_one, select_scenes
from shared.bench.scene_runners import (
    RUNNER_GROUP,
    RemoteRunner,
    RunOutput,
    SceneRunner,
    local_runner,
    remote_runner,
)
from shared.bench.scoring import Run, averages

__all__ = [
    "ABLATIONS",
    "ACCURATE_ABLATIONS",
    "BASELINES",
    "DEFAULT_SOLVERS",
    "EXPERIMENTS",
    "PAPER_FIGURES",
    "RUNNER_GROUP",
    "BenchError",
    "BenchOptions",
    "PaperFigure",
    "RemoteRunner",
    "Run",
    "RunOutput",
    "SceneRunner",
    "Variant",
    "averages",
    "encoding_for",
    "error_map_png",
    "local_runner",
    "markdown",
    "match_config",
    "paper_figure",
    "parse_solver_params",
    "remote_runner",
    "run_bench",
    "run_one",
    "select_scenes",
    "split_names",
    "variants",
]
