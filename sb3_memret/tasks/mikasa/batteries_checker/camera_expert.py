"""BatteriesChecker's check-cycle expert on what MIKASA's harness gives a policy alone: a protocol entry, not an
upper bound.

``BatteryCheckController`` reads every battery, tray slot, the socket and the button from a simulated detector and
the arm's joint velocities, so its rows are a privileged upper bound. ``CameraBatteryCheckController`` plays the same
cycles on the harness's inputs only (``ControllerSpec.harness_inputs``):

- **the tray** (``read_tray``): the first frame that shows every battery in play standing (the writer's
  ``read_batteries``: their green tops, in MIKASA's slot order) places the slots; MIKASA lays the tray's 5x3 grid
  about the tray's centre, so the readings' mean offset from that grid places the tray, and from it the socket
  (20 cm beyond the tray) and the button (24 cm to its left), as MIKASA lays them. At development seeds 5000-5009
  (BatteriesCheckerEasy-6) a battery was read within 0.5 cm of its slot and the socket laid within 0.3 cm of its
  seat. Two batteries of a row, 5 cm apart along the camera's line of sight, can show their tops as one blob: the
  reader, told how many stand, splits it (``read_batteries``'s ``count``);
- **the batteries** (``SeenBatteries``): each stands at its slot until the fingers close on it (the hand within
  reach of it); then it is carried at its offset from the hand. Let go, where it went is not known until the camera
  shows it again (Easy's env snaps a tested battery home; Hard's stands in the socket or where it was set down): it
  is the green top that no other battery explains, once two calls read it in one place. The hand holds still,
  fingers open, while it looks; unseen there (the arm over the socket hides the tray from the camera, and the hand a
  battery below it), it goes up over the tray's centre (``CameraCheckGains.look_height``), above the camera's lines
  of sight. A top partly hidden reads centimetres off its centre: the socket's walls hide a seated battery's side,
  and at development seed 5002 (Easy-6) the arm hid part of a neighbour, read 2.3 cm off its slot, twice running.
  So a top counts as the battery's near the socket or its own slot (``at_seat``), where MIKASA puts it exactly (on
  the seat's axis, resting on the socket's floor 1.1 cm over the seat, or in its slot); elsewhere, only read from
  the look height. One unseen for ``unseen_calls`` is taken to be where it was let go;
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``).

Which batteries are done comes from its prompt alone, as for the detector's version; the lamp is never read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.batteries_checker.expert import (
    GRIP_PICK, BatteryCheckController, CheckGains, CheckGoal,
)
from sb3_memret.tasks.mikasa.batteries_checker.writer import CAP_TOP_Z, read_batteries
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED
from sb3_memret.tasks.mikasa.core.harness_expert import HarnessExpert
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains

TRAY_COLUMNS = 3  # MIKASA's tray: slot i in row i // 3 (along y) and column i % 3 (along x) ...
ROW_PITCH, COLUMN_PITCH = 0.052, 0.050  # ... this far apart, the grid centred on the tray (5 rows, 3 columns)
MIDDLE_ROW, MIDDLE_COLUMN = 2, 1
SOCKET_FROM_TRAY = np.array([0.20, 0.0])  # MIKASA lays the socket and the button from the tray's centre
BUTTON_FROM_TRAY = np.array([0.0, 0.24])
SEAT_Z = 0.03  # a battery's centre standing on the tray; the socket's seat (the detector's points) ...
SEATED_ABOVE = 0.011  # ... over which a battery seated in the socket rests, on the socket's floor
LOOK_TOL = 0.03  # the hand within this of the look height sees the table clear


class BatteryLayout(NamedTuple):
    """The fixed scene: the slots' (n, 3) points (where each battery stands at home), the socket's seat (3,) and the
    button cap's top (3,), as the detector's expert reads them, and the tray's centre (2,)."""

    slots: np.ndarray
    socket: np.ndarray
    cap: np.ndarray
    tray: np.ndarray


def read_tops(rgb: Any, count: int | None = None) -> np.ndarray:
    """The (n, 2) table points of the standing batteries' tops one base-camera frame (H, W, 3) shows, in MIKASA's
    slot order (the writer's reader; ``count``: the batteries in play, two tops that touch in the picture split)."""
    return read_batteries(np.asarray(as_numpy(rgb)), count)


