"""BARN (Benchmark Autonomous Robot Navigation): its worlds run by its protocol (barn.md).

:mod:`~agv_mission.barn.protocol` holds the protocol (start, goal, clock, outcomes, the
metric) and the referee that applies it to a run; :mod:`~agv_mission.barn.suite` plans and
runs one world into a run directory and summarises many; :mod:`~agv_mission.barn.workers`
runs them in parallel (processes or Ray).
"""
