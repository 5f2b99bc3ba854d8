"""``qhsm datasets fetch``: the known Middlebury files, downloaded and checked through pooch.

:data:`MANIFESTS` is the registry: per dataset, every file's path below the official base URL,
where it goes below the target folder, and its sha256 where one is known. ``fetch`` turns a
manifest into a :class:`pooch.Pooch` (registry of hashes, one URL per file, retries over http) and
lets pooch download, verify and keep each file. ``mirror`` replaces the base URL (any mirror with
the same relative paths, e.g. ``file:///srv/middlebury/``). Files without a known checksum are
reported as *unverified*, never silently trusted under an invented checksum, and are downloaded
again on every fetch.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from urllib.request import urlopen

import pooch

#: Download attempts after a failed one over http(s) (pooch waits 1 s, 2 s, ... in between).
RETRIES = 2


@dataclass(frozen=True)
class RemoteFile:
    """One file of a dataset: where it lives below the base URL and where it goes below DIR.

    ``sha256`` is ``None`` where no checksum is known; such files are reported as unverified.
    """

    source: str
    target: str
    sha256: str | None = None


@dataclass(frozen=True)
class Manifest:
    name: str
    base_url: str
    files: tuple[RemoteFile, ...]
    note: str = ""

    def scenes(self) -> list[str]:
        return sorted({f.target.split("/")[0] for f in self.files})


# Checksums below are the sha256 of the copies in ../shared/data/middlebury (PROVENANCE.md):
# byte copies of the distributed files (Venus: identical to the members of the official zip).
# Everything else is unknown here and stays None (reported as unverified) until someone records
# the sha256 of an official download (`qhsm datasets fetch` prints them).
_2001 = "stereo/data/scenes2001/data/"
_2003 = "stereo/data/scenes2003/newdata/"
_EVAL = "stereo/eval/newEval/"
_MASK_SHA256 = {
    "tsukuba": {
        "nonocc": "826a3b8521c9fdcb8f05401e4676262c68d85251adbae1507e2c984c19d5b211",
        "all": "17630759fd7f99aba9b8d17ec66973974b30a938c9c542ce8ec4f497e3ea64ca",
        "disc": "5cc99c325e09f24f5f812ccd8022ea25014a2f85a84731c899199e26d3c16cfc",
    },
    "venus": {
        "nonocc": "fb2db205bb6a83e00fd360a1b7580886d2c65b6c2f4a0f43b36dc710d2eb2db6",
        "all": "47415362ed6c2ca7bd61d52f7cc68e858098b581b591dc0cb0fc019e331a70ba",
        "disc": "b449e1cdc7ed573f1c98e4359102b97a51761da8d3bc675cad45b3969005990d",
    },
    "cones": {
        "nonocc": "0fd35104fcc1acb21840a5a87187d571584fff3bf0b01bb5a087bc4a1e324d0f",
        "all": "d9a367fe82b2da6d1c91a8287804bace86b878bcac8bafcc43d011d11268be37",
        "disc": "b512f4ee425202a501dea3ca4aa666a33c541484d334659e705de9132bcc8008",
    },
}


def _masks(scene: str) -> list[RemoteFile]:
    known = _MASK_SHA256.get(scene, {})
    return [
        RemoteFile(f"{_EVAL}{scene}/{mask}.png", f"{scene}/{mask}.png", known.get(mask))
        for mask in ("nonocc", "all", "disc")
    ]


MANIFESTS: dict[str, Manifest] = {
    "middlebury2001": Manifest(
        name="middlebury2001",
        base_url="https://vision.middlebury.edu/",
        note="Scharstein & Szeliski 2001 scenes with the v2 evaluation masks (Tsukuba, Venus)",
        files=(
            RemoteFile(
                f"{_2001}tsukuba/scene1.row3.col3.ppm",
                "tsukuba/scene1.row3.col3.ppm",
                "1d326401c70e4bce95f0415a612dd00fa2984db89754f28d490b816aa731361a",
            ),
            RemoteFile(
                f"{_2001}tsukuba/scene1.row3.col4.ppm",
                "tsukuba/scene1.row3.col4.ppm",
                "c8048c2e0d834488adfae1c2525f4c004907b369dc90730ca11bf1f6dd8d925d",
            ),
            RemoteFile(
                f"{_2001}tsukuba/truedisp.row3.col3.pgm",
                "tsukuba/truedisp.row3.col3.pgm",
                "3192e1b8a1ad50fa6ac743cbe93aea54066bc93d2ebee432a04e7cd759450296",
            ),
            *_masks("tsukuba"),
            RemoteFile(
                f"{_2001}venus/im2.ppm",
                "venus/im2.ppm",
                "fef870c1e2471fe5b3b2bac9ca71810e8503e1489e4203288a982b40355b9172",
            ),
            RemoteFile(
                f"{_2001}venus/im6.ppm",
                "venus/im6.ppm",
                "b2fca7b6f3aa7e1a34bc5eac2d99cbbc5dfc77ce531777b71153e2ed73290004",
            ),
            RemoteFile(
                f"{_2001}venus/disp2.pgm",
                "venus/disp2.pgm",
                "7d7b78ba89b1a8b8973cfebd61f2ef35b5adec70b2fb50817c2bd66e06a10170",
            ),
            *_masks("venus"),
            *(
                RemoteFile(f"{_2001}{scene}/{file}", f"{scene}/{file}")
                for scene in ("sawtooth", "bull")
                for file in ("im2.ppm", "im6.ppm", "disp2.pgm")
            ),
        ),
    ),
    "middlebury2003": Manifest(
        name="middlebury2003",
        base_url="https://vision.middlebury.edu/",
        note="Scharstein & Szeliski 2003 quarter-size scenes with the v2 evaluation masks",
        files=(
            RemoteFile(
                f"{_2003}cones/im2.png",
                "cones/im2.png",
                "e9875cec273b9c7a36ab8a0556b5c8451dd90cf50b5c8f30f4ab3bc8f201da92",
            ),
            RemoteFile(
                f"{_2003}cones/im6.png",
                "cones/im6.png",
                "a3795d564445b1e041a88fec490d4140efec87c9a4c64c1b56f7240c3a4fc727",
            ),
            RemoteFile(
                f"{_2003}cones/disp2.png",
                "cones/disp2.png",
                "d082b192d7893ef597dfaa9af5c7fea9cb0196808be42d40b80fbf47bb96f561",
            ),
            *_masks("cones"),
            *(
                RemoteFile(f"{_2003}teddy/{file}", f"teddy/{file}")
                for file in ("im2.png", "im6.png", "disp2.png")
            ),
            *_masks("teddy"),
        ),
    ),
}


class ChecksumMismatchError(ValueError):
    """A downloaded file differs from the manifest's checksum (nothing is kept)."""


