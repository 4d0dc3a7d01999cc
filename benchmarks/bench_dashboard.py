"""Dashboard costs, measured against a real `agv-mission serve` and headless chromium.

- ``dashboard.watched_rtf_ratio``: the demo patrol's real-time factor (sim s per wall s, from
  result.json) while a browser page watches it live, over the same run unwatched (target
  >= 0.9): medians of 9 interleaved pairs, the order alternating, after a warm-up run. The
  page is open (on the runs page) before the run starts and goes to the run's page as it
  is submitted, as a person at the dashboard would: chromium's start-up is not the run's
  cost. The browser runs on this same 2-core machine (other engineers' load too), under
  SCHED_IDLE: it stands for the person's own computer (see :func:`browser_in_background`);
  ``dashboard.worker_cpu_ms_per_sim_s.*`` (the mission process's own CPU per sim second)
  and ``dashboard.browser_cpu_per_wall_s.watched`` (chromium's CPU while watching) say
  where a difference comes from; ``.pairs_median`` is the median of each pair's ratio.
- ``dashboard.fps_30x50``: frames per second of the run page on a 30 x 50 m map (600 x 1000
  cells) with every frame fully redrawn while a teleop run streams (target >= 20).
"""

from __future__ import annotations

import contextlib
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from service_server import CHROMIUM, FINAL, launch_chromium, serve, wait_status  # noqa: E402

PAIRS = 9
FPS_SECONDS = 6.0


def _children() -> dict[int, list[int]]:
    tree: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        tree.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    return tree


def browser_cpu_seconds(root: int) -> float:
    """CPU seconds (user + system) of ``root`` and its descendants alive now: the
    Playwright driver and the chromium processes it started."""
    tree, total, todo = _children(), 0.0, [root]
    while todo:
        pid = todo.pop()
        todo += tree.get(pid, [])
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


@dataclass
class PatrolRun:
    rtf: float  # sim seconds per wall second (result.json)
    worker_cpu_per_sim_s: float  # the mission process's CPU seconds per sim second
    browser_cpu_per_wall_s: float  # chromium's (and its driver's) CPU while the run went on


def patrol_rtf(client: httpx.Client, page: Any | None, driver_pid: int | None) -> PatrolRun:
    """The demo patrol, watched from ``page`` (already open on the runs page, as a person
    would have it: the browser's start-up is not the run's cost) or unwatched."""
    mission = (REPO / "missions" / "patrol.yaml").read_text()
    cpu0 = browser_cpu_seconds(driver_pid) if driver_pid else 0.0
    wall0 = time.perf_counter()
    run_id = client.post("/api/runs", json={"mission": mission}).json()["id"]
    if page is not None:
        page.goto(f"{client.base_url}/runs/{run_id}")
    run = wait_status(client, run_id, FINAL, timeout=600.0, period=0.2)
    wall = time.perf_counter() - wall0
    cpu = (browser_cpu_seconds(driver_pid) - cpu0) if driver_pid else 0.0
    if page is not None:
        page.goto(f"{client.base_url}/")
    result = run["result"]
    assert run["status"] == "succeeded", run.get("reason")
    progress = run["progress"]
    return PatrolRun(
        rtf=float(result["sim_time"]) / float(result["wall_time"]),
        worker_cpu_per_sim_s=float(progress["cpu_time"]) / float(progress["sim_time"]),
        browser_cpu_per_wall_s=cpu / wall,
    )


