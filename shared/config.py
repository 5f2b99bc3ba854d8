"""Configuration: what one matching run needs (``MatchConfig``) and what a deployment reads from
the environment (``Settings``, defined in :mod:`shared.settings` and re-exported here).

``MatchConfig`` is the single description of a run. The CLI builds it from flags, the API
validates it from the ``params`` JSON of an upload, and the pipeline and the workers read it;
there is no second copy of these options anywhere.

Longer than most modules on purpose: each field carries the description and bounds that the CLI's
help, the API's schema and the error messages show, so they are written here once.
"""

from __future__ import annotations

import itertools
from enum import StrEnum
from typing import TYPE_CHECKING, Any, Final, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

if TYPE_CHECKING:  # re-exported lazily (__getattr__): `qhsm match` needs no pydantic-settings
    from shared.settings import (  # noqa: F401 (re-exported: one import path for configuration)
        Settings,
        default_data_dir,
        get_settings,
        seconds_field,
    )

#: What this module re-exports from :mod:`shared.settings` (one import path for configuration).
_SETTINGS_NAMES: Final = frozenset(
    {"Settings", "default_data_dir", "get_settings", "seconds_field"}
)


def __getattr__(name: str) -> Any:
    """The re-exports of :mod:`shared.settings`, imported on first use: it loads
    pydantic-settings, which the matcher's path (``qhsm match``) does not need."""
    if name in _SETTINGS_NAMES:
        import shared.settings

        return getattr(shared.settings, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class Regularizer(StrEnum):
    """Smoothness term between 4-neighbours."""

    TRUNCATED = "truncated"  # min(trunc, s|dp - dq|), times m across intensity edges (the paper)
    LINEAR = "linear"  # s|dp - dq|, not edge-aware (the paper's "L R" ablation)
    NONE = "none"  # data term only


class Preset(StrEnum):
    """A named set of defaults for the options that differ between the two methods."""

    ACCURATE = "accurate"  # bin pyramid, AD-census, both views + LR check, weighted median
    PAPER = "paper"  # the publication: image pyramid, squared difference, median + bilateral


class DataTerm(StrEnum):
    """How a pixel's cost for a disparity is measured."""

    SQUARED = "squared"  # (I_L - I_R)^2 of the gray images (the paper)
    AD_CENSUS = "ad-census"  # absolute colour difference + census Hamming distance, 5x5 aggregated
    CENSUS_GRADIENT = "census-gradient"  # census Hamming distance + gradient difference, 5x5


class PyramidKind(StrEnum):
    """What gets coarser from level to level."""

    IMAGE = "image"  # the images are downsampled; labels are disparities of the level (the paper)
    BINS = "bins"  # full-resolution images; labels are disparity bins that halve each level


class Inference(StrEnum):
    """Which MRF a level is and how it is minimised."""

    GRID = "grid"  # the 4-connected grid: dual decomposition into row and column chains (exact),
    # or 2D tiles with their neighbours' labels as unaries (QUBO solvers)
    ROWS = "rows"  # each bundle of rows alone, no edge between bundles (the paper)


class GridInference(StrEnum):
    """How ``exact`` minimises a level's grid: both over its row and column chains, with a bound."""

    DD = "dd"  # subgradient dual decomposition (Komodakis et al. 2007)
    TRWS = "trws"  # sequential tree-reweighted message passing (Kolmogorov 2006), then a polish


class Encoding(StrEnum):
    """How a pixel's label becomes binary variables."""

    ONE_HOT = "one-hot"
    DOMAIN_WALL = "domain-wall"


class Rectifier(StrEnum):
    """Penalty weight that enforces a valid encoding."""

    LOCAL = "local"  # one weight per pixel (chi_p / lambda_p), provably sufficient
    GLOBAL = "global"  # one weight for the whole bundle (the max of the local ones)


class LevelConfig(BaseModel):
    """One pyramid level's MRF. Defaults are the paper's full-resolution level.

    With the bin pyramid there is one entry, the template of every level: ``downsample`` is 1,
    ``candidates`` is the window of finer levels (the coarsest level takes every bin), and the
    smoothness is measured in bins.
    """

    model_config = ConfigDict(frozen=True, allow_inf_nan=False)

    downsample: int = Field(1, ge=1, description="Integer downsampling factor of this level")
    candidates: int = Field(4, ge=2, le=64, description="Candidate disparities per pixel")
    edge_threshold: float = Field(0.3, ge=0, description="|I(p)-I(q)| above which m applies")
    slope: float = Field(0.0005, ge=0, description="s in min(trunc, s|dp-dq|)")
    truncation: float = Field(300.0, ge=0, description="trunc in min(trunc, s|dp-dq|)")
    edge_factor: float = Field(0.1, ge=0, description="m: smoothness weight across edges")
    coarse_slope: float | None = Field(
        None,
        ge=0,
        description="Bin pyramid: s on the coarse_levels coarsest levels (unset: slope), where "
        "a bin spans several disparities and the data term is flatter",
    )
    coarse_levels: int = Field(
        3, ge=0, description="Bin pyramid: levels that take coarse_slope and coarse_prior"
    )
    coarse_prior: float = Field(
        0.0,
        ge=0,
        description="Bin pyramid: on the coarse_levels coarsest levels, this per bin a label lies "
        "outside its coarser level's bin (that bin's two children cost nothing), so that a large "
        "flat region keeps the bin the coarser level gave it unless its data disagree by more "
        "(0: none)",
    )
    finest_candidates: int | None = Field(
        None,
        ge=2,
        le=64,
        description="Bin pyramid: the finest level's window (bin width 1; unset: candidates), "
        "which only refines the two disparities of its coarser bin",
    )


def paper_levels() -> list[LevelConfig]:
    """The authors' pyramid: 1/4, 1/2 and full resolution with 6, 4, 4 candidates."""
    return [
        LevelConfig(
            downsample=4, candidates=6, edge_threshold=0.15, slope=0.0005, truncation=0.0015
        ),
        LevelConfig(
            downsample=2, candidates=4, edge_threshold=0.15, slope=0.0003, truncation=0.0015
        ),
        LevelConfig(downsample=1, candidates=4, edge_threshold=0.3, slope=0.0005, truncation=300.0),
    ]


def accurate_levels() -> list[LevelConfig]:
    """The bin pyramid's level template: 6 candidate bins (4 disparities at the finest level:
    its coarser bin's two and one either side), 0.1 per bin (0.2 on the three coarsest levels)
    capped at 0.4, times 0.3 across gray steps above 0.06; on the three coarsest levels 0.01 per
    bin outside the coarser level's bin (docs/benchmarks.md, "The coarse-to-fine prior")."""
    return [
        LevelConfig(
            downsample=1,
            candidates=6,
            finest_candidates=4,
            edge_threshold=0.06,
            slope=0.1,
            truncation=0.4,
            edge_factor=0.3,
            coarse_slope=0.2,
            coarse_levels=3,
            coarse_prior=0.01,
        )
    ]


#: The values a preset gives to the options it decides; anything the user sets wins.
PRESETS: dict[Preset, dict[str, Any]] = {
    Preset.ACCURATE: {
        "levels": accurate_levels,
        "pyramid": PyramidKind.BINS,
        "inference": Inference.GRID,
        "data_term": DataTerm.CENSUS_GRADIENT,
        "encoding": Encoding.DOMAIN_WALL,
        "median_size": 3,
        "bilateral": False,
        "lr_check": True,
        "weighted_median": True,
        "warm_start": None,
        "coarse_grid": 4,
    },
    Preset.PAPER: {
        "levels": paper_levels,
        "pyramid": PyramidKind.IMAGE,
        "inference": Inference.ROWS,
        "data_term": DataTerm.SQUARED,
        "encoding": Encoding.ONE_HOT,
        "median_size": 7,
        "bilateral": True,
        "lr_check": False,
        "weighted_median": False,
        "warm_start": False,
        "coarse_grid": 1,
    },
}

AUTO: Final = "auto"
#: The integer fields that also take ``auto`` (``bundle_width`` also None): their ranges.
AUTO_OR_WITHIN: Final = {"max_disparity": (1, 1024), "bundle_width": (8, 4096)}
#: Rows of a QUBO solver's tile in ``grid`` inference when ``bundle_height`` is not given.
GRID_TILE_ROWS: Final = 3


class MatchConfig(BaseModel):
    """Everything that determines the disparity map of one stereo pair.

    ``preset`` fills the options listed in :data:`PRESETS` that are not given; every option set
    explicitly overrides its preset value. A validated config always holds concrete values, so a
    stored config reproduces its run whatever the defaults become.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    preset: Preset = Field(
        Preset.ACCURATE,
        description="accurate: the 2D grid MRF of a disparity-bin pyramid (its coarse levels on "
        "a smaller grid, the two finest at full resolution), census + gradient cost, both "
        "views with a left-right check, weighted median, "
        "domain-wall bundles; paper: the publication's image pyramid, independent rows, squared "
        "difference, median + bilateral, one-hot bundles",
    )
    levels: list[LevelConfig] = Field(min_length=1, description="Pyramid levels (from preset)")
    pyramid: PyramidKind = Field(description="image or bins (from preset)")
    inference: Inference = Field(
        description="grid: the 4-connected MRF of each level (exact: dual decomposition into "
        "row and column chains, with a lower bound; QUBO solvers: tiles of bundle_height rows "
        "given their neighbours' labels); rows: every bundle alone (from preset)"
    )
    grid_inference: GridInference = Field(
        GridInference.DD,
        description="grid inference with exact: dd, subgradient dual decomposition into row "
        "and column chains; trws, TRW-S message passing over the same chains (a few passes "
        "to the same bound), its labels polished by the chain primal step",
    )
    dual_iterations: int = Field(
        60,
        ge=1,
        le=1000,
        description="grid inference with exact: most dual-decomposition iterations per level "
        "(fewer when the row and column chains agree or the gap is within dual_gap); with a "
        "QUBO solver and certify_tiles, of the host's settling of each level (no gap stop)",
    )
    dual_gap: float = Field(
        0.01,
        ge=0.0,
        lt=1.0,
        description="grid inference with exact: stop a level's dual decomposition once its "
        "certified gap (E - lower bound) / E is at most this (0: run dual_iterations)",
    )
    certify_tiles: bool = Field(
        True,
        description="grid inference with a QUBO solver: settle each level on the host first "
        "(dual decomposition of each whole view); only the 4x4 tiles around the pixels whose "
        "row and column chains disagree reach the solver, their other pixels pinned to the "
        "host's labels, and a tile's answer replaces the host's only where it lowers the "
        "level's energy (off: every bundle_height-row tile is sent)",
    )
    data_term: DataTerm = Field(description="squared, ad-census or census-gradient (from preset)")
    max_disparity: int | Literal["auto"] = Field(
        AUTO,
        description="Largest disparity in full-resolution pixels, or auto: estimated from "
        "a quick dense match of the two views",
    )
    max_coarse_bins: int = Field(
        8, ge=2, le=64, description="Bin pyramid: bins of the coarsest level, at most"
    )
    second_bins: int = Field(
        0,
        ge=0,
        le=16,
        description="Bin pyramid: levels, coarsest first, whose finer level also takes the "
        "children of each pixel's second-best bin (box-averaged data term, at least two bins "
        "from the chosen one), so a wrong coarse choice can be undone (0: off)",
    )
    second_bins_radius: int = Field(
        8, ge=0, le=64, description="The box radius, pixels, of second_bins' averaged costs"
    )
    coarse_grid: int = Field(
        ge=1,
        le=16,
        description="Bin pyramid: run the coarse levels on a smaller grid, a level of bin width "
        "w downsampled by min(coarse_grid, w / 4) (widths 4, 2 and 1 stay at full resolution): "
        "its data term the full-resolution bin costs averaged over each block, its smoothness "
        "divided by the factor, its map upsampled (nearest) to centre the finer level's "
        "windows (1: every level at full resolution) (from preset: accurate 4)",
    )
    bundle_height: int = Field(
        ge=1,
        le=64,
        description="Rows per QUBO bundle: with grid inference a tile's rows, their vertical "
        f"edges inside (unset: {GRID_TILE_ROWS}); with rows inference rows solved together, "
        "no edge to other bundles (unset: 1). exact solves single rows, or whole views by "
        "dual decomposition with grid inference",
    )
    bundle_width: int | Literal["auto"] | None = Field(
        None,
        description="Pixels per QUBO bundle along the row: an integer cuts rows into overlapping "
        "segments of that width, auto takes the widest segment whose QUBO embeds on the QPU "
        "graph; unset: the solver's default (auto for qpu and qpu-sim, whole rows otherwise)",
    )
    bundle_margin: int = Field(
        12, ge=0, le=256, description="Pixels by which neighbouring row segments overlap"
    )
    regularizer: Regularizer = Field(
        Regularizer.TRUNCATED,
        description="Smoothness term: the paper's truncated linear, its linear ablation, or none",
    )
    encoding: Encoding = Field(description="one-hot or domain-wall (from preset)")
    rectifier: Rectifier = Field(
        Rectifier.LOCAL, description="Encoding penalty weights: one per pixel, or one per bundle"
    )
    median: bool = Field(True, description="Median filter of every level's result")
    median_size: int = Field(ge=1, le=31, description="Its window (from preset)")
    bilateral: bool = Field(description="Final bilateral filter (from preset)")
    bilateral_diameter: int = Field(9, ge=1, le=31)
    bilateral_sigma_color: float = Field(4.0, gt=0, description="In disparity pixels")
    bilateral_sigma_space: float = Field(3.0, gt=0, description="In pixels")
    lr_check: bool = Field(
        description="Match the right view too; pixels failing the left-right check take the "
        "background's disparity (from preset)"
    )
    lr_tolerance: float = Field(1.0, ge=0, description="Left-right check tolerance, pixels")
    weighted_median: bool = Field(
        description="Colour-weighted median of the final map (from preset)"
    )
    weighted_median_radius: int = Field(9, ge=1, le=64)
    weighted_median_sigma: float = Field(25.5, gt=0, description="On the 0..255 colour scale")
    warm_start: bool | None = Field(
        description="Start every bundle from the best guess at hand (the coarser level's "
        "estimate; on the coarsest level the data term's minimum); unset: the solver's choice "
        "(on for the classical annealers and local searches, off for QPU and cloud solvers) "
        "(from preset)"
    )
    subpixel: bool = Field(
        False,
        description="Parabola fit on the final cost (bin pyramid): lower RMSE on slants, more "
        "1-px errors on integer ground truth",
    )
    solver: str = Field(
        "exact",
        description="Solver name, see `qhsm solvers`, or dimod:PACKAGE.MODULE.CLASS (any installed "
        "dimod sampler)",
    )
    seed: int = Field(0, ge=0, lt=2**32, description="Seeds every bundle's solver")
    solver_params: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="before")
    @classmethod
    def _apply_preset(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        try:
            preset = Preset(data.get("preset", Preset.ACCURATE))
        except ValueError:
            return data  # the field validator reports the bad name
        filled = dict(data)
        for name, value in PRESETS[preset].items():
            if filled.get(name) is None:
                filled[name] = value() if callable(value) else value
        if filled.get("bundle_height") is None:
            filled["bundle_height"] = GRID_TILE_ROWS if filled["inference"] == "grid" else 1
        return filled

    @field_validator("median_size")
    @classmethod
    def _odd(cls, value: int) -> int:
        if value % 2 == 0:
            raise ValueError("median_size must be odd")
        return value

    @field_validator(*AUTO_OR_WITHIN)
    @classmethod
    def _auto_or_within(cls, value: int | str | None, info: ValidationInfo) -> int | str | None:
        name = str(info.field_name)
        low, high = AUTO_OR_WITHIN[name]
        if isinstance(value, int) and not low <= value <= high:
            raise ValueError(f"{name} must be auto or an integer in {low}..{high}")
        return value

    @model_validator(mode="after")
    def _levels_coarse_to_fine(self) -> MatchConfig:
        if isinstance(self.bundle_width, int) and 2 * self.bundle_margin >= self.bundle_width:
            raise ValueError(
                f"bundle_margin ({self.bundle_margin}) must be below half the bundle_width "
                f"({self.bundle_width}): lower --bundle-margin or widen the segments"
            )
        if self.subpixel and self.pyramid is not PyramidKind.BINS:
            raise ValueError(
                "subpixel fits the final cost volume of the bin pyramid: use it with pyramid bins"
            )
        if self.pyramid is PyramidKind.BINS:
            if len(self.levels) != 1 or self.levels[0].downsample != 1:
                raise ValueError(
                    "the bin pyramid takes one level template with downsample 1 (its levels "
                    "follow from the disparity range)"
                )
            return self
        factors = [level.downsample for level in self.levels]
        for coarse, fine in itertools.pairwise(factors):
            if coarse != 2 * fine:
                raise ValueError(
                    f"levels must halve the downsampling factor each step, got {factors}"
                )
        return self