@dataclass(frozen=True)
class FetchedFile:
    """One file of a fetch: where it is, its sha256, and whether that was checked."""

    path: Path
    sha256: str
    status: str  # "verified", "unverified" (no known checksum) or "present" (already verified)


class _Downloader:
    """A pooch downloader for http(s) (pooch's own) and ``file://`` mirrors (copied here).

    It keeps the sha256 of the last download, so a checksum mismatch can name it.
    """

    def __init__(self, timeout: float) -> None:
        self.http = pooch.HTTPDownloader(timeout=timeout)
        self.timeout = timeout
        self.sha256 = ""

    def __call__(
        self, url: str, output_file: str, pooch_: pooch.Pooch, check_only: bool = False
    ) -> None:
        if url.startswith("file:"):
            with open(output_file, "wb") as out, urlopen(url, timeout=self.timeout) as response:
                shutil.copyfileobj(response, out)
        else:
            self.http(url, output_file, pooch_)
        self.sha256 = pooch.file_hash(output_file)


def _registry(files: tuple[RemoteFile, ...], base: str, directory: Path) -> pooch.Pooch:
    """The pooch of ``files``: named by their target, each with its URL below ``base``."""
    return pooch.create(
        path=directory,
        base_url=base,
        registry={f.target: f"sha256:{f.sha256}" if f.sha256 else None for f in files},
        urls={f.target: base + f.source for f in files},
        retry_if_failed=RETRIES if base.startswith(("http:", "https:")) else 0,
    )


