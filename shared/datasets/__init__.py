"""Stereo scenes with ground truth: the Middlebury copies beside the repo and synthetic scenes.

Modules, one job each:

* :mod:`~shared.datasets.scenes`: scene discovery: finding scenes on disk in the layouts we know
  (ours, Middlebury 2001/2003/2014), and each scene's evaluation protocol (ground-truth scale,
  ignored border, v2 masks, disparity range; PROVENANCE.md's figures for the known scenes);
* :mod:`~shared.datasets.download`: ``qhsm datasets fetch``: the registry of known Middlebury
  files with their sha256 and URLs, downloaded, verified and retried through pooch.
"""

from shared.datasets.download import (
    MANIFESTS,
    ChecksumMismatch,
    FetchedFile,
    Manifest,
    RemoteFile,
    fetch,
)
from shared.datasets.scenes import (
    DEFAULT_MAX_DISPARITY,
    KNOWN_MAX_DISPARITY,
    KNOWN_PROTOCOLS,
    LAYOUT_BY_LEFT,
    LAYOUTS,
    MASK_FILES,
    MASKS,
    Layout,
    Scene,
    default_middlebury_dir,
    find_scenes,
    load_scene,
)

__all__ = [
    "DEFAULT_MAX_DISPARITY",
    "KNOWN_MAX_DISPARITY",
    "KNOWN_PROTOCOLS",
    "LAYOUTS",
    "LAYOUT_BY_LEFT",
    "MANIFESTS",
    "MASKS",
    "MASK_FILES",
    "ChecksumMismatch",
    "FetchedFile",
    "Layout",
    "Manifest",
    "RemoteFile",
    "Scene",
    "default_middlebury_dir",
    "fetch",
    "find_scenes",
    "load_scene",
]
