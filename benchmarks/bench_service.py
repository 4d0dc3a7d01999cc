"""The service under load: a real ``agv-mission serve`` process, real HTTP/WebSocket clients.

* ``service.missions_per_min.2_workers``: 200 short missions submitted at once to a
  service with 2 workers, until every one is final (``service.lost`` counts runs that did
  not succeed: target 0).
* ``service.missions_per_min.sequential_run``: the same mission through ``agv-mission run``
  one after another (a sample of 20 calls; a rate, so comparable).
  ``service.throughput_ratio`` = service / sequential (issue target >= 1.8).
* ``service.rtf.0_subscribers`` / ``service.rtf.50_subscribers``: the real-time factor (sim
  seconds per wall second, from result.json) of one wander mission with no live clients and
  with 50 WebSocket clients reading everything, in interleaved pairs (the order alternating,
  a warm-up run first; medians). ``service.slowdown_50_subscribers`` = 1 - rtf50/rtf0: the
  issue's target (< 0.10) applies to it. The 50 clients run in one process at nice 10: they
  stand for browsers elsewhere, and on this 2-core machine they would otherwise take the
  CPU from the very mission measured; other engineers' load changes between runs, so
  ``service.slowdown_pairs_median`` (the median of each pair's own slowdown) is shown too.
* ``service.worker_cpu_ms_per_sim_s.*``: the mission process's own CPU time per simulated
  second (reported by the worker), with and without the 50 clients: what the run itself
  pays for being watched, free of other processes' load
  (``service.worker_cpu_slowdown_50_subscribers`` = c50/c0 - 1).
  ``service.service_cpu_per_wall_s`` and ``service.clients_cpu_per_wall_s``: the CPU the
  fan-out (the service process) and the 50 clients took, per wall second.
* ``service.get_run_ms.p50`` / ``.p99``: latency of ``GET /api/runs/{id}`` during the
  50-subscriber runs (polled every 20 ms). ``service.load_avg_1min.live``: the machine's
  load average around the live part (other engineers' work).
* ``service.control_ms.pause_p50`` / ``resume_p50``: from ``POST pause`` (``resume``) to
  the live stream's state saying ``paused`` (``running``) (issue: under 200 ms).
"""

from __future__ import annotations

import asyncio
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import websockets

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from service_server import AGV, FINAL, SHORT_MISSION, WANDER_MISSION, Server  # noqa: E402

N_MISSIONS = 200
N_SEQUENTIAL = 20
N_SUBSCRIBERS = 50
WANDER_SIM_S = 300
LIVE_PAIRS = 6


def _throughput(root: Path) -> dict[str, float]:
    with Server(root / "data", "--workers", "2") as srv, srv.client() as c:
        start = time.perf_counter()
        ids = []
        for _ in range(N_MISSIONS):
            r = c.post("/api/runs", json={"mission": SHORT_MISSION})
            ids.append(r.json()["id"])
        pending = set(ids)
        while pending:
            runs = c.get("/api/runs", params={"limit": 1000}).json()["runs"]
            pending = {r["id"] for r in runs if r["id"] in pending and r["status"] not in FINAL}
            time.sleep(0.2)
        wall = time.perf_counter() - start
        runs = c.get("/api/runs", params={"limit": 1000}).json()["runs"]
        succeeded = sum(r["status"] == "succeeded" for r in runs if r["id"] in set(ids))
    mission = root / "short.yaml"
    mission.write_text(SHORT_MISSION)
    start = time.perf_counter()
    for _ in range(N_SEQUENTIAL):
        subprocess.run(
            [AGV, "run", str(mission), "--output", str(root / "seq")],
            capture_output=True,
            check=True,
        )
    seq_wall = time.perf_counter() - start
    service_rate = N_MISSIONS / wall * 60.0
    seq_rate = N_SEQUENTIAL / seq_wall * 60.0
    return {
        "service.missions_per_min.2_workers": round(service_rate, 1),
        "service.missions_per_min.sequential_run": round(seq_rate, 1),
        "service.throughput_ratio": round(service_rate / seq_rate, 2),
        "service.lost": float(N_MISSIONS - succeeded),
    }


async def _subscriber(url: str, counts: list[int]) -> None:
    n = 0
    async with websockets.connect(url, max_size=1 << 24) as ws:
        async for text in ws:
            n += 1
            if text.startswith('{"type":"end"'):
                break
    counts.append(n)


async def _subscribers(url: str, n: int) -> dict[str, Any]:
    counts: list[int] = []
    await asyncio.gather(*(_subscriber(url, counts) for _ in range(n)))
    return {"counts": counts, "cpu_s": time.process_time()}


def _subscriber_process(url: str, n: int) -> subprocess.Popen[str]:
    """The clients in their own process at a low priority: they stand for browsers on other
    machines, and must not take the CPU from the mission this machine also runs."""
    code = (
        "import asyncio, json, sys; sys.path.insert(0, sys.argv[3]); import bench_service as b; "
        "print(json.dumps(asyncio.run(b._subscribers(sys.argv[1], int(sys.argv[2])))))"
    )
    return subprocess.Popen(
        ["nice", "-n", "10", sys.executable, "-c", code, url, str(n), str(HERE)],
        stdout=subprocess.PIPE,
        text=True,
    )


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of one process (all its threads, not its children)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _load() -> float:
    return os.getloadavg()[0]


@dataclass
class LiveRun:
    """One wander run: its wall real-time factor, the worker's CPU seconds per simulated
    second, the service process's CPU per wall second, and GET latencies meanwhile."""

    rtf: float
    worker_cpu_per_sim_s: float
    service_cpu_per_wall_s: float
    clients_cpu_per_wall_s: float
    latencies: list[float]


