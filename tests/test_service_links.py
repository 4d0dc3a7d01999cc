"""The worker <-> service links: the worker never waits for the service, the service's event
loop never waits for a half-written message, and the registry answers from memory."""

from __future__ import annotations

import asyncio
import json
import multiprocessing
from pathlib import Path

from agv_mission.service.links import Outbox, WorkerLink
from agv_mission.service.registry import Registry, Submission


def _state(t: float) -> tuple[str, str, str, float]:
    return ("msg", "state", json.dumps({"type": "state", "t": t}), t)


def test_outbox_never_blocks_and_keeps_the_newest_state_and_every_event() -> None:
    service, worker = multiprocessing.Pipe(duplex=True)
    outbox = Outbox(worker)
    big = "x" * 100_000  # fills the socket buffer at once: the pump thread blocks, not put
    outbox.put(("msg", "map", big, None))
    for i in range(2000):  # a fast run's steps while nobody reads
        outbox.put(_state(i * 0.1))
        if i % 100 == 0:
            outbox.put(("msg", "event", json.dumps({"type": "event", "i": i}), i * 0.1))
    assert outbox.coalesced > 0  # states replaced while queued
    received = []

    def done() -> bool:
        events = sum(item[1] == "event" for item in received)
        return events == 20 and any(item[3] == 1999 * 0.1 for item in received)

    while not done():
        assert service.poll(30), "the outbox stopped delivering"
        received.append(service.recv())
    outbox.close()
    assert received[0][1] == "map"
    events = [json.loads(item[2])["i"] for item in received if item[1] == "event"]
    assert events == list(range(0, 2000, 100))  # all of them, in order
    states = [item[3] for item in received if item[1] == "state"]
    assert states == sorted(states) and len(states) < 2000  # thinned, never reordered


def test_worker_link_speaks_multiprocessing_frames_both_ways() -> None:
    async def main() -> None:
        service, worker = multiprocessing.Pipe(duplex=True)
        link = await WorkerLink.of(service)
        payload = {"points": list(range(20_000))}  # > 16 kB: header and body written apart
        worker.send(("msg", "scan", payload, 1.5))
        worker.send(("status", "running"))
        assert await link.recv() == ("msg", "scan", payload, 1.5)
        assert await link.recv() == ("status", "running")
        link.send(("pause",))
        link.send(("cmd_vel", 0.1, -0.2))
        await link.writer.drain()
        assert worker.recv() == ("pause",)
        assert worker.recv() == ("cmd_vel", 0.1, -0.2)
        worker.close()
        try:
            await link.recv()
        except asyncio.IncompleteReadError:
            pass
        else:
            raise AssertionError("a closed worker end must end the link")
        link.close()

    asyncio.run(main())


def test_registry_answers_from_memory_and_keeps_every_write(tmp_path: Path) -> None:
    async def main() -> None:
        registry = Registry(tmp_path)
        run, stored = registry.add(Submission("patrol", "name: patrol\n", ["a=1"], 3))
        await asyncio.wrap_future(stored)
        registry.set_status(run["id"], "running")
        registry.update(run["id"], progress={"sim_time": 4.0, "task_index": 0})
        now = await registry.aget(run["id"])
        assert now is not None and now["status"] == "running" and now["started"]
        assert now["progress"]["sim_time"] == 4.0
        now["progress"]["sim_time"] = -1.0  # a caller's copy: the cache is not touched
        again = await registry.aget(run["id"])
        assert again is not None and again["progress"]["sim_time"] == 4.0
        registry.set_status(run["id"], "succeeded", "done")
        listed = await registry.alist()  # queued behind the writes: as fresh as the cache
        assert [(r["id"], r["status"]) for r in listed] == [(run["id"], "succeeded")]
        registry.close()

        reopened = Registry(tmp_path)  # from disk alone
        row = await reopened.aget(run["id"])
        assert row is not None
        assert (row["status"], row["reason"], row["set"], row["seed"]) == (
            "succeeded",
            "done",
            ["a=1"],
            3,
        )
        assert row["progress"]["sim_time"] == 4.0 and row["started"] and row["ended"]
        assert reopened.submission(run["id"]).mission == "name: patrol\n"
        reopened.close()

    asyncio.run(main())
