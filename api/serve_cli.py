"""``qhsm serve``, ``qhsm demo`` and ``qhsm api``: the commands that start the service in this
process (their parsers are in :mod:`api.cli`, beside the client commands)."""

from __future__ import annotations

import argparse
import sys

from shared.cli_options import CommandError, settings_from_args
from shared.config import Settings
from shared.exit_codes import EXIT_INTERRUPTED


def cmd_api(args: argparse.Namespace) -> int:
    """The API alone, in this thread (stopped within seconds of SIGTERM or Ctrl-C)."""
    from api.server import stoppable_server

    stoppable_server(settings_from_args(args), args.log_level).run()
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    import logging

    from api.server import PortBusyError, bind_api_socket, once, stoppable_server
    from workers.embedded_redis import DataDirBusyError
    from workers.supervisor import Stack, WorkerStartError

    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    settings = settings_from_args(args)
    try:  # the port first: a busy one fails before Redis and workers start
        sock = bind_api_socket(settings.api_host, settings.api_port)
    except PortBusyError as error:
        raise CommandError(str(error)) from None
    stack = Stack(settings, concurrency=args.worker_concurrency)
    stop = once(stack.stop)  # here at the end, or by the API's stop if a request holds it
    print("starting Redis and workers ...", file=sys.stderr)
    try:
        try:
            stack.launch()
            settings = stack.settings
            # the API is built (its imports, the app) while the workers boot, which takes
            # longer; it serves only once they all answer
            server = stoppable_server(settings, args.log_level, cleanup=stop)
            stack.wait_ready()
        except (DataDirBusyError, WorkerStartError) as error:
            raise CommandError(str(error)) from None
        print(f"data directory: {settings.data_dir.resolve()} (QHSM_DATA_DIR)", file=sys.stderr)
        print(stack.describe(), file=sys.stderr)
        url = f"http://{settings.api_host}:{settings.api_port}"
        print(f"API on {url} (docs: /docs); Ctrl-C stops", file=sys.stderr)
        announce_web_page(settings, url)
        server.run(sockets=[sock])
    except KeyboardInterrupt:  # Ctrl-C is how serve is stopped (uvicorn re-raises it)
        print("qhsm serve: stopping the workers and Redis ...", file=sys.stderr)
    finally:
        stop()
        sock.close()
    return 0


def sign_in_url(url: str, host: str, key: str | None) -> str:
    """The web page's address; with a key just made and a loopback address it signs the local
    admin in: the key is in the fragment, which browsers never send, so it stays out of every
    server log (the page asks before it switches a signed-in tab to that account)."""
    import ipaddress

    try:
        local = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        local = False
    return f"{url}/#key={key}" if key and local else f"{url}/"


def _announce_key(settings: Settings) -> tuple[str | None, bool]:
    """Make sure the local admin exists (auth on) and say where its key is: (the key, whether
    it was just made). The key itself is printed only when it was just made, never in a log
    line of a later start."""
    if not settings.auth_enabled:
        print("authentication is off (QHSM_AUTH_ENABLED=false)", file=sys.stderr)
        return None, False
    from api.users import LOCAL_ADMIN, LOCAL_KEY_FILE, UserStore, ensure_local_admin

    key, new = ensure_local_admin(UserStore.from_settings(settings), settings.data_dir)
    where = settings.data_dir / LOCAL_KEY_FILE
    if new:
        print(f"new API key of {LOCAL_ADMIN} (admin): {key}", file=sys.stderr)
    print(
        f"{LOCAL_ADMIN}'s API key is in {where} (sign in to the web page with it); "
        "`qhsm submit` uses it unless --key or QHSM_API_KEY is given; add lab members with "
        "`qhsm admin create-user NAME`",
        file=sys.stderr,
    )
    return key, new


def announce_web_page(settings: Settings, url: str) -> str | None:
    """Print where the local admin's key is and the web page's address (with the key in its
    fragment only when the key was just made); returns the key."""
    key, new = _announce_key(settings)
    print(f"web page: {sign_in_url(url, settings.api_host, key if new else None)}", file=sys.stderr)
    return key


