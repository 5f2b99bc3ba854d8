"""Stereo scenes with ground truth: the Middlebury copies beside the repo and synthetic scenes.

Modules, one job each:

* :mod:`~shared.datasets.scenes`: scene discovery: finding scenes and dataset folders on disk in
  the layouts we know (ours, Middlebury 2001/2003/2005/2006/2014, KITTI), each with its files,
  masks and non-occluded pixels;
* :mod:`~shared.datasets.protocols`: the evaluation protocols (ground-truth scale, ignored
  border, masks, disparity range; the PROVENANCE files' figures for the known scenes and
  datasets), the layouts, and how a scene's protocol is resolved;
* :mod:`~shared.datasets.download`: ``qhsm datasets fetch``: the registry of known Middlebury
  files with their sha256 and URLs, downloaded, verified and retried through pooch.
"""

from shared.datasets.download import (
    MANIFESTS,
    ChecksumMismatchError,
    FetchedFile,
    Manifest,
    RemoteFile,
    fetch,
)
from shared.datasets.protocols import (
    DEFAULT_MAX_DISPARITY,
    GT_CONSISTENCY_TOLERANCE,
    KNOWN_DATASETS,
    KNOWN_MAX_DISPARITY,
    KNOWN_PROTOCOLS,
    LAYOUT_BY_LEFT,
    LAYOUTS,
    MASK_FILES,
    MASKS,
    DatasetConvention,
    Layout,
)
from shared.datasets.scenes import (
    Scene,
    confirmed_by_right_view,
    default_middlebury_dir,
    find_datasets,
    find_scenes,
    load_scene,
)

__all__ = [
    "DEFAULT_MAX_DISPARITY",
    "GT_CONSISTENCY_TOLERANCE",
    "KNOWN_DATASETS",
    "KNOWN_MAX_DISPARITY",
    "KNOWN_PROTOCOLS",
    "LAYOUTS",
    "LAYOUT_BY_LEFT",
    "MANIFESTS",
    "MASKS",
    "MASK_FILES",
    "ChecksumMismatchError",
    "DatasetConvention",
    "FetchedFile",
    "Layout",
    "Manifest",
    "RemoteFile",
    "Scene",
    "confirmed_by_right_view",
    "default_middlebury_dir",
    "fetch",
    "find_datasets",
    "find_scenes",
    "load_scene",
]
