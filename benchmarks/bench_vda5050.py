"""VDA 5050: N vehicles at time scale 1 on one broker (issue 26).

``agv-mission vda5050 vehicles`` runs a fleet mission of N robots in the 30 x 50 m
warehouse (one world: every robot a body the others' lidars see; each robot on its own
spot of a rack aisle, 2.5 m apart) against Debian's mosquitto (the embedded broker when
mosquitto is absent). A subscriber in this process counts every ``state`` and
``visualization`` message per vehicle (rates, and messages lost as gaps in each topic's
headerIds), and sends each vehicle orders in turn (there and back along its aisle, 1 m,
released at once), timing order-to-motion: from publishing the order to the first
``state`` reporting ``driving: true``. CPU is the vehicles' process, user + system, over
the measured window, in cores.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
import yaml

COUNTS = [int(n) for n in os.environ.get("BENCH_VDA5050_N", "20,50").split(",")]
WINDOW = float(os.environ.get("BENCH_VDA5050_WINDOW", "30"))
MAP = "warehouse"
AISLES = (-13.2, -8.95, -5.35, -1.75, 1.85, 5.45, 9.05, 12.55)  # x of the rack aisles


def spot(k: int) -> tuple[float, float]:
    """Robot ``k``'s start: aisle after aisle, 2.5 m apart along each (17 spots an aisle)."""
    return AISLES[k % len(AISLES)], -20.0 + 2.5 * (k // len(AISLES))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _stamp() -> str:
    now = datetime.now(timezone.utc)
    return now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 1000:03d}Z"


class Observer:
    def __init__(self, port: int) -> None:
        self.lock = threading.Lock()
        self.counts: dict[tuple[str, str], int] = {}
        self.last_id: dict[tuple[str, str], int] = {}
        self.lost = 0
        self.driving: dict[str, bool] = {}
        self.waiting: dict[str, float] = {}  # serial -> when its order was sent
        self.latencies: list[float] = []
        self.last_node: dict[str, str] = {}
        self.counting = False
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-observer")
        self.client.on_message = self._message
        self.client.connect("127.0.0.1", port)
        self.client.subscribe("uagv/v2/agv-mission/+/state", 0)
        self.client.subscribe("uagv/v2/agv-mission/+/visualization", 0)
        self.client.loop_start()
        self.header = 0

    def _message(self, _c: Any, _u: Any, msg: mqtt.MQTTMessage) -> None:
        now = time.monotonic()
        _, _, _, serial, kind = msg.topic.split("/")
        doc = json.loads(msg.payload)
        key = (serial, kind)
        with self.lock:
            prev = self.last_id.get(key)
            if prev is not None and doc["headerId"] > prev + 1:
                self.lost += doc["headerId"] - prev - 1
            self.last_id[key] = doc["headerId"]
            if self.counting:
                self.counts[key] = self.counts.get(key, 0) + 1
            if kind == "state":
                self.last_node[serial] = doc["lastNodeId"]
                sent = self.waiting.get(serial)
                if sent is not None and doc["driving"]:
                    self.latencies.append(now - sent)
                    del self.waiting[serial]

    def order(
        self, serial: str, to: tuple[float, float], frm: tuple[float, float], oid: str
    ) -> None:
        self.header += 1
        nodes = [
            {
                "nodeId": "a",
                "sequenceId": 0,
                "released": True,
                "nodePosition": {"x": frm[0], "y": frm[1], "mapId": MAP},
                "actions": [],
            },
            {
                "nodeId": "b",
                "sequenceId": 2,
                "released": True,
                "nodePosition": {"x": to[0], "y": to[1], "mapId": MAP, "allowedDeviationXY": 0.1},
                "actions": [],
            },
        ]
        edges = [
            {
                "edgeId": "a-b",
                "sequenceId": 1,
                "released": True,
                "startNodeId": "a",
                "endNodeId": "b",
                "actions": [],
            }
        ]
        doc = {
            "headerId": self.header,
            "timestamp": _stamp(),
            "version": "2.1.0",
            "manufacturer": "agv-mission",
            "serialNumber": serial,
            "orderId": oid,
            "orderUpdateId": 0,
            "nodes": nodes,
            "edges": edges,
        }
        with self.lock:
            self.waiting[serial] = time.monotonic()
        self.client.publish(f"uagv/v2/agv-mission/{serial}/order", json.dumps(doc), 0)


