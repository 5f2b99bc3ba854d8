"""``qhsm submit-batch`` (a folder of pairs as one batch: ``POST /v1/batches``) and
``qhsm usage`` (your QPU budget in its period), the client commands beside :mod:`api.cli`."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from datetime import UTC, datetime

from api.cli_client import KEY_OPTION, api_client
from shared.cli_options import (
    CommandError,
    add_json_option,
    add_match_options,
    config_from_args,
    match_params,
    settings_from_args,
)


def register(commands: argparse._SubParsersAction, client_options: Callable[..., None]) -> None:
    """Add ``submit-batch`` and ``usage``; ``client_options`` adds --url and --key."""
    batch = commands.add_parser(
        "submit-batch",
        help="send every stereo pair below a folder (scene folders or KITTI's layout) as one "
        "batch (one job per pair, all or none)",
    )
    batch.add_argument("folder", help="what `qhsm batch` reads: scene folders or KITTI's layout")
    add_match_options(batch)
    batch.add_argument(
        "--tag",
        action="append",
        help="the batch's tag (default: batch-<UTC time>); more --tag add tags to every job",
    )
    batch.add_argument(
        "--per-job",
        action="store_true",
        help="send the pairs one request each (POST /v1/jobs), as before batches: a refused "
        "pair does not stop the ones sent before it",
    )
    add_json_option(batch, "the batch's id, tag and jobs")
    client_options(batch, json=False)
    batch.set_defaults(handler=cmd_submit_batch)

    usage = commands.add_parser(
        "usage", help="your QPU budget in its period (when it resets) and your jobs' charges"
    )
    add_json_option(usage, "GET /v1/usage's answer")
    client_options(usage, json=False)
    usage.set_defaults(handler=cmd_usage)


def cmd_submit_batch(args: argparse.Namespace) -> int:
    """``qhsm submit-batch FOLDER``: every pair below the folder as one job each, with its
    ground truth, its calibration file and its stated range (else the given one, else
    ``auto``), all under one batch id and tag."""
    from api.client import BatchPair
    from shared.batch import find_pairs

    config_from_args(args)  # refuse bad options before uploading anything
    params = match_params(args)
    try:
        pairs = find_pairs(args.folder)
    except FileNotFoundError as error:
        raise CommandError(str(error)) from None
    tags = args.tag or [f"batch-{datetime.now(UTC):%Y%m%d-%H%M%S}"]
    ranges = [params.get("max_disparity", pair.max_disparity or "auto") for pair in pairs]
    batch = [
        BatchPair(
            pair.left.read_bytes(),
            pair.right.read_bytes(),
            names=(pair.left.name, pair.right.name),
            name=pair.name,
            ground_truth=pair.gt.read_bytes() if pair.gt else None,
            gt_scale=pair.scale if pair.gt else None,
            gt_border=pair.border if pair.gt else None,
            calib=pair.calib.read_bytes() if pair.calib else None,
            max_disparity=top,
        )
        for pair, top in zip(pairs, ranges, strict=True)
    ]
    batch_id = None
    with api_client(args, key_source=KEY_OPTION) as client:
        if args.per_job:
            created = [
                client.submit(
                    p.left, p.right, {**params, "max_disparity": p.max_disparity},
                    ground_truth=p.ground_truth, gt_scale=p.gt_scale, gt_border=p.gt_border,
                    names=p.names, label=p.name, tags=tags, calib=p.calib,
                )
                for p in batch
            ]  # fmt: skip
        else:
            answer = client.submit_batch(batch, params, tags)
            batch_id, created = answer["id"], answer["jobs"]
    jobs = [
        {"name": pair.name, "id": job["id"], "max_disparity": top}
        for pair, job, top in zip(pairs, created, ranges, strict=True)
    ]
    base = settings_from_args(args).api_url.rstrip("/")
    listing = f"{base}/v1/jobs?tag={tags[0]}"
    batch_url = f"{base}/v1/batches/{batch_id}" if batch_id else None
    if args.json:
        print(json.dumps({"batch": batch_id, "tag": tags[0], "jobs": jobs, "url": listing,
                          "batch_url": batch_url}))  # fmt: skip
        return 0
    for job in jobs:
        print(f"{job['id']}  {job['name']}  (max disparity {job['max_disparity']})")
    where = f"batch {batch_id}: {batch_url}; " if batch_id else ""
    print(f"{len(jobs)} jobs tagged {tags[0]}: {where}{listing}", file=sys.stderr)
    return 0


def cmd_usage(args: argparse.Namespace) -> int:
    """``qhsm usage``: your budget in its period (admins: every user's) and your jobs'
    charges, as ``qhsm admin usage`` prints them."""
    from api.admin import print_usage

    with api_client(args, key_source=KEY_OPTION) as client:
        usage = client.usage()
    if args.json:
        print(json.dumps(usage, indent=2))
        return 0
    print_usage(usage["users"])
    return 0