@contextmanager
def _quiet_pooch() -> Iterator[None]:
    """Keep pooch's own "Downloading ..." lines off stderr: the caller reports every file."""
    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel("WARNING")
    try:
        yield
    finally:
        logger.setLevel(level)


def _unverified(remote: RemoteFile, target: Path) -> AbstractContextManager:
    """Files without a known checksum are downloaded again on every fetch."""
    return _set_aside(target) if remote.sha256 is None else nullcontext()


@contextmanager
def _set_aside(path: Path) -> Iterator[None]:
    """Move an unverified file out of pooch's way so it is downloaded again; put it back if
    the download fails."""
    if not path.is_file():
        yield
        return
    aside = path.with_name(f".{path.name}.previous")
    path.replace(aside)
    try:
        yield
    except BaseException:
        aside.replace(path)
        raise
    aside.unlink()


def fetch(
    name: str,
    directory: str | Path,
    *,
    mirror: str | None = None,
    scenes: list[str] | None = None,
    timeout: float = 60.0,
    progress: Callable[[FetchedFile], None] | None = None,
) -> list[FetchedFile]:
    """Download dataset ``name`` into ``directory/<scene>/`` and check the known checksums.

    A file already present with the expected checksum is not downloaded again. A checksum
    mismatch keeps nothing (a stale copy is deleted) and raises :class:`ChecksumMismatchError`.

    Parameters
    ----------
    name
        A key of :data:`MANIFESTS`.
    directory
        Where the scenes' folders go.
    mirror
        Replaces the manifest's base URL (same relative paths; ``file://`` works).
    scenes
        Only these scenes of the dataset (default: all).
    timeout
        Seconds an http(s) download may stall.
    progress
        Called with each file once it is in place.

    Returns
    -------
    list of FetchedFile
        Every file, in manifest order.

    Raises
    ------
    ValueError
        An unknown dataset or scene.
    ConnectionError
        A file could not be downloaded.
    ChecksumMismatchError
        A file differs from its known checksum.
    """
    if name not in MANIFESTS:
        raise ValueError(f"unknown dataset {name!r}; known datasets: {', '.join(MANIFESTS)}")
    manifest = MANIFESTS[name]
    wanted = manifest.files
    if scenes:
        unknown = set(scenes) - set(manifest.scenes())
        if unknown:
            raise ValueError(
                f"{name} has no scene {', '.join(sorted(unknown))}; "
                f"it has {', '.join(manifest.scenes())}"
            )
        wanted = tuple(f for f in wanted if f.target.split("/")[0] in scenes)
    base = (mirror or manifest.base_url).rstrip("/") + "/"
    directory = Path(directory)
    store = _registry(wanted, base, directory)
    download = _Downloader(timeout)
    fetched = []
    for remote in wanted:
        fetched.append(_fetch_one(store, remote, directory / remote.target, download))
        if progress is not None:
            progress(fetched[-1])
    return fetched


def _fetch_one(
    store: pooch.Pooch, remote: RemoteFile, target: Path, download: _Downloader
) -> FetchedFile:
    """One file through pooch, with this module's statuses and errors."""
    url = store.get_url(remote.target)
    if remote.sha256 and target.is_file() and pooch.file_hash(str(target)) == remote.sha256:
        return FetchedFile(target, remote.sha256, "present")
    try:
        with _quiet_pooch(), _unverified(remote, target):
            store.fetch(remote.target, downloader=download)
    except OSError as error:  # URLError and requests' errors are OSErrors
        raise ConnectionError(f"could not download {url}: {error}") from None
    except ValueError:  # pooch's hash check: the download was not kept
        target.unlink(missing_ok=True)
        raise ChecksumMismatchError(
            f"{url}: sha256 {download.sha256} differs from the expected "
            f"{remote.sha256}; the file was deleted (check the mirror)"
        ) from None
    if remote.sha256 is None:
        return FetchedFile(target, download.sha256, "unverified")
    return FetchedFile(target, remote.sha256, "verified")
