"""``qhsm embeddings warm``: the residual design's tile shapes embedded ahead of time.

A QPU level sends 4x4 tiles (:mod:`shared.settle`) of one shape per candidate count; their
copies across the chip are translations of one embedding into a small defect-free sublattice
(:mod:`shared.solvers.qpu.tile_embedding`), which depends on the shape and the chip's family only.
This command computes those sublattice embeddings for the known chips (Advantage Pegasus P16,
Advantage2 Zephyr Z12 and Z15) into the store the workers read, so that a worker meeting the
shape on any such chip only translates it (seconds) instead of searching (its tries). Offline:
no D-Wave token is needed.
"""

from __future__ import annotations

import argparse

from shared.cli_options import CommandError, settings_from_args

#: Candidate counts warmed by default: the accurate preset's finer levels take 6 and its finest 4
#: (5 and 3 variables per pixel with domain-wall), a coarsest level of a small range 4 or 5.
DEFAULT_CANDIDATES = (4, 5, 6)


def register(commands: argparse._SubParsersAction) -> None:
    embeddings = commands.add_parser("embeddings", help="QPU tile embeddings kept for workers")
    actions = embeddings.add_subparsers(dest="embeddings_command", required=True)
    warm = actions.add_parser(
        "warm",
        help="embed the 4x4 tile shapes into the known chips' sublattices ahead of time",
    )
    warm.add_argument(
        "--candidates", type=int, nargs="+", default=list(DEFAULT_CANDIDATES),
        help="labels per pixel of the shapes to embed (default: 4 5 6)",
    )  # fmt: skip
    warm.add_argument(
        "--encoding", default="domain-wall", choices=["domain-wall", "one-hot"],
        help="the QUBO encoding the jobs use (default: domain-wall)",
    )  # fmt: skip
    warm.add_argument(
        "--chips", nargs="+",
        help="chips to embed for: P16 (Advantage), Z12, Z15 (Advantage2); default: all",
    )  # fmt: skip
    warm.add_argument(
        "--store", choices=["redis", "directory"],
        help="redis: the service's (QHSM_REDIS_URL), what its workers read; directory: "
        "QHSM_DATA_DIR/embeddings, what qhsm match reads (default: redis when QHSM_REDIS_URL "
        "is set, else directory)",
    )  # fmt: skip
    warm.set_defaults(handler=cmd_warm)


def cmd_warm(args: argparse.Namespace) -> int:
    from shared.settle import TILE
    from shared.solvers.qpu.bundle_shapes import shape_bqm
    from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingStore
    from shared.solvers.qpu.tile_embedding import KNOWN_CHIPS, warm

    settings = settings_from_args(args)
    where = args.store or ("redis" if settings.redis_url else "directory")
    store: EmbeddingStore
    if where == "redis":
        if settings.redis_url is None:
            raise CommandError("--store redis needs QHSM_REDIS_URL (the service's Redis)")
        from workers.embedding_store import for_settings

        store = for_settings(settings)
    else:
        store = DirectoryStore(settings.data_dir / "embeddings")
    if any(k < 2 for k in args.candidates):
        raise CommandError("--candidates: at least 2 labels per pixel")
    shapes = [shape_bqm(args.encoding, TILE, TILE, k) for k in args.candidates]
    unknown = sorted(set(args.chips or []) - set(KNOWN_CHIPS))
    if unknown:
        raise CommandError(
            f"--chips: unknown {', '.join(unknown)}; choose from {', '.join(KNOWN_CHIPS)}"
        )
    chips = {name: KNOWN_CHIPS[name] for name in args.chips or KNOWN_CHIPS}
    found = warm(store, shapes, settings.embedding_tries, chips, progress=print)
    for chip, variables, copies in found:
        print(f"{chip}: {variables}-variable tile shape, {copies} copies on the defect-free chip")
    print(f"stored in the {where} embedding store")
    return 0
