"""A real ``agv-mission serve`` process on a loopback port, and the headless chromium that
watches its dashboard, for tests and benchmarks."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import websockets

from mission_texts import tb3_mission

AGV = str(Path(sys.executable).with_name("agv-mission"))
CHROMIUM = Path("/usr/bin/chromium")  # Debian's, driven by Playwright
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]

SHORT_MISSION = tb3_mission(
    "{type: go_to, pose: {x: -1.5, y: -0.5, yaw: 0.0}}",
    limits="{time: 30}",
    stack="{localization: {type: ground_truth}, global_planner: {type: grid_astar}}",
    name="short",
    robot=None,
)

# sim seconds that take a few wall seconds: long enough to pause, cancel or kill
WANDER_MISSION = tb3_mission(
    "{type: wander, duration: %(duration)s, min_range: 0.6}",
    limits="{time: 2000}",
    stack="{localization: {type: amcl}}",
    name="wander",
    robot=None,
)

# A small fleet: two robots in turtlebot3_world, each with its own tasks (agv2 two legs, so
# that the two trees differ); ``%(tasks1)s`` / ``%(tasks2)s`` replace them.
FLEET_MISSION = """\
name: pair
world: turtlebot3_world
seed: 3
stack: {localization: {type: ground_truth}, global_planner: {type: grid_astar}}
robots:
  - name: agv1
    robot: burger
    start: {x: -2.0, y: -0.5, yaw: 0.0}
    tasks: %(tasks1)s
  - name: agv2
    robot: waffle
    start: {x: 2.0, y: 0.5, yaw: 3.14}
    tasks: %(tasks2)s
limits: {time: %(time)s}
"""
FLEET_TASKS = {
    "tasks1": "[{type: go_to, pose: {x: -2.0, y: 1.0, yaw: 0.0}}]",
    "tasks2": "[{type: go_to, pose: {x: 2.0, y: -0.5, yaw: 0.0}}, "
    "{type: go_to, pose: {x: 1.8, y: -1.0, yaw: 0.0}}]",
    "time": 60,
}
SHORT_FLEET = FLEET_MISSION % FLEET_TASKS
# both robots under remote command (the run goes on until cancelled)
TELEOP_FLEET = FLEET_MISSION % {
    "tasks1": "[{type: teleop}]",
    "tasks2": "[{type: teleop}]",
    "time": 600,
}


class Server:
    """Start ``agv-mission serve --port 0`` and read its URL from the first stdout line."""

    def __init__(self, data: Path, *args: str, env: dict[str, str] | None = None) -> None:
        self.data = data
        self.args = list(args)
        self.env = {**os.environ, **(env or {})}
        self.proc: subprocess.Popen[str] | None = None
        self.url = ""

    def start(self, timeout: float = 60.0) -> Server:
        self.proc = subprocess.Popen(
            [AGV, "serve", "--port", "0", "--data", str(self.data), *self.args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=self.env,
            start_new_session=True,
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line.startswith("serving on "):
            self.proc.kill()
            raise RuntimeError(f"serve did not start: {line!r} {self.proc.stderr.read()}")
        self.url = line.split()[-1]
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:  # the lifespan (recovery, fork server) is up
            try:
                httpx.get(self.url + "/api/health", headers=self.headers, timeout=5.0)
                return self
            except httpx.HTTPError:
                time.sleep(0.1)
        raise RuntimeError("serve did not answer /api/health")

    @property
    def headers(self) -> dict[str, str]:
        token = self.env.get("AGV_MISSION_TOKEN")
        return {"Authorization": f"Bearer {token}"} if token else {}

    @property
    def ws_url(self) -> str:
        return "ws" + self.url[len("http") :]

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, headers=self.headers, timeout=30.0)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 60.0) -> int:
        assert self.proc is not None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
            for stream in (self.proc.stdout, self.proc.stderr):
                if stream is not None:
                    stream.close()

    def kill9(self) -> None:
        """kill -9 the service alone (its workers notice their pipe closing)."""
        assert self.proc is not None
        self.proc.kill()
        self.proc.wait(30)

    def __enter__(self) -> Server:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.stop()


@contextmanager
def serve(data: Path, *extra: str) -> Iterator[str]:
    """A real service process on a free loopback port; yields its base URL."""
    with Server(data, *extra) as server:
        yield server.url


def launch_chromium(playwright: Any) -> Any:
    """Headless chromium from a ``sync_playwright()`` context."""
    return playwright.chromium.launch(
        executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True
    )


def submit(client: httpx.Client, mission: str, **body: Any) -> dict[str, Any]:
    response = client.post("/api/runs", json={"mission": mission, **body})
    assert response.status_code == 201, response.text
    return response.json()


def wait_status(
    client: httpx.Client,
    run_id: str,
    statuses: set[str],
    timeout: float = 120.0,
    period: float = 0.05,
) -> dict[str, Any]:
    """Poll every ``period`` seconds until the run reaches one of ``statuses`` (a test's
    deadline, not a timing)."""
    deadline = time.monotonic() + timeout
    while True:
        run = client.get(f"/api/runs/{run_id}").json()
        if run["status"] in statuses:
            return run
        if time.monotonic() > deadline:
            raise AssertionError(f"run {run_id} stuck in {run['status']}: {json.dumps(run)[:500]}")
        time.sleep(period)


async def collect_live(url: str, until: str = "end", limit: int = 100000) -> list[dict]:
    """A run's live-stream messages from ``url`` until one of type ``until`` (or ``limit``)."""
    out: list[dict] = []
    async with websockets.connect(url, max_size=1 << 24) as ws:
        async for text in ws:
            out.append(json.loads(text))
            if out[-1]["type"] == until or len(out) >= limit:
                break
    return out


FINAL = {"succeeded", "failed", "aborted", "error", "interrupted"}
