"""Run observers and run control: what every front door sees of a run and how it steers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.observe import RunStart
from agv_mission.missions.run.record import RunRecord
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.missions.run.samples import StepSample

MISSION = """\
name: observed
world: turtlebot3_world
start: {x: -2.0, y: -0.5, yaw: 0.0}
seed: 3
stack:
  localization: {type: amcl}
  global_planner: {type: grid_astar}
tasks:
  - type: go_to
    pose: {x: -0.5, y: -1.6, yaw: 0.0}
  - type: record_room
    room: corner
    settle: 0.5
limits: {time: 60.0}
"""


class Recorder:
    """Keeps everything it is shown."""

    def __init__(self) -> None:
        self.starts: list[RunStart] = []
        self.samples: list[StepSample] = []
        self.records: list[RunRecord] = []

    def on_start(self, start: RunStart) -> None:
        self.starts.append(start)

    def on_step(self, sample: StepSample) -> None:
        self.samples.append(sample)

    def on_end(self, record: RunRecord) -> None:
        self.records.append(record)


def load(tmp_path: Path, extra: list[str] | None = None):
    return load_mission(tmp_path / "observed.yaml", extra, text=MISSION)


def test_an_observer_sees_every_step_of_a_run(tmp_path: Path) -> None:
    loaded = load(tmp_path)
    seen = Recorder()
    record = run_mission(loaded, observers=[seen])
    assert record.status == "succeeded", record.reason

    [start] = seen.starts
    assert start.start == loaded.start and start.world_map is loaded.world.map
    assert start.tree_nodes[0].depth == 0 and start.tree_nodes[0].status == "INVALID"
    assert len(start.tree_nodes) > 3
    assert seen.records == [record]  # on_end once, with the record returned

    samples = seen.samples
    assert len(samples) == len(record.trajectory)
    times = np.array([s.t for s in samples])
    assert np.all(np.diff(times) > 0)
    np.testing.assert_allclose(times, record.trajectory[:, 0])
    for s, row in zip(samples, record.trajectory, strict=True):
        assert (s.truth.x, s.truth.y, s.estimate.x, s.v, s.w) == (
            row[1],
            row[2],
            row[4],
            row[7],
            row[8],
        )

    # scans at the lidar's rate, over the whole run
    scan_times = np.array([s.t for s in samples if s.scan is not None])
    rate = loaded.robot.lidar.rate
    assert abs(len(scan_times) - times[-1] * rate) <= 2
    np.testing.assert_allclose(np.diff(scan_times), 1.0 / rate, atol=0.11)

    plans = [s.plan for s in samples if s.plan is not None]
    assert len(plans) == len(record.paths) >= 1
    assert np.array_equal(plans[0], record.paths[0])
    assert any(s.horizon is not None for s in samples)
    assert any(s.goal is not None for s in samples)

    # the particle cloud comes with filter updates, a covariance with every estimate
    clouds = [s.particles for s in samples if s.particles is not None]
    assert clouds and all(c.ndim == 2 and c.shape[1] == 3 for c in clouds)
    assert all(s.covariance is not None and s.covariance.shape == (3, 3) for s in samples)

    events = [e for s in samples for e in s.events]
    assert events == record.events
    assert any(e["event"] == "room_recorded" for e in events)

    tasks = [s.task_index for s in samples]
    assert tasks[0] == 0 and 1 in tasks
    assert {s.task_type for s in samples} >= {"go_to", "record_room"}
    changes = [s.tree_nodes for s in samples if s.tree_nodes is not None]
    assert 2 <= len(changes) < len(samples)
    assert changes[-1][0].status == "SUCCESS"


class CancelAt:
    def __init__(self, t: float) -> None:
        self.t = t
        self.calls = 0

    def before_step(self, run: MissionRun) -> None:
        self.calls += 1
        if run.sim.time >= self.t:
            run.cancel("stopped from outside")


def test_a_control_cancels_a_run(tmp_path: Path) -> None:
    seen = Recorder()
    control = CancelAt(3.0)
    record = run_mission(load(tmp_path), observers=[seen], control=control)
    assert record.status == "aborted"
    assert record.reason == "stopped from outside"
    assert record.tasks[0]["status"] == "aborted"
    assert 2.9 <= record.sim_time <= 3.1
    assert control.calls == len(record.trajectory) + 1  # the last call cancelled
    assert seen.records == [record]


def test_runs_without_observers_build_no_samples(tmp_path: Path) -> None:
    run = MissionRun(load(tmp_path, ["limits.time=1"]), None)
    assert run.handle.remote_command is None
    while run.step():
        pass
    assert run.lead.sampler is None and run.record().status == "failed"


def test_safety_watch_skips_only_queries_that_cannot_change_its_outcome(tmp_path: Path) -> None:
    """The runner queries clearance and contacts only where they could matter (a bound
    from the last query and the distance moved); its minimum clearance and contacts are
    those of querying every step, which an observer does here."""

    class EveryStep(Recorder):
        def __init__(self) -> None:
            super().__init__()
            self.clearances: list[float] = []
            self.contacts = 0

        def on_step(self, sample: StepSample) -> None:
            self.clearances.append(exact_clearances()[1])
            self.contacts += run.sim.contacts()

    watcher = EveryStep()
    run = MissionRun(load(tmp_path), None, [watcher])
    exact_clearances = run.sim.clearances
    queries = []
    run.sim.clearances = lambda: queries.append(1) or exact_clearances()  # type: ignore[method-assign]
    run.drive()
    assert run.status == "succeeded" and len(watcher.clearances) > 20
    assert run.lead.min_clearance == min(watcher.clearances)
    assert 0 < len(queries) < len(watcher.clearances)  # some steps were skipped
    assert watcher.contacts == 0 and not run.lead.collisions