def read_tray(rgb: Any, n_batteries: int) -> BatteryLayout | None:
    """The slots, socket and button from one base-camera frame (H, W, 3); None unless it shows exactly
    ``n_batteries`` standing batteries."""
    tops = read_tops(rgb, n_batteries)
    if len(tops) != n_batteries:
        return None
    index = np.arange(n_batteries)
    grid = np.column_stack([-(index % TRAY_COLUMNS - MIDDLE_COLUMN) * COLUMN_PITCH,
                            (index // TRAY_COLUMNS - MIDDLE_ROW) * ROW_PITCH])
    tray = (tops - grid).mean(axis=0)
    slots = np.column_stack([tray + grid, np.full(n_batteries, SEAT_Z)])
    return BatteryLayout(slots, np.array([*(tray + SOCKET_FROM_TRAY), SEAT_Z]),
                         np.array([*(tray + BUTTON_FROM_TRAY), CAP_TOP_Z]), tray)


@dataclass(frozen=True)
class CameraCheckGains(CheckGains):
    """``CheckGains`` and how a battery let go is found again (metres, calls)."""

    explained: float = 0.025  # a green top this close (xy) to another battery's place is that battery's (partly
    # hidden, one read 2.3 cm off); the slots are 5 cm apart
    at_seat: float = 0.03  # the one let go, read this close to the socket or its slot: seated there; read elsewhere,
    # only from the look height (partly hidden tops read centimetres off their centres)
    settled: float = 0.003  # two calls' readings this close: the battery let go has come to rest there
    look_after: int = 2  # unseen this many calls after it was let go: look from over the tray ...
    look_height: float = 0.3  # ... the hand this high (the camera's lines of sight to the tray and socket pass below
    # it: the camera looks down from 30 cm beyond the table's centre, 60 cm up) ...
    unseen_calls: int = 12  # ... and after this many, it is where it was let go


class SeenBatteries:
    """One env's batteries as far as it knows: at their slots until gripped, carried at their offset from the hand,
    and, once let go, unsettled until the camera shows them at rest."""

    def __init__(self, check: CameraCheckGains, slots: np.ndarray, socket: np.ndarray,
                 read_tops: Callable[[Any], np.ndarray]):
        self.check, self.read_tops = check, read_tops
        self.slots = np.asarray(slots, dtype=np.float64)
        self.seated = np.asarray(socket, dtype=np.float64) + (0.0, 0.0, SEATED_ABOVE)
        self.places = self.slots.copy()
        self.held: int | None = None
        self.offset = np.zeros(3)
        self.unsettled: int | None = None  # the battery let go, until seen at rest
        self.reading: np.ndarray | None = None  # its last reading
        self.unseen = 0

    def track(self, tcp: np.ndarray, gap: float, rgb: Any) -> np.ndarray:
        """The (n, 3) batteries now, the hand at ``tcp`` with the fingers ``gap`` apart, ``rgb`` the base camera's
        frame."""
        c = self.check
        if not c.held_gap[0] <= gap <= c.held_gap[1]:
            if self.held is not None:  # let go: where it went is read from the camera
                self.unsettled, self.reading, self.unseen = self.held, None, 0
            self.held = None
        elif self.held is None:
            reach = np.linalg.norm(self.places - tcp, axis=1)
            if reach.min() <= c.held_reach:
                self.held = int(reach.argmin())
                self.offset = tcp - self.places[self.held]
                if self.unsettled == self.held:
                    self.unsettled = None
        if self.held is not None:
            self.places[self.held] = tcp - self.offset
        elif self.unsettled is not None:
            self._find(self.unsettled, rgb, clear_view=tcp[2] >= c.look_height - LOOK_TOL)
        return self.places.copy()

    def _find(self, k: int, rgb: Any, clear_view: bool) -> None:
        """Look for battery ``k`` (let go): the green top nearest its place that no other battery explains, by the
        socket or its slot or (``clear_view``: the hand at the look height) anywhere; settle it there once two calls
        agree, or where it was let go once unseen for ``unseen_calls``."""
        c = self.check
        tops = np.asarray(self.read_tops(rgb), dtype=np.float64).reshape(-1, 2)
        others = np.delete(self.places, k, axis=0)[:, :2]
        if len(tops) and len(others):
            tops = tops[np.linalg.norm(tops[:, None] - others[None], axis=2).min(axis=1) > c.explained]
        if len(tops) and not clear_view:
            seats = np.stack([self.seated[:2], self.slots[k, :2]])
            tops = tops[np.linalg.norm(tops[:, None] - seats[None], axis=2).min(axis=1) <= c.at_seat]
        if not len(tops):
            self.reading, self.unseen = None, self.unseen + 1
            if self.unseen >= c.unseen_calls:
                self.unsettled = None
            return
        top = tops[np.linalg.norm(tops - self.places[k, :2], axis=1).argmin()]
        if self.reading is not None and np.linalg.norm(top - self.reading) <= c.settled:
            self.places[k] = self._seat(k, top)
            self.unsettled = None
        self.reading = top

    def _seat(self, k: int, top: np.ndarray) -> np.ndarray:
        """Battery ``k`` read at rest at ``top``: seated in the socket or at its slot when within ``at_seat`` of
        either."""
        seats = np.stack([self.seated, self.slots[k]])
        near = np.linalg.norm(seats[:, :2] - top, axis=1)
        return seats[near.argmin()].copy() if near.min() <= self.check.at_seat else np.array([*top, SEAT_Z])


class CameraBatteryCheckController(HarnessExpert, BatteryCheckController):
    """Checks, one cycle at a time, each battery its prompt's checklist does not name, reading only the base camera's
    image, the hand's pose and the gripper's opening (the module docstring says how). ``n_batteries``: the task's;
    ``paced_every``: the control steps executed between its calls; ``read``: image -> a ``BatteryLayout`` or None;
    ``tops``: image -> the standing batteries' (n, 2) tops (by default ``read_tops`` expecting all of them)."""

    def __init__(self, prompt_template: PromptTemplate, hard: bool, n_batteries: int, paced_every: int,
                 chunk_len: int = 8, gains: TouchGains | None = None, check: CameraCheckGains | None = None,
                 read: Callable[[Any], BatteryLayout | None] | None = None,
                 tops: Callable[[Any], np.ndarray] | None = None):
        super().__init__(prompt_template, hard, chunk_len, gains, check or CameraCheckGains())
        self._on_harness(paced_every, chunk_len)
        self.n_batteries = n_batteries
        self.read = read or (lambda rgb: read_tray(rgb, n_batteries))
        self.tops = tops or (lambda rgb: read_tops(rgb, n_batteries))
        self.layouts: list[BatteryLayout | None] = []
        self.batteries: list[SeenBatteries | None] = []

    def _forget(self, n_envs: int) -> None:
        self.layouts, self.batteries = [None] * n_envs, [None] * n_envs

    def _forget_env(self, i: int) -> None:
        self.layouts[i] = self.batteries[i] = None

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        inputs = self._harness_inputs(obs, len(prompts))
        tcp, gaps, steps, rgb = inputs
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            if self.layouts[i] is None:
                self.layouts[i] = self.read(rgb[i])
                if self.layouts[i] is None:
                    continue  # the tray not yet read whole: hold still
                self.batteries[i] = SeenBatteries(self.check, self.layouts[i].slots, self.layouts[i].socket,
                                                   self.tops)
            seen, layout, pos = self.batteries[i], self.layouts[i], tcp[i, :3]
            batteries = seen.track(pos, float(gaps[i]), rgb[i])
            if seen.unsettled is not None:
                goal = self._look(seen, layout, pos)
            else:
                goal = self._cycle_goal(self.cycles[i], p, pos, float(gaps[i]), batteries, layout.slots,
                                        layout.socket, layout.cap)
            if goal is None:
                chunks[i, :, -1] = GRIP_CLOSED  # every battery checked: hold still
            else:
                chunks[i] = self._chunk(tcp[i], steps[i], goal)
        return self._ran(inputs, chunks)

    def _look(self, seen: SeenBatteries, layout: BatteryLayout, pos: np.ndarray) -> CheckGoal:
        """Where the hand waits while the battery let go is looked for, fingers open: still, until it has been unseen
        for ``look_after`` calls and is not being read again; then over the tray's centre, out of the camera's way."""
        if seen.reading is not None or seen.unseen < self.check.look_after:
            return CheckGoal(pos.copy(), GRIP_PICK, rise_first=False)
        return CheckGoal(np.array([*layout.tray, self.check.look_height]), GRIP_PICK)


__all__ = ["BatteryLayout", "CameraBatteryCheckController", "CameraCheckGains", "SeenBatteries", "read_tops",
           "read_tray"]
