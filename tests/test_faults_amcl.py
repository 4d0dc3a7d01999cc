"""amcl under faults (issue 6, issue 3's kidnap): lidar dropout, wheel slip and a kidnap.

The mission is issue 6's, with the time limit cut to 35 s to keep the test short: the
patrol then ends at the limit (about 20 s before its own end), so the run "fails" with a
reason that names the faults that fired. What matters is that amcl finds the robot again
after the kidnap at t = 20 s: over seeds 1-21 of the full mission, 0.6-6.4 s (median
1.6 s); with amcl's uniform injection 2.6-26.2 s (median 5.6 s, 5 seeds over 10 s).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import run_mission

KIDNAP_AT = 20.0
FOUND_WITHIN = 10.0  # seconds after the kidnap
LIMIT = 35.0

MISSION = """\
name: faults
world: small_house
start: livingroom
seed: {seed}
stack:
  localization:
    type: amcl
{localization}
faults:
  - {{type: lidar_dropout, rate: 0.2}}
  - {{type: wheel_slip, factor: 0.1}}
  - {{type: kidnap, time: {at}, pose: {{x: 1.5, y: -4.0, yaw: 1.0}}}}
tasks:
  - type: patrol
    waypoints:
      - {{x: 7.0, y: -2.0, yaw: 0.0}}
      - {{x: -0.5, y: 1.8, yaw: 1.57}}
limits: {{time: {limit}}}
"""

# Issue 6's profile, as written in its mission; and the named profile that does the same.
ISSUE_PROFILE = """\
    laser_model_type: likelihood_field_prob
    laser_log_likelihood_scale: 0.05
    max_particles: 20000
    recovery_alpha_slow: 0.001
    recovery_alpha_fast: 0.1"""
NAMED_PROFILE = "    profile: recovery"


def run(tmp_path, seed: int, localization: str):
    path = tmp_path / "faults.yaml"
    path.write_text(MISSION.format(seed=seed, localization=localization, at=KIDNAP_AT, limit=LIMIT))
    return run_mission(load_mission(path))


@pytest.mark.parametrize(
    ("seed", "localization"),
    # Seeds where uniform injection (amcl's) took 13.4 s and 26.2 s; here 1.2 s and 5.6 s.
    [(4, ISSUE_PROFILE), (13, ISSUE_PROFILE), (7, NAMED_PROFILE)],
    ids=["issue-profile-seed4", "issue-profile-seed13", "profile-recovery-seed7"],
)
def test_kidnapped_robot_is_found_again_despite_dropout_and_slip(tmp_path, seed, localization):
    record = run(tmp_path, seed, localization)

    # Every fault fired: dropouts and slip from the start, the kidnap on time.
    faults = {f["type"]: f for f in record.extras["faults"]}
    assert set(faults) == {"lidar_dropout", "wheel_slip", "kidnap"}
    assert all(f["fired"] for f in faults.values()), faults
    assert faults["kidnap"]["first"] == pytest.approx(KIDNAP_AT, abs=0.11)
    assert faults["kidnap"]["count"] == 1
    assert faults["lidar_dropout"]["count"] > 10 and faults["wheel_slip"]["first"] < 1.0

    # Ends by succeeding, or failing with a reason that names the kidnap; never past the limit.
    assert record.status == "succeeded" or (
        record.status == "failed" and "kidnap" in (record.reason or "")
    ), (record.status, record.reason)
    assert record.sim_time <= LIMIT + 0.2

    tr = record.trajectory
    t = tr[:, 0]
    err = np.hypot(tr[:, 1] - tr[:, 4], tr[:, 2] - tr[:, 5])
    yaw_err = np.abs((tr[:, 3] - tr[:, 6] + math.pi) % (2 * math.pi) - math.pi)
    assert err[t < KIDNAP_AT - 0.1].max() < 0.15  # tracking through dropout and slip
    assert err[(t > KIDNAP_AT) & (t < KIDNAP_AT + 0.5)].max() > 2.0  # carried away
    after = t >= KIDNAP_AT + FOUND_WITHIN
    assert after.sum() > 20  # the run went on long enough to tell
    assert err[after].max() < 0.2, f"lost {err[after].max():.2f} m at the end"
    assert yaw_err[after].max() < 0.1
