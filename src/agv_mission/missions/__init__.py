"""Missions: what the user wrote, the run it becomes, and what the run produced.

Three sub-packages, data flowing one way:

- :mod:`~agv_mission.missions.load`: the mission as written, checked and resolved
  (schema, YAML with lines, ``--set``, world checks, the tree assembly) -> a
  ``LoadedMission``;
- :mod:`~agv_mission.missions.run`: the simulation-clock loop over the world's robots,
  its observer/control hooks -> a ``RunRecord``;
- :mod:`~agv_mission.missions.report`: the run directory, summaries and the scenario
  expectations, read from a ``RunRecord`` (never a live run).
"""
