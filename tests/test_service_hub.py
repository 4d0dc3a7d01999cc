"""The live hub: late clients get the snapshot first, slow ones are thinned, never waited for."""

from __future__ import annotations

import asyncio
import json

from agv_mission.service.hub import BURST, CLIENT_HARD_LIMIT, CLIENT_QUEUE, KIND_BUDGET, Hub


def _state(t: float) -> str:
    return json.dumps({"type": "state", "t": round(t, 3), "status": "running"})


def test_late_client_gets_snapshot_in_order_then_live() -> None:
    async def main() -> None:
        hub = Hub()
        for kind in ("state", "tree", "map", "rooms", "recorded", "plan", "goal"):
            hub.publish(kind, json.dumps({"type": kind}))
        hub.publish("event", json.dumps({"type": "event"}))  # not the snapshot: after it
        hub.publish("state", _state(1.0), 1.0)
        client = hub.subscribe()
        items, _ = client.take(0.0)
        kinds = [k for k, _ in items]
        assert kinds == ["map", "rooms", "recorded", "tree", "plan", "goal", "state", "event"]
        assert json.loads(items[-2][1])["t"] == 1.0  # the current state, not the first
        hub.set_status("paused")
        items, _ = client.take(1.0)
        assert json.loads(items[-1][1])["status"] == "paused"

    asyncio.run(main())


def test_one_client_keeps_five_states_per_sim_second() -> None:
    async def main() -> None:
        hub = Hub()
        client = hub.subscribe()
        client.take(0.0)
        for step in range(100):  # 10 sim seconds arriving in one burst
            hub.publish("state", _state(step * 0.1), round(step * 0.1, 3))
        items, _ = client.take(0.0)
        ts = [json.loads(text)["t"] for _, text in items]
        assert len(ts) >= 50 and ts[-1] == 9.9  # >= 5 per sim second, the newest always
        assert all(b - a <= 0.2 + 1e-9 for a, b in zip(ts, ts[1:], strict=False))

    asyncio.run(main())


def test_slow_client_is_thinned_then_dropped_without_blocking() -> None:
    async def main() -> None:
        hub = Hub()
        slow = hub.subscribe()
        for i in range(3 * CLIENT_QUEUE):
            hub.publish("state", _state(i * 0.1), round(i * 0.1, 3))
            hub.publish("event", json.dumps({"type": "event", "i": i}))
        kinds = [k for k, *_ in slow.queue]
        assert kinds.count("event") == 3 * CLIENT_QUEUE  # nothing but frequent kinds is lost
        assert kinds.count("state") < CLIENT_QUEUE and slow.thinned > 0
        assert not slow.dropped
        for i in range(CLIENT_HARD_LIMIT):
            hub.publish("event", json.dumps({"type": "event", "i": i}))
        assert slow.dropped and not slow.queue

    asyncio.run(main())


def test_many_clients_share_a_budget() -> None:
    async def main() -> None:
        hub = Hub()
        clients = [hub.subscribe() for _ in range(50)]
        for c in clients:
            c.take(0.0)
        sent = 0
        for step in range(200):  # 2 wall seconds of a run at 10x: 100 states per second
            now = step / 100
            hub.publish("state", _state(step * 0.1), round(step * 0.1, 3))
            sent += sum(len(c.take(now)[0]) for c in clients)
        # the budget: 1000 states a second over all clients, plus each one's first burst
        assert sent <= 2 * KIND_BUDGET + 50 * KIND_BUDGET / 50 * BURST  # (of 10000)
        last = [json.loads(c.take(10.0)[0][-1][1])["t"] for c in clients]
        assert last == [19.9] * 50  # each still gets the newest state

    asyncio.run(main())


def test_a_client_may_ask_for_fewer_messages() -> None:
    async def main() -> None:
        hub = Hub()
        page = hub.subscribe(max_rate=5.0)  # a page drawing a few frames a second
        full = hub.subscribe()
        page.take(0.0)
        full.take(0.0)
        got = {page: 0, full: 0}
        for step in range(200):  # 2 wall seconds of a run at 10x real time
            now = step / 100
            hub.publish("state", _state(step * 0.1), round(step * 0.1, 3))
            for c in got:
                got[c] += len(c.take(now)[0])
        assert got[page] <= 5 * 2 + 5 * BURST + 1 < got[full]
        items, _ = page.take(10.0)
        assert json.loads(items[-1][1])["t"] == 19.9  # the newest still arrives

    asyncio.run(main())


def _robot_state(robot: str, t: float) -> str:
    return json.dumps({"type": "state", "robot": robot, "t": round(t, 3), "status": "running"})


def test_a_fleets_robots_are_thinned_and_snapshotted_each_on_its_own() -> None:
    async def main() -> None:
        hub = Hub()
        client = hub.subscribe()
        client.take(0.0)
        for step in range(100):  # 10 sim seconds of two robots, in one burst
            for robot in ("agv1", "agv2"):
                t = round(step * 0.1, 3)
                hub.publish("state", _robot_state(robot, t), t, robot=robot)
        items, _ = client.take(0.0)
        for robot in ("agv1", "agv2"):
            ts = [json.loads(x)["t"] for _, x in items if json.loads(x)["robot"] == robot]
            assert len(ts) >= 50 and ts[-1] == 9.9  # 5 per sim second each, the newest
            assert all(b - a <= 0.2 + 1e-9 for a, b in zip(ts, ts[1:], strict=False))
        # a late client gets both robots' latest state; a pause reaches both
        hub.publish("robots", json.dumps({"type": "robots"}))
        late = hub.subscribe()
        items, _ = late.take(1.0)
        assert [k for k, _ in items] == ["robots", "state", "state"]
        assert {json.loads(x)["robot"] for _, x in items[1:]} == {"agv1", "agv2"}
        hub.set_status("paused")
        items, _ = late.take(2.0)
        paused = [json.loads(x) for _, x in items]
        assert {m["robot"] for m in paused if m["status"] == "paused"} == {"agv1", "agv2"}

    asyncio.run(main())
