"""agv-mission serve with a service of its own per test: the exposure and token rules, a
full queue, and restarts after kill -9 and SIGTERM (the whole history kept)."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import WebSocketException

from service_server import (
    AGV,
    FINAL,
    SHORT_MISSION,
    WANDER_MISSION,
    Server,
    collect_live,
    submit,
    wait_status,
)


def test_token_and_host_rules(tmp_path: Path) -> None:
    refused = subprocess.run(
        [AGV, "serve", "--host", "0.0.0.0", "--port", "0", "--data", str(tmp_path / "d")],
        capture_output=True,
        text=True,
        timeout=60,
        env={k: v for k, v in os.environ.items() if k != "AGV_MISSION_TOKEN"},
    )
    assert refused.returncode == 2 and "token" in refused.stderr
    with Server(tmp_path / "data", "--workers", "1", env={"AGV_MISSION_TOKEN": "s3cret"}) as srv:
        assert httpx.get(srv.url + "/api/health").status_code == 401
        wrong = httpx.get(srv.url + "/api/runs", headers={"Authorization": "Bearer nope"})
        assert wrong.status_code == 401
        with srv.client() as c:
            run = submit(c, SHORT_MISSION)

        async def live(url: str) -> list[dict]:
            return await collect_live(url)

        with pytest.raises(WebSocketException):
            asyncio.run(live(f"{srv.ws_url}/api/runs/{run['id']}/live"))
        messages = asyncio.run(live(f"{srv.ws_url}/api/runs/{run['id']}/live?token=s3cret"))
        assert messages[-1]["type"] == "end"
        mission = tmp_path / "short.yaml"
        mission.write_text(SHORT_MISSION)
        out = subprocess.run(
            [AGV, "submit", str(mission), "--server", srv.url],
            capture_output=True,
            text=True,
            timeout=60,
            env={k: v for k, v in os.environ.items() if k != "AGV_MISSION_TOKEN"},
        )
        assert out.returncode == 69  # refused (no token): not the mission's fault


def test_queue_full_429(tmp_path: Path) -> None:
    with Server(tmp_path / "data", "--workers", "1", "--queue-size", "1") as srv, srv.client() as c:
        long = WANDER_MISSION % {"duration": 600}
        first = submit(c, long)
        wait_status(c, first["id"], {"running"})
        submit(c, long)
        third = c.post("/api/runs", json={"mission": long})
        assert third.status_code == 429
        assert c.get("/api/health").json()["queued"] == 1
        for run in c.get("/api/runs").json()["runs"]:
            c.post(f"/api/runs/{run['id']}/cancel")
        assert wait_status(c, first["id"], FINAL)["status"] == "aborted"


@pytest.mark.slow  # 20 s of restarts
def test_restart_after_kill_9_and_sigterm(tmp_path: Path) -> None:
    data = tmp_path / "data"
    long = WANDER_MISSION % {"duration": 600}
    srv = Server(data, "--workers", "1").start()
    with srv.client() as c:
        done = submit(c, SHORT_MISSION)
        wait_status(c, done["id"], FINAL)
        running = submit(c, long)
        wait_status(c, running["id"], {"running"})
        queued = submit(c, SHORT_MISSION)
    srv.kill9()

    srv = Server(data, "--workers", "1").start()
    with srv.client() as c:
        runs = {r["id"]: r for r in c.get("/api/runs").json()["runs"]}
        assert set(runs) == {done["id"], running["id"], queued["id"]}
        assert runs[done["id"]]["status"] == "succeeded"
        assert runs[running["id"]]["status"] == "interrupted"
        assert wait_status(c, queued["id"], FINAL)["status"] == "succeeded"
        again = submit(c, long)
        wait_status(c, again["id"], {"running"})
        while c.get(f"/api/runs/{again['id']}").json()["progress"]["sim_time"] < 0.5:
            time.sleep(0.05)
    assert srv.stop(signal.SIGTERM) == 0

    srv = Server(data, "--workers", "1").start()
    with srv.client() as c:
        stopped = c.get(f"/api/runs/{again['id']}").json()
        assert stopped["status"] == "aborted"
        assert stopped["result"]["status"] == "aborted"
        assert len(c.get("/api/runs").json()["runs"]) == 4
    srv.stop(signal.SIGINT)
