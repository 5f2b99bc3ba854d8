"""The ``qhsm`` commands that work on results rather than produce them: ``eval`` (scores
against ground truth), ``batch`` (a folder of pairs into one table) and ``depth`` (depth and
point clouds); :func:`register` adds them to the parser of :mod:`shared.cli`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from shared.exit_codes import EXIT_FAILED


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``eval``, ``batch`` and ``depth`` to the ``qhsm`` command's sub-parsers."""
    from shared.cli_options import (
        add_calib_option,
        add_json_option,
        add_match_options,
        add_processes_option,
    )

    evaluate = commands.add_parser("eval", help="score a disparity map against ground truth")
    evaluate.add_argument("disparity", help="disparity map to score (.pfm, .png x256, .npy)")
    evaluate.add_argument("ground_truth", help="ground truth (stored value = disparity x --scale)")
    evaluate.add_argument(
        "--scale",
        type=float,
        help="stored ground-truth value per pixel of disparity (default: from the format, PFM "
        "1, 16-bit PNG 256, or the scene folder's protocol; a warning when the given "
        "one contradicts them)",
    )
    evaluate.add_argument(
        "--border", type=int, help="ignored frame, pixels (default: the scene's, else 0)"
    )
    evaluate.add_argument("--mask", help="evaluate only where this mask is non-zero")
    evaluate.add_argument(
        "--threshold", type=float, default=1.0, help="bpp: error above which a pixel is bad, px"
    )
    evaluate.add_argument(
        "--nonocc",
        help="non-occluded pixels' mask (non-zero; default: a recognised scene's mask or its "
        "ground truth's left-right check)",
    )
    evaluate.add_argument(
        "--fg", help="foreground mask (KITTI's obj_map: non-zero = object): D1-bg and D1-fg"
    )
    evaluate.add_argument("--error-map", help="write |d - gt| here: .png (colours), .pfm or .npy")
    add_json_option(evaluate, "the scores")
    evaluate.set_defaults(handler=cmd_eval)

    batch = commands.add_parser(
        "batch", help="match every pair below a folder (scene folders or KITTI) into a table"
    )
    batch.add_argument(
        "folder", help="folder of scene folders (Middlebury layouts, ours) or KITTI's training/"
    )
    batch.add_argument("--out", default="out/batch", help="output folder (maps, results.csv/json)")
    add_match_options(batch)
    batch.add_argument(
        "--force", action="store_true", help="match pairs whose views fail their check too"
    )
    add_json_option(batch, "the table")
    add_processes_option(batch)
    batch.set_defaults(handler=cmd_batch)

    depth = commands.add_parser(
        "depth", help="depth map and coloured PLY point cloud from a disparity map"
    )
    depth.add_argument("disparity", help="disparity map (.pfm, .png x256, .npy)")
    depth.add_argument("-o", "--output", help="write the depth here (.pfm or .npy)")
    depth.add_argument("--ply", help="write a coloured point cloud here (binary PLY)")
    depth.add_argument("--image", help="the left view: the points' colours")
    depth.add_argument("--valid", help="only these pixels (e.g. qhsm match's d.valid.png)")
    add_calib_option(depth, "the cameras (else --focal, --baseline, ...)")
    depth.add_argument("--focal", type=float, help="focal length, px (without --calib)")
    depth.add_argument("--baseline", type=float, help="baseline, in --unit (without --calib)")
    depth.add_argument("--doffs", type=float, default=0.0, help="cx(right) - cx(left), px")
    depth.add_argument("--cx", type=float, help="principal point x, px (default: the centre)")
    depth.add_argument("--cy", type=float, help="principal point y, px (default: the centre)")
    depth.add_argument("--unit", default="mm", help="the baseline's unit (depth's)")
    add_json_option(depth, "what was written")
    depth.set_defaults(handler=cmd_depth)


def cmd_eval(args: argparse.Namespace) -> int:
    """``qhsm eval``: score the map ``disparity`` against ``ground_truth`` with Middlebury's and
    KITTI's measures, on every pixel and, where masks exist (``nonocc``, KITTI's object map
    ``fg``, a recognised scene's non-occluded pixels), per region; the scale and border default
    to the file's format or scene (:func:`shared.ground_truth.resolve_gt_scale`). Prints a table
    or (``json``) JSON; ``error_map`` writes |d - gt|; 0."""
    from shared.ground_truth import evaluate_ground_truth
    from shared.images import load_disparity, load_mask
    from shared.metrics import Truth

    disparity = load_disparity(args.disparity)
    mask = load_mask(args.mask) if args.mask else None
    result = evaluate_ground_truth(
        disparity,
        args.ground_truth,
        scale=args.scale,
        border=args.border,
        mask=mask,
        nonocc=load_mask(args.nonocc) if args.nonocc else None,
        foreground=load_mask(args.fg) if args.fg else None,
        threshold=args.threshold,
    )
    report = result.report()
    if args.error_map:
        errors = Truth(result.gt_values, result.scale, result.border, mask).error_map(disparity)
        report["error_map"] = write_error_map(errors, args.error_map, args.threshold)
    if args.json:
        print(json.dumps(report))
        return 0
    print(f"scale {result.scale:g} ({result.scale_source}), border {result.border}")
    header = ("region", "pixels", "rmse", "avgerr", "bad-0.5", "bad-1", "bad-2", "bad-4", "D1")
    print(("{:<8}" + " {:>8}" * 8).format(*header) + f" bad>{args.threshold:g}")
    for name, figures in result.scores.items():
        row = (figures.rmse, figures.avgerr, figures.bad_0_5, figures.bad_1, figures.bad_2)
        cells = [*row, figures.bad_4, figures.d1, figures.bpp]
        print(f"{name:<8} {figures.pixels:>8}" + "".join(f" {c:>8.3f}" for c in cells))
    if args.error_map:
        print(f"wrote {report['error_map']}")
    return 0


