"""agv-mission serve --backend ray: missions as Ray tasks on a local Ray instance."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import pytest
import websockets

from service_server import FINAL, SHORT_MISSION, WANDER_MISSION, Server, submit, wait_status


@pytest.mark.slow
def test_ray_backend_runs_streams_and_cancels(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="ray not installed (pip install 'agv-mission[ray]')")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    try:
        address = ray.get_runtime_context().gcs_address
        args = ("--workers", "2", "--backend", "ray", "--address", address)
        with Server(tmp_path / "data", *args) as srv, srv.client() as c:
            assert c.get("/api/health").json()["backend"] == "ray"
            short = submit(c, SHORT_MISSION)

            async def live() -> list[dict]:
                out = []
                async with websockets.connect(f"{srv.ws_url}/api/runs/{short['id']}/live") as ws:
                    async for text in ws:
                        out.append(json.loads(text))
                        if out[-1]["type"] == "end":
                            return out
                return out

            messages = asyncio.run(live())
            assert messages[-1]["status"] == "succeeded"
            assert any(m["type"] == "state" for m in messages)
            done = wait_status(c, short["id"], FINAL)
            assert done["result"]["status"] == "succeeded"
            assert "run.png" in c.get(f"/api/runs/{short['id']}/files").json()["files"]

            long = submit(c, WANDER_MISSION % {"duration": 600})
            wait_status(c, long["id"], {"running"})
            while c.get(f"/api/runs/{long['id']}").json()["progress"]["sim_time"] < 0.5:
                time.sleep(0.05)
            assert c.post(f"/api/runs/{long['id']}/pause").status_code == 202
            wait_status(c, long["id"], {"paused"})
            assert c.post(f"/api/runs/{long['id']}/cancel").status_code == 202
            final = wait_status(c, long["id"], FINAL)
            assert final["status"] == "aborted" and final["result"]["status"] == "aborted"
    finally:
        ray.shutdown()