def _demo_scene(choice: str):
    """(name, left PNG, right PNG, ground truth .npy bytes, gt scale, gt border, max disparity)."""
    import cv2
    import numpy as np

    from shared.datasets import default_middlebury_dir, load_scene

    folder = default_middlebury_dir() / "tsukuba"
    if choice == "tsukuba" or (choice == "auto" and folder.is_dir()):
        if not folder.is_dir():
            raise CommandError(f"Tsukuba not found at {folder} (set QHSM_MIDDLEBURY_DIR)")
        scene = load_scene(folder)
        gt = scene.gt.read_bytes() if scene.gt else None
        return "tsukuba", scene.left.read_bytes(), scene.right.read_bytes(), gt, 16.0, 18, 16
    from shared.synthetic import make_scene

    synthetic = make_scene(120, 160, max_disparity=16, seed=0)

    def png(image) -> bytes:
        return cv2.imencode(".png", np.rint(image * 255).astype(np.uint8))[1].tobytes()

    from io import BytesIO

    stream = BytesIO()
    np.save(stream, synthetic.disparity)
    return "synthetic", png(synthetic.left), png(synthetic.right), stream.getvalue(), 1.0, 0, 16


def cmd_demo(args: argparse.Namespace) -> int:
    import importlib

    from api.client import Client, progress_bar, scores_text
    from api.server import ApiThread, PortBusyError, bind_api_socket
    from workers.embedded_redis import free_port
    from workers.supervisor import Stack, WorkerStartError

    settings = settings_from_args(args)
    if args.api_port is None:
        settings = settings.model_copy(update={"api_port": free_port()})
    else:  # a busy port fails before Redis and workers start
        try:
            bind_api_socket(settings.api_host, settings.api_port).close()
        except PortBusyError as error:
            raise CommandError(str(error)) from None
    name, left, right, gt, scale, border, max_disparity = _demo_scene(args.scene)
    stack = Stack(settings, concurrency=args.worker_concurrency)
    api = None
    bar = progress_bar()
    serving = False  # after the job with --keep-running: Ctrl-C is how one stops it
    print("starting Redis, workers and the API ...", file=sys.stderr)
    try:
        stack.launch()
        importlib.import_module("api.app")  # while the workers boot (ApiThread builds the app)
        try:
            stack.wait_ready()
        except WorkerStartError as error:
            raise CommandError(str(error)) from None
        print(stack.describe(), file=sys.stderr)
        api = ApiThread(stack.settings).start()
        key, new = _announce_key(stack.settings)
        client = Client(api.url, key=key, key_source="the demo's local admin")
        params = {"solver": args.solver, "max_disparity": max_disparity}
        job = client.submit(left, right, params, ground_truth=gt, gt_scale=scale, gt_border=border)
        print(f"job {job['id']}: {name}, solver {args.solver}  ({api.url}{job['links']['self']})")
        status = client.wait(job["id"], on_progress=bar)
        if status["state"] != "succeeded":
            raise CommandError(f"the demo job {status['state']}: {status['error']}")
        out = stack.settings.data_dir / "demo"
        out.mkdir(parents=True, exist_ok=True)
        (out / "disparity.pfm").write_bytes(client.disparity(job["id"], "pfm"))
        (out / "preview.png").write_bytes(client.preview(job["id"]))
        seconds = sum(level["seconds"] for level in status["levels"])
        scores = scores_text(status) or "no ground truth"
        print(f"done in {seconds:.2f} s over {len(status['levels'])} levels; {scores}")
        print(f"wrote {out / 'disparity.pfm'} and {out / 'preview.png'}")
        if args.keep_running:
            print(f"API still on {api.url} (docs: {api.url}/docs); Ctrl-C stops", file=sys.stderr)
            page = sign_in_url(api.url, stack.settings.api_host, key if new else None)
            print(f"web page: {page}", file=sys.stderr)
            serving = True
            api.join()
    except KeyboardInterrupt:
        bar.close()
        if not serving:
            print("qhsm: interrupted; stopping the demo's service", file=sys.stderr)
            return EXIT_INTERRUPTED
    finally:
        if api is not None:
            api.stop()
        stack.stop()
    return 0
