"""How a vehicle runs actions: instant actions and node actions, their states (6.11) and
their blocking types (6.12), each action type's work (6.8). A part of
:class:`~agv_mission.vda5050.vehicle.Vehicle`, which holds the lock every method here runs
under."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from agv_mission.atomic import atomic_write_text
from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.vda5050 import factsheet as fs
from agv_mission.vda5050.body import BodySnapshot, VehicleBody
from agv_mission.vda5050.order_checks import first_error, number
from agv_mission.vda5050.protocol import Action, InstantActions

FINAL = ("FINISHED", "FAILED")


@dataclass
class ActionRun:
    """One action the vehicle holds: where it came from and how far it got."""

    action: Action
    status: str = "WAITING"
    node_seq: int | None = None  # the node it triggers on; None: an instant action
    started: float | None = None  # simulated time it started
    result: str | None = None
    elapsed: float = 0.0  # simulated seconds of work done (frozen while paused)
    request: int = 0  # the body's charge request it waits for (start/stopCharging)
    #: its node was reached: it starts as soon as the blocking types let it (still WAITING)
    triggered: bool = False

    def doc(self) -> dict[str, Any]:
        d = {
            "actionId": self.action.actionId,
            "actionType": self.action.actionType,
            "actionStatus": self.status,
        }
        if self.action.actionDescription:
            d["actionDescription"] = self.action.actionDescription
        if self.result is not None:
            d["resultDescription"] = self.result
        return d


class VehicleActions:
    """The action side of a vehicle: every action it holds, by ``actionId``, and what they
    change (pause, loads).

    Mixed into :class:`~agv_mission.vda5050.vehicle.Vehicle`, whose ``_error``,
    ``_advance``, ``state_body`` and publishers it calls, and whose order side
    (:class:`~agv_mission.vda5050.vehicle_orders.VehicleOrders`) does ``cancelOrder``."""

    body: VehicleBody
    serial: str
    log_dir: Path
    actions: dict[str, ActionRun]
    loads: list[dict[str, Any]]
    paused: bool
    last_node_id: str
    _load_count: int
    _lock: Any

    def _receive_instant(self, doc: dict[str, Any]) -> None:
        try:
            msg = InstantActions.model_validate(doc)
        except ValidationError as exc:
            self._error(
                "validationError", f"instantActions: {first_error(exc)}", topic="instantActions"
            )
            return
        if len(msg.actions) > fs.MAX_INSTANT_ACTIONS:
            self._error(
                "validationError", f"instantActions: more than {fs.MAX_INSTANT_ACTIONS} actions"
            )
            return
        for action in msg.actions:
            run = ActionRun(action)
            self.actions[action.actionId] = run
            spec = fs.ACTIONS.get(action.actionType)
            if spec is None or "INSTANT" not in spec["scopes"]:
                run.status = "FAILED"
                what = "unknown action" if spec is None else "not an instant action"
                self._error(
                    "actionError",
                    f"{action.actionType}: {what}",
                    actionId=action.actionId,
                    actionType=action.actionType,
                )
                continue
            self._start_action(run, self.body.snapshot())

    def _blocked(self) -> bool:
        """A SOFT or HARD action stops driving while it runs or waits to run (6.12)."""
        return any(
            a.action.blockingType != "NONE"
            and (a.status in ("INITIALIZING", "RUNNING") or (a.triggered and a.status == "WAITING"))
            for a in self.actions.values()
        )

    # ---------------------------------------------------------------- actions (6.8, 6.11, 6.12)

    def _run_actions(self, snap: BodySnapshot) -> None:
        """Carry the running actions on, then start the triggered ones in list order as
        their blocking types allow (6.12, figure 17): a HARD action starts only when no
        other action runs, and nothing starts while it runs; SOFT and NONE run beside
        each other (SOFT and HARD stop driving: :meth:`_blocked`)."""
        for run in list(self.actions.values()):
            if run.status == "RUNNING":
                self._continue_action(run, snap)
        for run in list(self.actions.values()):
            if not (run.triggered and run.status == "WAITING"):
                continue
            active = [a for a in self.actions.values() if a.status in ("INITIALIZING", "RUNNING")]
            if any(a.action.blockingType == "HARD" for a in active):
                break
            if run.action.blockingType == "HARD" and active:
                break  # waits for what runs now; the actions after it wait for it
            self._start_action(run, snap)
            if run.action.blockingType == "HARD" and run.status == "RUNNING":
                break

    def _start_action(self, run: ActionRun, snap: BodySnapshot) -> None:
        a, kind = run.action, run.action.actionType
        run.started, run.elapsed = snap.time, 0.0
        run.status = "RUNNING"
        if kind == "startPause":
            self.paused = True
            self.body.pause()
            run.status = "FINISHED"
        elif kind == "stopPause":
            self.paused = False
            self.body.resume()
            run.status = "FINISHED"
        elif kind == "cancelOrder":
            self._cancel_order(run)
        elif kind == "stateRequest":
            run.status = "FINISHED"  # the state published after this message is the answer
        elif kind == "factsheetRequest":
            self.publish_factsheet()
            run.status = "FINISHED"
        elif kind == "logReport":
            self._log_report(run)
        elif kind == "initPosition":
            self._init_position(run)
        elif kind in ("startCharging", "stopCharging"):
            run.request = self.body.charge(kind == "startCharging")  # RUNNING until answered
        elif kind == "drop" and not self.loads:
            run.status, run.result = "FAILED", "no load to drop"
            self._error("loadError", "drop: the vehicle carries no load", actionId=a.actionId)
        # pick, drop, waitForTrigger: RUNNING until done (_continue_action) or cancelled

    def _continue_action(self, run: ActionRun, snap: BodySnapshot) -> None:
        kind = run.action.actionType
        if kind in ("startCharging", "stopCharging"):
            if snap.charge_id < run.request:
                return  # the body has not handled it yet (communication with the charger)
            if snap.charge_error is None:
                run.status, run.result = "FINISHED", snap.dock or "not charging"
            else:
                run.status, run.result = "FAILED", snap.charge_error
                self._error(
                    "chargingError", f"{kind}: {snap.charge_error}", actionId=run.action.actionId
                )
            return
        if kind == "cancelOrder":
            if not self._driving(snap) and not any(
                a.status not in FINAL for a in self.actions.values() if a.node_seq is not None
            ):
                run.status = "FINISHED"
            return
        if kind in ("pick", "drop"):
            self._continue_load_handling(run, snap)

    def _continue_load_handling(self, run: ActionRun, snap: BodySnapshot) -> None:
        """``pick`` / ``drop``: done once its ``duration`` of unpaused simulated time passed."""
        kind = run.action.actionType
        if not self.paused and run.started is not None:
            run.elapsed += max(0.0, snap.time - run.started)
        run.started = snap.time
        duration = number(run.action.param("duration"), 5.0)
        if run.elapsed + 1e-9 < duration:
            return
        if kind == "pick":
            self._load_count += 1
            load_id = str(run.action.param("loadId") or f"{self.serial}-load{self._load_count}")
            load: dict[str, Any] = {"loadId": load_id, "loadPosition": "deck"}
            if run.action.param("loadType"):
                load["loadType"] = str(run.action.param("loadType"))
            self.loads.append(load)
            run.result = load_id
        else:
            wanted = run.action.param("loadId")
            idx = next(
                (i for i, ld in enumerate(self.loads) if wanted in (None, ld["loadId"])), None
            )
            if idx is None:
                run.status, run.result = "FAILED", f"no load {wanted}"
                return
            run.result = self.loads.pop(idx)["loadId"]
        run.status = "FINISHED"

    def trigger(self, action_id: str) -> bool:
        """The trigger a ``waitForTrigger`` waits for (a button on the vehicle)."""
        with self._lock:
            run = self.actions.get(action_id)
            if run is None or run.action.actionType != "waitForTrigger" or run.status != "RUNNING":
                return False
            run.status = "FINISHED"
            self._advance(self.body.snapshot())
        self.publish_state()
        return True

    def _init_position(self, run: ActionRun) -> None:
        a = run.action
        try:
            x, y, theta = (float(a.param(k)) for k in ("x", "y", "theta"))
        except (TypeError, ValueError):
            run.status, run.result = "FAILED", "x, y and theta must be numbers"
            self._error(
                "validationError",
                "initPosition: x, y and theta must be numbers",
                actionId=a.actionId,
            )
            return
        map_id = a.param("mapId", self.body.map_id)
        x0, x1, y0, y1 = self.body.extent
        on_map = all(map(math.isfinite, (x, y, theta))) and x0 <= x <= x1 and y0 <= y <= y1
        if map_id != self.body.map_id or not on_map:
            run.status, run.result = "FAILED", f"not a pose on map {self.body.map_id}"
            self._error(
                "initPositionError",
                f"initPosition: map {map_id!r}, x={x}, y={y}",
                actionId=a.actionId,
            )
            return
        self.body.set_pose(Pose2D(x, y, wrap_angle(theta)))
        if a.param("lastNodeId") is not None:
            self.last_node_id = str(a.param("lastNodeId"))
        run.status = "FINISHED"

    def _log_report(self, run: ActionRun) -> None:
        name = f"{self.serial}-{time.strftime('%Y%m%dT%H%M%S')}-{run.action.actionId}.json"[:120]
        doc = {"reason": str(run.action.param("reason", "")), "state": self.state_body()}
        try:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.log_dir / name, json.dumps(doc, indent=2) + "\n")
        except OSError as exc:
            run.status, run.result = "FAILED", f"cannot store the report: {exc}"
            return
        run.status, run.result = "FINISHED", str(self.log_dir / name)