def _broker(folder: Path) -> tuple[str, int, subprocess.Popen[bytes] | None]:
    port = _free_port()
    exe = shutil.which("mosquitto") or (
        "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None
    )
    if exe is None:
        return "embedded", port, None
    conf = folder / "mosquitto.conf"
    conf.write_text(
        f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nmax_queued_messages 10000\n"
    )
    proc = subprocess.Popen(
        [exe, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    time.sleep(0.3)
    return "mosquitto", port, proc


def _measure(n: int, folder: Path) -> dict[str, float]:
    kind, port, broker = _broker(folder)
    mission = {
        "name": f"bench-{n}",
        "world": MAP,
        "seed": 1,
        "stack": {
            "localization": {"type": "ground_truth"},
            "global_planner": {"type": "cost_grid"},
            "local_planner": {"type": "pure_pursuit"},
        },
        "robots": [
            {
                "name": f"agv{i + 1}",
                "robot": "burger",
                "start": {"x": spot(i)[0], "y": spot(i)[1], "yaw": 1.5708},
            }
            for i in range(n)
        ],
    }
    path = folder / f"fleet{n}.yaml"
    path.write_text(yaml.safe_dump(mission))
    cmd = [
        sys.executable,
        "-m",
        "agv_mission.cli",
        "vda5050",
        "vehicles",
        str(path),
        "--time-scale",
        "1",
    ]
    cmd += (
        ["--broker", f"mqtt://127.0.0.1:{port}"]
        if broker is not None
        else ["--embedded-port", str(port)]
    )
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    serials = [f"agv{i + 1}" for i in range(n)]
    try:
        deadline = time.monotonic() + 300
        while (
            proc.poll() is None and time.monotonic() < deadline
        ):  # up when every vehicle is listed
            line = proc.stdout.readline() if proc.stdout else ""
            if line.startswith(f"agv{n}:"):
                break
        obs = Observer(port)
        time.sleep(2.0)
        with obs.lock:
            obs.counting, obs.counts = True, {}
        cpu0, t0 = _cpu_seconds(proc.pid), time.monotonic()
        home = {s: spot(i) for i, s in enumerate(serials)}
        away = {s: (x, y + 1.0) for s, (x, y) in home.items()}
        where = dict(home)
        k = 0
        while time.monotonic() - t0 < WINDOW:
            serial = serials[k % n]
            frm = where[serial]
            to = away[serial] if frm == home[serial] else home[serial]
            if obs.last_node.get(serial) in (None, "", "a", "b") and serial not in obs.waiting:
                obs.order(serial, to, frm, f"o{k}")
                where[serial] = to
            k += 1
            time.sleep(max(0.05, 4.0 / n))
        wall = time.monotonic() - t0
        cpu = _cpu_seconds(proc.pid) - cpu0
        with obs.lock:
            counting = dict(obs.counts)
            lost, lat = obs.lost, list(obs.latencies)
        obs.client.loop_stop()
    finally:
        proc.terminate()
        proc.wait(30)
        if broker is not None:
            broker.terminate()
            broker.wait(5)
    state = [counting.get((s, "state"), 0) / wall for s in serials]
    viz = [counting.get((s, "visualization"), 0) / wall for s in serials]
    lat_ms = np.array(lat) * 1000.0 if lat else np.array([np.nan])
    return {
        f"vda5050.n{n}.broker_is_mosquitto": float(kind == "mosquitto"),
        f"vda5050.n{n}.state_hz.min": round(min(state), 3),
        f"vda5050.n{n}.state_hz.mean": round(statistics.fmean(state), 3),
        f"vda5050.n{n}.visualization_hz.min": round(min(viz), 3),
        f"vda5050.n{n}.visualization_hz.mean": round(statistics.fmean(viz), 3),
        f"vda5050.n{n}.messages_lost": float(lost),
        f"vda5050.n{n}.order_to_motion_ms.p50": round(float(np.percentile(lat_ms, 50)), 1),
        f"vda5050.n{n}.order_to_motion_ms.p99": round(float(np.percentile(lat_ms, 99)), 1),
        f"vda5050.n{n}.orders_timed": float(len(lat)),
        f"vda5050.n{n}.vehicles_cpu_cores": round(cpu / wall, 3),
    }


def run() -> dict[str, float]:
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in COUNTS:
            out.update(_measure(n, Path(tmp)))
    return out


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