def big_map(folder: Path) -> Path:
    """A 30 x 50 m office floor: 5 m rooms with doors along corridors, some furniture."""
    w, h = 600, 1000  # cells of 0.05 m
    occ = np.zeros((h, w), dtype=bool)
    occ[:4, :] = occ[-4:, :] = occ[:, :4] = occ[:, -4:] = True
    for x in range(100, w, 100):
        occ[:, x : x + 3] = True
        for y in range(0, h, 100):
            occ[y + 40 : y + 60, x : x + 3] = False  # doors
    for y in range(100, h, 100):
        occ[y : y + 3, :] = True
        for x in range(0, w, 100):
            occ[y : y + 3, x + 40 : x + 60] = False
    rng = np.random.default_rng(1)
    for _ in range(60):
        cx, cy = rng.integers(10, w - 30), rng.integers(10, h - 30)
        occ[cy : cy + rng.integers(6, 20), cx : cx + rng.integers(6, 20)] = True
    occ[450:550, 250:350] = False  # the start room is clear
    pixels = np.where(occ, 0, 254).astype(np.uint8)[::-1]  # row 0 = top
    Image.fromarray(pixels, mode="L").save(folder / "office.pgm")
    (folder / "office.yaml").write_text(
        "image: office.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return folder / "office.yaml"


def page_fps(client: httpx.Client, browser: Any, map_yaml: Path) -> tuple[float, float]:
    mission = (
        f"name: office-teleop\nworld: {map_yaml}\nrobot: burger\n"
        "start: {x: 15.0, y: 25.0, yaw: 0.0}\nseed: 1\n"
        "tasks:\n  - {type: teleop, duration: 120}\nlimits: {time: 200.0}\n"
    )
    answer = client.post("/api/runs", json={"mission": mission})
    assert answer.status_code == 201, answer.text
    run_id = answer.json()["id"]
    page = browser.new_page(viewport={"width": 1400, "height": 860})
    page.goto(f"{client.base_url}/runs/{run_id}")
    page.wait_for_function(
        "() => window.agvView && window.agvView.scene.map && window.agvView.scene.truth",
        timeout=120_000,
    )
    page.evaluate("() => window.agvView.setAlwaysDraw(true)")
    page.keyboard.down("ArrowLeft")
    before = page.evaluate("() => ({...window.agvView.stats, now: performance.now()})")
    page.wait_for_timeout(FPS_SECONDS * 1000)
    after = page.evaluate("() => ({...window.agvView.stats, now: performance.now()})")
    page.keyboard.up("ArrowLeft")
    page.close()
    client.post(f"/api/runs/{run_id}/cancel")
    frames = after["frames"] - before["frames"]
    seconds = (after["now"] - before["now"]) / 1000
    draw_ms = (after["drawMs"] - before["drawMs"]) / max(1, frames)
    return frames / seconds, draw_ms


@contextmanager
def browser_in_background() -> Iterator[None]:
    """Processes started meanwhile (the Playwright driver, chromium) run under SCHED_IDLE:
    the browser stands for a person's laptop, not for a second job of the machine the
    mission runs on (the service was started before, at its own priority). Chromium,
    running as root here, raises its compositor threads to nice -8 itself, so a nice value
    would not hold; the idle policy does (threads inherit it and ``setpriority`` leaves it).
    This process's policy comes back after."""
    before = os.sched_getscheduler(0)
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, before, os.sched_param(0))


def _driver_pid() -> int | None:
    """The Playwright driver this process started (chromium runs below it)."""
    mine = _children().get(os.getpid(), [])
    for pid in mine:
        with contextlib.suppress(OSError):
            if b"playwright" in Path(f"/proc/{pid}/cmdline").read_bytes():
                return pid
    return None


def run() -> dict[str, float]:
    from playwright.sync_api import sync_playwright

    if not CHROMIUM.exists():
        print("  /usr/bin/chromium is not installed: dashboard bench skipped")
        return {}
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        data.mkdir()
        maps = data / "maps"
        maps.mkdir()
        map_yaml = big_map(maps)
        with (
            serve(data, "--workers", "1") as url,
            httpx.Client(base_url=url, timeout=30) as c,
            browser_in_background(),
            sync_playwright() as p,
        ):
            browser = launch_chromium(p)
            driver = _driver_pid()
            page = browser.new_page(viewport={"width": 1400, "height": 860})
            page.goto(f"{url}/")
            patrol_rtf(c, page, driver)  # warm-up: imports, OMPL and casadi caches, the page
            watched: list[PatrolRun] = []
            unwatched: list[PatrolRun] = []
            load0 = os.getloadavg()[0]
            for i in range(PAIRS):  # interleaved, the order alternating
                for watch in (False, True) if i % 2 == 0 else (True, False):
                    got = patrol_rtf(c, page if watch else None, driver)
                    (watched if watch else unwatched).append(got)
            page.close()

            def med(values: list[float]) -> float:
                return statistics.median(values)

            ratios = [w.rtf / u.rtf for w, u in zip(watched, unwatched, strict=True)]
            out["dashboard.patrol_rtf.unwatched"] = round(med([r.rtf for r in unwatched]), 2)
            out["dashboard.patrol_rtf.watched"] = round(med([r.rtf for r in watched]), 2)
            out["dashboard.watched_rtf_ratio"] = round(
                med([r.rtf for r in watched]) / med([r.rtf for r in unwatched]), 3
            )
            out["dashboard.watched_rtf_ratio.pairs_median"] = round(med(ratios), 3)
            out["dashboard.worker_cpu_ms_per_sim_s.unwatched"] = round(
                1e3 * med([r.worker_cpu_per_sim_s for r in unwatched]), 1
            )
            out["dashboard.worker_cpu_ms_per_sim_s.watched"] = round(
                1e3 * med([r.worker_cpu_per_sim_s for r in watched]), 1
            )
            out["dashboard.browser_cpu_per_wall_s.watched"] = round(
                med([r.browser_cpu_per_wall_s for r in watched]), 3
            )
            out["dashboard.load_avg_1min"] = round(max(load0, os.getloadavg()[0]), 2)
            print(
                "  dashboard pairs (watched, unwatched rtf):",
                [
                    (round(w.rtf, 1), round(u.rtf, 1))
                    for w, u in zip(watched, unwatched, strict=True)
                ],
            )
            fps, draw_ms = page_fps(c, browser, map_yaml)
            out["dashboard.fps_30x50"] = round(fps, 1)
            out["dashboard.draw_ms_30x50"] = round(draw_ms, 2)
            browser.close()
    return out


if __name__ == "__main__":
    print(run())
