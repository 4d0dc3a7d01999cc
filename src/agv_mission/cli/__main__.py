"""``python -m agv_mission.cli``: the same as ``agv-mission``."""

from agv_mission.cli import main

if __name__ == "__main__":
    main()
