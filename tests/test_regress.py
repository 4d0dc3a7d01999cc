"""Scenario regression: expectations, sweeps, the process-pool and Ray backends, reports.

The fast scenarios (``tests/scenarios/*.yaml``) run here through the regress machinery;
the long ones (``tests/scenarios/slow/``) run under ``-m slow`` and ``make regress``.
"""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from pydantic import ValidationError

from agv_mission.missions.load.schema.expect import Expectations
from agv_mission.missions.report.expectations import Failure, check
from agv_mission.regress import backends, report
from agv_mission.regress import plan as planning
from cli_in_process import agv

REPO = Path(__file__).resolve().parents[1]
SCENARIOS = REPO / "tests" / "scenarios"
FAST = sorted(SCENARIOS.glob("*.yaml"))
SLOW = SCENARIOS / "slow"

# Short scenarios for the backend comparisons: one per localiser / controller kind.
SHORT = [SCENARIOS / "go_to_tb3.yaml", SCENARIOS / "wander_tb3_odometry.yaml"]


def result_doc(**over) -> dict:
    doc = {
        "status": "succeeded",
        "reason": None,
        "sim_time": 20.0,
        "tasks": [
            {
                "index": 1,
                "type": "patrol",
                "status": "succeeded",
                "reason": None,
                "waypoints": [{"status": "reached"}, {"status": "reached"}],
            },
            {"index": 2, "type": "record_room", "status": "succeeded", "reason": None},
        ],
        "metrics": {
            "distance_driven": 5.0,
            "collisions": 0,
            "min_clearance": 0.1,
            "localization": {"position_rmse": 0.05},
        },
        "rooms_recorded": {"kitchen": {"x": 1.0, "y": 2.0, "yaw": 0.0}},
    }
    doc.update(over)
    return doc


# ------------------------------------------------------------------------ expectations


def test_expectations_met() -> None:
    e = Expectations(
        status="succeeded",
        tasks=["succeeded", None],
        sim_time_max=30,
        collisions_max=0,
        min_clearance_min=0.05,
        distance_driven_max=10,
        localization_rmse_max=0.1,
        rooms_recorded=["kitchen"],
        waypoints_reached=2,
    )
    assert check(e, result_doc()) == []
    assert check(Expectations(tasks={2: "succeeded"}), result_doc()) == []


def test_no_expect_block_means_succeeded() -> None:
    assert check(None, result_doc()) == []
    (f,) = check(None, result_doc(status="failed", reason="task 1 (go_to) failed: blocked"))
    assert f.metric == "status" and "blocked" in str(f.actual)


def test_failures_name_the_metric_and_by_how_much() -> None:
    doc = result_doc(sim_time=42.5)
    doc["metrics"]["collisions"] = 3
    doc["metrics"]["localization"]["position_rmse"] = 0.25
    e = Expectations(
        sim_time_max=30,
        collisions_max=1,
        localization_rmse_max=0.1,
        min_clearance_min=0.2,
        waypoints_reached=4,
        rooms_recorded=["kitchen", "bedroom"],
        tasks=["succeeded", "failed"],
    )
    by = {f.metric: f for f in check(e, doc)}
    assert set(by) == {
        "sim_time_max",
        "collisions_max",
        "localization_rmse_max",
        "min_clearance_min",
        "waypoints_reached",
        "rooms_recorded",
        "tasks.2",
    }
    assert by["sim_time_max"].by == pytest.approx(12.5)
    assert by["collisions_max"].by == 2
    assert by["localization_rmse_max"].by == pytest.approx(0.15)
    assert by["min_clearance_min"].by == pytest.approx(0.1)
    assert by["waypoints_reached"].by == 2
    assert "bedroom" in str(by["rooms_recorded"].actual)
    text = str(by["sim_time_max"])
    assert "sim_time_max" in text and "42.5" in text and "<= 30" in text and "12.5" in text
    assert by["tasks.2"].to_dict()["message"].startswith("tasks.2:")


def test_expected_failure_and_reason() -> None:
    doc = result_doc(status="failed", reason="time limit of 5 s reached during task 1 (patrol)")
    assert check(Expectations(status="failed", reason_contains="time limit"), doc) == []
    (f,) = check(Expectations(status="failed", reason_contains="collision"), doc)
    assert f.metric == "reason_contains"