def write_error_map(errors, path: str, threshold: float) -> str:
    """Write |d - gt| to ``path``: ``.png`` colour-mapped (black: not evaluated, brightest at
    4x the bad-pixel threshold), ``.pfm`` / ``.npy`` the errors in pixels (NaN: not
    evaluated); returns the path."""
    from shared.bench.report import error_map_png
    from shared.cli_options import CommandError
    from shared.images import save_disparity

    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        Path(path).write_bytes(error_map_png(errors, 4 * threshold))
    elif suffix in (".pfm", ".npy"):
        save_disparity(errors, path)
    else:
        raise CommandError(f"{path}: the error map must end in .png, .pfm or .npy")
    return str(path)


def cmd_batch(args: argparse.Namespace) -> int:
    """``qhsm batch``: match every pair below ``folder`` into ``--out`` with the ``MatchConfig``
    options (:func:`shared.batch.run_batch`); prints the table (or ``json``) and where it is;
    0 when every pair matched, 1 when some failed (their rows say why)."""
    from shared.batch import COLUMNS, run_batch
    from shared.cli_options import config_from_args

    config = config_from_args(args)
    rows = run_batch(
        args.folder,
        args.out,
        config,
        range_given=args.max_disparity is not None,
        force=args.force,
        processes=args.processes,
    )
    if args.json:
        print(json.dumps(rows, indent=2, default=str))
    else:
        for row in rows:
            figures = "  ".join(f"{key} {row[key]:.3f}" for key in COLUMNS if key in row)
            state = row["status"] if row["status"] == "ok" else f"failed: {row['reason']}"
            print(
                f"{row['name']:<28} range {row.get('max_disparity', '-')} "
                f"({row['range_source']})  {figures}  {state}"
            )
        print(f"wrote {Path(args.out) / 'results.csv'} and results.json")
    return 0 if all(row["status"] == "ok" for row in rows) else EXIT_FAILED


def cmd_depth(args: argparse.Namespace) -> int:
    """``qhsm depth``: depth (Z = f B / (d + doffs)) and optionally a coloured PLY point cloud
    from the map ``disparity`` and a calibration file or ``--focal``/``--baseline`` options."""
    from shared.cli_options import CommandError
    from shared.datasets.calibration import Calibration, read_calibration
    from shared.depth import ply_bytes, point_cloud
    from shared.images import load_disparity, load_mask, load_view, save_disparity

    disparity = load_disparity(args.disparity)
    height, width = disparity.shape
    if args.calib:
        calibration = read_calibration(args.calib)
    elif args.focal and args.baseline:
        calibration = Calibration(
            args.focal,
            args.cx if args.cx is not None else (width - 1) / 2,
            args.cy if args.cy is not None else (height - 1) / 2,
            args.baseline,
            args.doffs,
            args.unit,
        )
    else:
        raise CommandError(
            "give --calib (Middlebury calib.txt, KITTI calib) or --focal and --baseline"
        )
    written: dict[str, str | int] = {}
    if args.output:
        written["depth"] = str(save_disparity(calibration.depth(disparity), args.output))
    if args.ply:
        image = load_view(args.image) if args.image else None
        if image is not None and image.shape[:2] != disparity.shape:
            raise CommandError(f"{args.image} is not the size of {args.disparity}")
        valid = load_mask(args.valid) if args.valid else None
        points, colours = point_cloud(disparity, calibration, image, valid)
        Path(args.ply).write_bytes(ply_bytes(points, colours))
        written["ply"] = str(args.ply)
        written["points"] = len(points)
    if not written:
        raise CommandError("nothing to write: give -o DEPTH.pfm|.npy and/or --ply CLOUD.ply")
    report = {**written, "unit": calibration.unit, "calibration": calibration.source}
    print(json.dumps(report) if args.json else f"wrote {', '.join(map(str, written.values()))}")
    return 0
