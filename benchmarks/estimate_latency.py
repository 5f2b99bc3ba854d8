"""How long ``POST /v1/estimate`` takes to answer now that the estimate runs on a pricing worker
(issue 29, item 2: within 1 s on any allowed size): the API behind a real uvicorn server, a
synthetic pair of the largest allowed size (``QHSM_MAX_IMAGE_PIXELS``, 4 MP: 2000x2000) sent as
PNG over HTTP, the answer's time measured at the client. ``miss``: a new request (decoded,
checked, its views written to Redis in bounded pieces, the task sent: 202 ``pending``);
``hit``: an identical request answered from the cache (202 ``done``). No worker runs: only the
answer is timed (the estimate itself takes the exact pyramid's time on the worker, see "Speed").

    python benchmarks/estimate_latency.py [SIDE] [ROUNDS]   # default 2000 5

Runs its own embedded Redis in a temporary folder; prints one markdown row per kind
(docs/benchmarks.md, "Estimates off the API").
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import uvicorn

from shared.config import MatchConfig, Settings
from shared.synthetic import make_scene
from workers.embedded_redis import EmbeddedRedis, free_port


def png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", np.rint(np.clip(image, 0, 1) * 255).astype(np.uint8))[1].tobytes()


def serve(settings: Settings) -> tuple[uvicorn.Server, str]:
    from api.app import create_app

    port = free_port()
    config = uvicorn.Config(create_app(settings), port=port, log_level="warning")
    server = uvicorn.Server(config)
    threading.Thread(target=server.run, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    return server, f"http://127.0.0.1:{port}"


def main(side: int = 2000, rounds: int = 5) -> None:
    from api.users import UserStore
    from shared.solvers.meters.qpu_time import JobEstimate
    from workers.estimates import EstimateStore, request_digest
    from workers.pricing import Priced

    scene = make_scene(side, side, max_disparity=64, seed=0)
    files = {"left": ("l.png", png(scene.left)), "right": ("r.png", png(scene.right))}
    with tempfile.TemporaryDirectory() as folder:
        server_redis = EmbeddedRedis(Path(folder) / "redis").start()
        try:
            settings = Settings(
                redis_url=server_redis.url,
                data_dir=Path(folder) / "data",
                auth_enabled=False,
                max_estimates_per_user=1000,  # no worker runs: every miss stays open
            )
            UserStore.from_settings(settings)
            server, url = serve(settings)
            times: dict[str, list[float]] = {"miss": [], "hit": []}
            states: dict[str, set[str]] = {"miss": set(), "hit": set()}
            with httpx.Client(base_url=url, timeout=120) as client:
                for number in range(rounds):
                    params = {"solver": "qpu-sim", "max_disparity": "auto", "seed": number}
                    for kind in ("miss", "hit"):
                        if kind == "hit":  # as a finished identical estimate leaves it
                            config = MatchConfig.model_validate(params)
                            digest = request_digest(files["left"][1], files["right"][1], config)
                            store = EstimateStore(server.config.app.state.services.store.redis,
                                                  settings)  # fmt: skip
                            job = JobEstimate(solver="qpu-sim", seconds=1.0, bundles=1, levels=[])
                            store.cache(digest, Priced(job, 64, None, 100).result())
                        started = time.perf_counter()
                        response = client.post(
                            "/v1/estimate", files=files, data={"params": json.dumps(params)}
                        )
                        times[kind].append(time.perf_counter() - started)
                        assert response.status_code == 202, response.text
                        states[kind].add(response.json()["state"])
            server.should_exit = True
        finally:
            server_redis.stop()
    mb = (len(files["left"][1]) + len(files["right"][1])) / 2**20
    print(f"{side}x{side} pair, {mb:.1f} MiB of PNG, {rounds} rounds")
    print("| request | answer | median (s) | worst (s) | first (s) |")
    print("|---|---|---|---|---|")
    for kind, values in times.items():
        answer = "/".join(sorted(states[kind]))
        print(
            f"| {kind} | 202 {answer} | {statistics.median(values):.3f} | {max(values):.3f} "
            f"| {values[0]:.3f} |"
        )


if __name__ == "__main__":
    main(*(int(value) for value in sys.argv[1:3]))