def test_map_iou_and_missing_metrics() -> None:
    e = Expectations(map_iou_min=0.8)
    assert check(e, result_doc()) == [Failure("map_iou_min", ">= 0.8", "no map reported")]
    doc = result_doc()
    doc["maps"] = [{"map": "house", "free_iou": 0.95, "occupied_iou": 0.3, "coverage": 0.97}]
    assert check(e, doc) == []
    assert check(Expectations(map_occupied_iou_min=0.3, map_coverage_min=0.9), doc) == []
    doc["maps"].append({"map": "second", "free_iou": 0.7, "occupied_iou": 0.2, "coverage": 0.5})
    (f,) = check(e, doc)
    assert f.metric == "map_iou_min" and f.by == pytest.approx(0.1)
    by = {f.metric: f for f in check(Expectations(map_occupied_iou_min=0.25), doc)}
    assert by["map_occupied_iou_min"].by == pytest.approx(0.05)
    assert check(e, result_doc(metrics={"map": {"iou": 0.9}})) == []
    doc = result_doc()
    doc["metrics"]["min_clearance"] = None
    (f,) = check(Expectations(min_clearance_min=0.0), doc)
    assert f.actual is None and f.by is None
    (f,) = check(Expectations(tasks=["succeeded"]), result_doc())
    assert f.metric == "tasks" and f.actual == "2 task(s)"


def test_expectations_are_strict() -> None:
    with pytest.raises(ValidationError):
        Expectations.model_validate({"sim_time": 3})
    with pytest.raises(ValidationError):
        Expectations.model_validate({"status": "maybe"})


# ------------------------------------------------------------------ discovery, variants