async def _one_run(srv: Server, subscribers: int) -> LiveRun:
    mission = WANDER_MISSION % {"duration": WANDER_SIM_S}
    latencies: list[float] = []
    assert srv.proc is not None
    async with httpx.AsyncClient(base_url=srv.url, timeout=60.0) as c:
        cpu0, wall0 = _cpu_seconds(srv.proc.pid), time.perf_counter()
        rid = (await c.post("/api/runs", json={"mission": mission})).json()["id"]
        url = f"{srv.ws_url}/api/runs/{rid}/live"
        clients = _subscriber_process(url, subscribers) if subscribers else None
        while True:
            t0 = time.perf_counter()
            run = (await c.get(f"/api/runs/{rid}")).json()
            latencies.append((time.perf_counter() - t0) * 1e3)
            if run["status"] in FINAL:
                break
            await asyncio.sleep(0.02)
        wall = time.perf_counter() - wall0
        service_cpu = _cpu_seconds(srv.proc.pid) - cpu0
        clients_cpu = 0.0
        if clients is not None:
            out, _ = clients.communicate(timeout=120)
            report = json.loads(out)
            counts = report["counts"]
            assert len(counts) == subscribers and min(counts) > 0, counts
            clients_cpu = report["cpu_s"]
    assert run["status"] == "succeeded", run.get("reason")
    progress = run["progress"]
    return LiveRun(
        rtf=float(run["result"]["metrics"]["real_time_factor"]),
        worker_cpu_per_sim_s=float(progress["cpu_time"]) / float(progress["sim_time"]),
        service_cpu_per_wall_s=service_cpu / wall,
        clients_cpu_per_wall_s=clients_cpu / wall,
        latencies=latencies,
    )


async def _control(srv: Server, cycles: int = 10) -> tuple[list[float], list[float]]:
    mission = WANDER_MISSION % {"duration": 6000}
    pauses, resumes = [], []
    async with httpx.AsyncClient(base_url=srv.url, timeout=60.0) as c:
        rid = (await c.post("/api/runs", json={"mission": mission})).json()["id"]
        async with websockets.connect(f"{srv.ws_url}/api/runs/{rid}/live") as ws:

            async def until(status: str) -> None:
                while True:
                    m = json.loads(await ws.recv())
                    if m["type"] == "state" and m["status"] == status:
                        return

            await until("running")
            for _ in range(cycles):
                t0 = time.perf_counter()
                await c.post(f"/api/runs/{rid}/pause")
                await until("paused")
                pauses.append((time.perf_counter() - t0) * 1e3)
                t0 = time.perf_counter()
                await c.post(f"/api/runs/{rid}/resume")
                await until("running")
                resumes.append((time.perf_counter() - t0) * 1e3)
                await asyncio.sleep(0.2)
        await c.post(f"/api/runs/{rid}/cancel")
    return pauses, resumes


def _live(root: Path) -> dict[str, float]:
    load0 = _load()
    with Server(root / "live", "--workers", "1") as srv:
        asyncio.run(_one_run(srv, 0))  # warm-up: the fork server's first worker, caches
        runs: dict[int, list[LiveRun]] = {0: [], N_SUBSCRIBERS: []}
        for i in range(LIVE_PAIRS):  # interleaved, the order alternating
            for n in (0, N_SUBSCRIBERS) if i % 2 == 0 else (N_SUBSCRIBERS, 0):
                runs[n].append(asyncio.run(_one_run(srv, n)))
        pauses, resumes = asyncio.run(_control(srv))
    quiet, busy = runs[0], runs[N_SUBSCRIBERS]
    loaded = [ms for r in busy for ms in r.latencies]

    def med(values: list[float]) -> float:
        return statistics.median(values)

    r0, r50 = med([r.rtf for r in quiet]), med([r.rtf for r in busy])
    c0 = med([r.worker_cpu_per_sim_s for r in quiet])
    c50 = med([r.worker_cpu_per_sim_s for r in busy])
    return {
        "service.rtf.0_subscribers": round(r0, 2),
        "service.rtf.50_subscribers": round(r50, 2),
        "service.slowdown_50_subscribers": round(1.0 - r50 / r0, 3),
        "service.slowdown_pairs_median": round(
            med([1.0 - b.rtf / q.rtf for q, b in zip(quiet, busy, strict=True)]), 3
        ),
        "service.worker_cpu_ms_per_sim_s.0_subscribers": round(c0 * 1e3, 1),
        "service.worker_cpu_ms_per_sim_s.50_subscribers": round(c50 * 1e3, 1),
        "service.worker_cpu_slowdown_50_subscribers": round(c50 / c0 - 1.0, 3),
        "service.service_cpu_per_wall_s.50_subscribers": round(
            med([r.service_cpu_per_wall_s for r in busy]), 3
        ),
        "service.clients_cpu_per_wall_s.50_subscribers": round(
            med([r.clients_cpu_per_wall_s for r in busy]), 3
        ),
        "service.get_run_ms.p50": round(float(np.percentile(loaded, 50)), 2),
        "service.get_run_ms.p99": round(float(np.percentile(loaded, 99)), 2),
        "service.control_ms.pause_p50": round(statistics.median(pauses), 1),
        "service.control_ms.resume_p50": round(statistics.median(resumes), 1),
        "service.control_ms.pause_max": round(max(pauses), 1),
        "service.load_avg_1min.live": round(max(load0, _load()), 2),
    }


def run() -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        results = _live(root)
        results.update(_throughput(root))
    return results


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
