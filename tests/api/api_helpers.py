"""Uploads shared by the API tests: a small synthetic pair and a multipart POST of it."""

from __future__ import annotations

import json

import harness

from shared.synthetic import make_scene

SCENE = make_scene(24, 32, max_disparity=6, seed=1)
LEFT, RIGHT = harness.png(SCENE.left), harness.png(SCENE.right)


def post(client, left=LEFT, right=RIGHT, params=None, **extra):
    files = {"left": ("left.png", left), "right": ("right.png", right)}
    data = {}
    if params is not None:
        data["params"] = params if isinstance(params, str) else json.dumps(params)
    for name, value in extra.items():
        if isinstance(value, bytes):
            files[name] = (f"{name}.bin", value)
        else:
            data[name] = str(value)
    return client.post("/v1/jobs", files=files, data=data)