def test_discovery_skips_non_missions_and_recurses(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "rooms.yaml").write_text("rooms: {}\n")
    (tmp_path / "a.yaml").write_text("tasks: []\n")
    (tmp_path / "sub" / "b.yaml").write_text("tasks: []\n")
    (tmp_path / "notes.txt").write_text("tasks: []\n")
    found = planning.discover([tmp_path])
    assert [p.name for p in found] == ["a.yaml", "b.yaml"]
    assert planning.discover([tmp_path / "rooms.yaml"]) == [(tmp_path / "rooms.yaml").resolve()]
    with pytest.raises(planning.RegressError, match="no such file"):
        planning.discover([tmp_path / "nope"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(planning.RegressError, match="no mission files"):
        planning.discover([tmp_path / "empty"])


def test_discovery_keeps_every_kind_of_mission_and_says_what_it_skips(tmp_path: Path) -> None:
    files = {
        "list.yaml": "tasks: []\n",
        "tree.yaml": "tree: {type: wait, seconds: 1}\n",
        "fleet.yaml": "robots: [{name: a}]\n",
        "broken.yaml": "tasks: [\n",  # unreadable: the loader must fail on it
        "no_tasks.yaml": "world: small_house\nexpect: {status: succeeded}\n",  # ditto
        "rooms.yaml": "rooms: {kitchen: {polygon: [[0, 0], [1, 0], [1, 1]]}}\n",
        "robot.yaml": "name: r\nwheel_radius: 0.03\nwheel_separation: 0.16\n",
        "map.yaml": "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n",
        "record.yaml": "kitchen: {position: {x: 1}, orientation: {w: 1}}\n",
        "other.yaml": "jobs: {build: 1}\n",
        "tree.xml": "<root/>\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    found = planning.survey([tmp_path])
    assert sorted(p.name for p in found.missions) == [
        "broken.yaml",
        "fleet.yaml",
        "list.yaml",
        "no_tasks.yaml",
        "tree.yaml",
    ]
    why = {p.name: reason for p, reason in found.skipped}
    assert why["rooms.yaml"] == "a rooms file" and why["robot.yaml"] == "a robot file"
    assert "map_server" in why["map.yaml"] and "room record" in why["record.yaml"]
    assert "not a mission" in why["other.yaml"] and "XML" in why["tree.xml"]
    (tmp_path / "uses.yaml").write_text("tree: tree.xml\n")
    why = {p.name: reason for p, reason in planning.survey([tmp_path]).skipped}
    assert "uses.yaml" in why["tree.xml"]
    with pytest.raises(planning.RegressError, match="uses.yaml"):
        planning.survey([tmp_path / "tree.xml"])  # named alone: the mission that runs it
    plan = planning.plan_jobs([tmp_path], output_root=tmp_path / "runs")
    bad = {Path(p.file).name for p in plan.problems}
    assert {"broken.yaml", "no_tasks.yaml"} <= bad  # failed on, not dropped
    suite = ET.fromstring(report.junit_xml([], plan, 0.0))  # one error case per such file
    cases = [c.get("file") for c in suite.iter("testcase")]
    assert len(cases) == len(set(cases)) == len(bad) and suite.get("errors") == str(len(bad))


def test_the_scenario_suite_is_one_run_per_mission_file() -> None:
    yaml_files = sorted(SCENARIOS.rglob("*.yaml"))
    found = planning.survey([SCENARIOS])
    assert len(found.missions) == len(yaml_files)
    assert {p.suffix for p, _ in found.skipped} == {".xml"}


def test_scenario_suite_is_valid_and_covers_the_stack() -> None:
    from agv_mission.missions.load.loader import load_mission

    suite = planning.discover([SCENARIOS])
    loaded = [load_mission(p) for p in suite]
    missions = [x.mission for x in loaded]
    assert all(m.expect is not None for m in missions)
    tasks = {t.type for m in missions for t in m.tasks or ()}
    assert {"go_to", "patrol", "wander", "visit_rooms", "record_room", "map_area"} <= tasks
    worlds = {Path(m.world).parent.name or m.world for m in missions}
    assert {"turtlebot3_world", "small_house", "aws_small_house"} <= worlds
    assert sum("ros_maps" in m.world for m in missions) >= 2
    assert {m.stack.localization.type for m in missions} >= {"ground_truth", "odometry", "amcl"}
    assert {m.stack.local_planner.type for m in missions} == {"mpc", "pure_pursuit"}
    assert {m.stack.global_planner.type for m in missions} == {"cost_grid", "ompl", "grid_astar"}
    assert {"warehouse", "depot"} <= worlds
    planners = {
        m.stack.global_planner.planner for m in missions if m.stack.global_planner.type == "ompl"
    }
    assert len(planners) >= 4
    assert any(m.expect.status == "failed" for m in missions)  # a fault case
    faults = {f.type for m in missions for f in m.faults}
    assert {"lidar_dropout", "wheel_slip", "kidnap"} <= faults
    assert any(m.obstacles for m in missions)
    assert any(getattr(t, "on_failure", "abort") == "skip" for m in missions for t in m.tasks or ())
    # the fast half stays short: task lists within 100 s, trees and fleets within 240 s
    assert len(FAST) >= 6 and all(
        m.limits.time <= (100 if m.tasks and not m.robots else 240)
        for m, p in zip(missions, suite, strict=True)
        if p in FAST
    )


def test_sweeps_are_cartesian_and_yaml_aware() -> None:
    assert planning.expand_variants([]) == [planning.Variant("")]
    vs = planning.expand_variants(
        [
            "stack.global_planner.planner=RRTConnect,RRTstar,BITstar",
            "stack.local_planner.type=mpc,pure_pursuit",
        ]
    )
    assert len(vs) == 6
    assert vs[0] == planning.Variant(
        "planner=RRTConnect type=mpc",
        ("stack.global_planner.planner=RRTConnect", "stack.local_planner.type=mpc"),
    )
    key, values = planning.parse_sweep("tasks.0.pose={x: 1, y: 2},{x: 3, y: 4}, 'a,b'")
    assert key == "tasks.0.pose" and values == ["{x: 1, y: 2}", "{x: 3, y: 4}", "'a,b'"]
    same_leaf = planning.expand_variants(["a.type=x", "b.type=y"])
    assert same_leaf[0].label == "a.type=x b.type=y"
    for bad in (["nokey"], ["=1,2"], ["a=1,,2"], ["a=1", "a=2"]):
        with pytest.raises(planning.RegressError):
            planning.expand_variants(bad)


def test_a_plan_past_a_million_runs_or_63_bit_seeds_is_refused(tmp_path: Path) -> None:
    """Sweeps whose product, or seeds whose count, would plan more than MAX_JOBS runs are
    refused before anything is expanded; seeds that would pass MAX_SEED are the scenario's
    problem, blamed on its seed."""
    scenario = SCENARIOS / "go_to_tb3.yaml"
    values = ",".join(str(k) for k in range(1001))
    with pytest.raises(planning.RegressError, match="variants, more than 1,000,000 runs"):
        planning.expand_variants([f"seed={values}", f"limits.time={values}"])
    with pytest.raises(planning.RegressError, match="more than 1,000,000 runs"):
        planning.plan_jobs([scenario], seeds=planning.MAX_JOBS + 1, output_root=tmp_path)
    late = tmp_path / "late.yaml"
    late.write_text(scenario.read_text().replace("seed: 1\n", "seed: 9223372036854775800\n", 1))
    plan = planning.plan_jobs([late], seeds=10, output_root=tmp_path)
    assert not plan.jobs and [p.field for p in plan.problems] == ["seed"], plan.problems


def test_plan_seeds_follow_the_mission_seed(tmp_path: Path) -> None:
    plan = planning.plan_jobs(
        [SCENARIOS / "go_to_tb3.yaml"],
        ["stack.local_planner.type=mpc,pure_pursuit"],
        seeds=3,
        output_root=tmp_path,
    )
    assert len(plan.jobs) == 6 and not plan.problems
    assert sorted({j["seed"] for j in plan.jobs}) == [1, 2, 3]  # the scenario's seed is 1
    assert all(Path(j["output_root"]) == tmp_path.resolve() for j in plan.jobs)
    swept = planning.plan_jobs(
        [SCENARIOS / "go_to_tb3.yaml"], ["seed=10"], seeds=2, output_root=tmp_path
    )
    assert [j["seed"] for j in swept.jobs] == [10, 11]
    bad = planning.plan_jobs(
        [SCENARIOS / "go_to_tb3.yaml"], ["stack.global_planner.planner=Nope"], output_root=tmp_path
    )
    assert not bad.jobs and "Nope" in str(bad.problems[0])


# --------------------------------------------------------------------- running suites


def _plain(results: list[dict]) -> list[dict]:
    return [report.deterministic_view(r) for r in results]


@pytest.mark.parametrize("scenario", FAST, ids=[p.stem for p in FAST])
def test_fast_scenario_passes(scenario: Path, tmp_path: Path) -> None:
    """Each fast scenario of tests/scenarios through the regress machinery, in this process
    (one worker); the pool's workers are the next test's and the backend comparisons'."""
    plan = planning.plan_jobs([scenario], output_root=tmp_path / "runs")
    assert not plan.problems
    [result] = backends.run_jobs(plan.jobs, "local", 1)
    assert result["passed"], report.failure_text(result) or result["error"]
    assert (Path(result["run_dir"]) / "result.json").is_file()
    assert Path(result["run_dir"]).parent == tmp_path / "runs"


def test_a_pool_of_two_reports_every_scenario(tmp_path: Path) -> None:
    """Two workers: every result arrives once, in order of completion, and the JUnit XML and
    JSON summary count them all."""
    plan = planning.plan_jobs(SHORT, output_root=tmp_path / "runs")
    seen: list[int] = []
    results = backends.run_jobs(
        plan.jobs, "local", 2, on_result=lambda r, done, total: seen.append(done)
    )
    assert seen == list(range(1, len(plan.jobs) + 1))
    assert all(r["passed"] for r in results), [report.failure_text(r) for r in results]
    report.write_reports(results, plan, 1.0, "local", 2, tmp_path / "j.xml", tmp_path / "s.json")
    suite = ET.parse(tmp_path / "j.xml").getroot()
    assert suite.get("tests") == str(len(SHORT)) and suite.get("failures") == "0"
    doc = json.loads((tmp_path / "s.json").read_text())
    assert doc["passed"] and doc["counts"]["runs"] == len(SHORT)


@pytest.mark.slow
def test_slow_scenarios_pass(tmp_path: Path) -> None:
    plan = planning.plan_jobs([SLOW], output_root=tmp_path)
    results = backends.run_jobs(plan.jobs, "local", 2)
    failed = {r["name"]: report.failure_text(r) or r["error"] for r in results if not r["passed"]}
    assert not failed, failed


def test_parallel_runs_equal_serial_runs(tmp_path: Path) -> None:
    """Process-pool workers reproduce the in-process runs (wall-clock keys aside)."""
    plan = planning.plan_jobs(SHORT, ["stack.local_planner.type=mpc,pure_pursuit"], 1, tmp_path)
    serial = backends.run_jobs(plan.jobs, "local", 1)
    parallel = backends.run_jobs(plan.jobs, "local", 2)
    assert [r["status"] for r in serial] == [r["status"] for r in parallel]
    assert _plain(serial) == _plain(parallel)
    assert {r["variant"] for r in serial} == {"type=mpc", "type=pure_pursuit"}


def test_sweep_comparison(tmp_path: Path) -> None:
    plan = planning.plan_jobs(
        [SCENARIOS / "go_to_tb3.yaml"],
        ["stack.global_planner.planner=RRTConnect,BITstar"],
        seeds=2,
        output_root=tmp_path,
    )
    results = backends.run_jobs(plan.jobs, "local", 2)
    rows = report.compare(results)
    assert [r["variant"] for r in rows] == ["planner=RRTConnect", "planner=BITstar"]
    for row in rows:
        assert row["runs"] == 2 and row["success_rate"] == 1.0
        assert row["sim_time_mean"] > 0 and row["sim_time_p95"] >= row["sim_time_mean"] - 1e-9
        assert row["driven_length_mean"] > 0 and row["min_clearance_min"] is not None
        assert row["solve_ms_p50_mean"] is not None
    from rich.console import Console

    console = Console(width=200, record=True)
    console.print(report.comparison_table(rows))
    text = console.export_text()
    assert "planner=BITstar" in text and "100%" in text


@pytest.mark.slow  # Ray's start-up: 12 s
def test_ray_backend_matches_local(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="ray not installed (pip install 'agv-mission[ray]')")
    plan = planning.plan_jobs(SHORT, seeds=2, output_root=tmp_path)
    local = backends.run_jobs(plan.jobs, "local", 1)
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    try:
        remote = backends.run_jobs(plan.jobs, "ray", 2)
    finally:
        ray.shutdown()
    assert all(r["error"] is None for r in remote), [r["error"] for r in remote]
    assert _plain(local) == _plain(remote)


def test_ray_backend_missing_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(planning.RegressError, match=r"pip install 'agv-mission\[ray\]'"):
        backends.run_jobs([{"id": 0}], "ray", 1)


def test_worker_errors_become_error_results(tmp_path: Path) -> None:
    (job,) = planning.plan_jobs([SCENARIOS / "go_to_tb3.yaml"], output_root=tmp_path).jobs
    result = backends.run_job({**job, "scenario": str(tmp_path / "gone.yaml")})
    assert result["status"] == "error" and not result["passed"] and "cannot read" in result["error"]
    xml = report.junit_xml(
        [result], planning.Plan([], [], [planning.Variant("")], 1, tmp_path), 0.5
    )
    case = ET.fromstring(xml).find(".//testcase")
    assert case is not None and case.find("error") is not None


# ------------------------------------------------------------------------------- CLI


def test_cli_broken_expectation_exits_1_naming_the_metric(tmp_path: Path) -> None:
    text = (SCENARIOS / "go_to_tb3.yaml").read_text()
    broken = tmp_path / "broken.yaml"
    broken.write_text(text.replace("sim_time_max: 15.0", "sim_time_max: 2.0"))
    assert broken.read_text() != text
    junit, summary = tmp_path / "out.xml", tmp_path / "sum.json"
    r = agv(
        "regress",
        str(broken),
        str(SCENARIOS / "record_room_house.yaml"),
        "--junit",
        str(junit),
        "--json",
        str(summary),
        "--output",
        str(tmp_path / "runs"),
        "--workers",
        "2",
    )
    assert r.returncode == 1, r.stdout + r.stderr
    assert "sim_time_max" in r.stdout and "1/2 passed" in r.stdout
    assert "Traceback" not in r.stdout + r.stderr
    root = ET.parse(junit).getroot()
    assert root.get("tests") == "2" and root.get("failures") == "1"
    failure = root.find(".//testcase/failure")
    assert failure is not None and "sim_time_max" in failure.get("message", "")
    assert "off by" in failure.get("message", "")
    doc = json.loads(summary.read_text())
    assert not doc["passed"] and doc["counts"] == {
        "runs": 2,
        "passed": 1,
        "failed": 1,
        "errors": 0,
        "invalid": 0,
    }
    (bad,) = [run for run in doc["runs"] if not run["passed"]]
    assert bad["failures"][0]["metric"] == "sim_time_max" and bad["failures"][0]["by"] > 0


def test_cli_invalid_input_exits_2(tmp_path: Path) -> None:
    """Each answer called in this process, as all of this file's (the program started as a
    process runs a suite in test_mission_matrix.py::test_regress_runs_every_kind)."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("tasks:\n  - {type: wander, duration: 1}\nexpect:\n  sim_time: 3\n")
    r = agv("regress", str(bad), "--output", str(tmp_path))
    assert r.returncode == 2 and "expect.sim_time" in r.stderr and "Traceback" not in r.stderr
    r = agv("regress", str(tmp_path / "nope"))
    assert r.returncode == 2 and "no such file" in r.stderr
    r = agv("regress", str(SCENARIOS / "go_to_tb3.yaml"), "--sweep", "seed")
    assert r.returncode == 2 and "KEY=V1,V2" in r.stderr
    r = agv("regress", str(SCENARIOS / "go_to_tb3.yaml"), "--backend", "slurm")
    assert r.returncode == 2


def test_run_ignores_expect(tmp_path: Path) -> None:
    text = (SCENARIOS / "record_room_house.yaml").read_text()
    scenario = tmp_path / "s.yaml"
    scenario.write_text(text.replace("sim_time_max: 20.0", "sim_time_max: 0.0"))
    r = agv("run", str(scenario), "--output", str(tmp_path / "runs"))
    assert r.returncode == 0, r.stdout + r.stderr


def test_sweep_over_planners_compares_them_as_they_are(tmp_path: Path) -> None:
    """cost_grid and three OMPL planners give four different rows, each with planned /
    shortest and driven / shortest per leg (the OMPL plans are OMPL's own)."""
    planners = "{type: cost_grid},{type: ompl, planner: RRTConnect},"
    planners += "{type: ompl, planner: RRTstar},{type: ompl, planner: BITstar}"
    plan = planning.plan_jobs(
        [SCENARIOS / "patrol_tb3_pure_pursuit.yaml"],
        [f"stack.global_planner={planners}"],
        seeds=1,
        output_root=tmp_path,
    )
    results = backends.run_jobs(plan.jobs, "local", 2)
    rows = report.compare(results)
    assert len(rows) == 4
    ratios = [row["planned_vs_shortest_mean"] for row in rows]
    assert all(r is not None and r >= 0.99 for r in ratios)
    assert len(set(ratios)) == 4  # no planner's plan is another's
    assert all(row["driven_vs_shortest_max"] >= row["driven_vs_shortest_mean"] for row in rows)
    for r in results:  # per leg, in each run: planned, shortest and driven lengths
        legs = r["metrics"]["navigation"]["legs"]
        assert legs and all(leg["shortest"] > 0 and leg["planned"] > 0 for leg in legs)
        assert r["metrics"]["navigation"]["planned_length"] == pytest.approx(
            sum(leg["planned"] for leg in legs), abs=1e-3
        )
    from rich.console import Console

    console = Console(width=250, record=True)
    console.print(report.comparison_table(rows))
    console.print(report.results_table(results, variants=4))
    text = console.export_text()
    assert text.count("planned/shortest") == 2 and "driven/shortest" in text
    for row in rows:
        assert f"{row['planned_vs_shortest_mean']:.3f}" in text
