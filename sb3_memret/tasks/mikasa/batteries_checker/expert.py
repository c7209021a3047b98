"""A scripted frozen controller for MIKASA's BatteriesChecker Easy and Hard: check every battery the prompt's
checklist does not name yet, one complete cycle at a time.

It stands in for a VLA finetuned on BatteriesChecker with the checklist written into its prompt (``the battery check
found slot 1 dead and slot 3 working.``). It reads ``BatteryObservation`` (joints, hand pose, where each battery, tray
slot, the socket and the button are: a simulated object detector) and takes which batteries are done only from its
prompt's first checklist fact, whatever that fact is about (a decoy or a wrong fact misleads it). Without one it starts
from slot 1 at every cycle: a check made is forgotten once its cycle ends.

Within one cycle it keeps the cycle's stage (per env): nothing in sight tells a battery picked from its slot from one
already tested and snapped back (Easy), nor a battery taken out of the socket from one about to go in. A cycle:

- ``pick``: come down over the target battery (the lowest slot the checklist leaves out) with the fingers open 3 cm,
  close them once the TCP is measured at its centre;
- ``insert``: lift it clear, carry it over the socket, come over it 5 cm up, lower it 1.5 cm a decision and open
  (Hard: down in the socket's hole): MIKASA seats it once it is let go within 1 cm of the socket's centre and lights
  the lamp for a working one; a battery let go is waited for until it comes to rest;
- Hard only, ``extract``, ``return`` and ``leave``: grasp it in the socket once it has come to rest, carry it back
  over its slot, lower it in and open (MIKASA counts it home within 2.3 cm), rise straight up with the fingers open;
  Easy's env snaps it home itself;
- ``press``: the fingers closed, come down over the button until the TCP is ``press_height`` over the cap's top
  (MIKASA counts a press with the TCP within 7.5 cm of its axis and 2.5 cm over the cap), then ``lift`` it clear:
  the cycle ends, and the next starts from the prompt's checklist.

A battery let go anywhere else is picked up again where it lies. Motion within a chunk uses
``ScriptedTouchController``'s fitted model of the ``pd_ee_delta_pose`` arm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.batteries_checker.checklist import stated_checklist
from sb3_memret.tasks.mikasa.core.carry_expert import GRIP_CLOSED, REACH_X
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT, ScriptedTouchController, TouchGains, tcp_velocity

STAGES = ("pick", "insert", "extract", "return", "leave", "press", "lift")
# the gripper command that opens the fingers 3 cm apart (each at 1.5 cm of MIKASA's -1 cm..4 cm range): a 2 cm
# battery fits with 5 mm to spare each side. Opened 4 cm, a finger's outer face came down on the next row's battery
# 5 cm away and tipped it over or dragged it up (BatteriesChecker-6's two rows): MIKASA then counted it not home
GRIP_PICK = 0.0


@dataclass(frozen=True)
class CheckGains:
    """The grasp, the carry, the seating and the press (metres)."""

    grasp_above: float = 0.005  # close the fingers with the TCP this far over the battery's centre: it hangs below the
    # grip (held at its top centimetre it swings about the fingers), and its lower half goes into the socket while the
    # fingertips stay over the socket's walls ...
    grasp_tol: float = 0.005  # ... once it is measured this close to that point
    held_gap: tuple[float, float] = (0.012, 0.019)  # the fingers' gap closed on a 2 cm battery (pressed into it) ...
    held_reach: float = 0.025  # ... with its centre this close to the TCP: it is in hand
    carry_height: float = 0.13  # the battery's centre while carried (its bottom 7 cm over the others' tops)
    near: float = 0.03  # the carried battery this close (xy) to where it goes: come over it at ``approach`` ...
    approach: float = 0.05  # ... this far over its seat's centre height (its bottom 2 cm clear of the socket's
    # walls: coming down fast it overshoots by up to 7 mm, and 5 mm clear, a battery still 9 mm off caught the wall
    # and tilted in hand)
    over_tol: float = 0.004  # ... and lower it once its xy is this close to the seat ...
    lower_tol: float = 0.008  # ... going on down while it stays this close, at most ``lower_step`` a decision (a
    lower_step: float = 0.015  # descent from the carry height straight to the seat swung it 8 mm off) ...
    seat_above: float = 0.005  # ... to this far over the seat's centre height
    release_tol: float = 0.006  # let go once its xy is this close (MIKASA seats it within 1 cm) ...
    drop_above: float = 0.04  # ... and its centre this far over the socket's: it drops into the socket's hole, and
    # MIKASA seats it as it falls (within 2.5 cm of the seat's height); lowered further it jams on the walls' edge ...
    hard_drop_above: float = 0.02  # Hard: let go only once it is this far over, down in the hole with the fingers
    # round it: MIKASA's seating moves it 1 cm into the socket's floor, and one dropped from 4 cm was flung out and
    # over;
    hard_release_tol: float = 0.008  # there, this close (xy) is close enough (one 7 mm off stuck on the wall's face,
    # 1.6 cm over the seat, held and pushed down to the episode's end)
    set_above: float = 0.01  # ... or over its slot's, where it stands on the table again
    seated: float = 0.012  # a battery let go this close (xy) to the socket's centre ...
    seated_z: float = 0.02  # ... and down to this over the socket's top is in it (it rests 11 mm over, on the floor)
    home: float = 0.015  # ... or to its slot: it is home
    at_rest: float = 0.002  # a battery let go that moved less than this since the last decision has come to rest
    clear_height: float = 0.13  # rise straight up to this TCP height before moving sideways from low down (and,
    cleared: float = 0.03  # Hard, from a battery set home: to this much below it before closing the fingers)
    press_height: float = 0.012  # the TCP over the cap's top at the press (MIKASA: within 2.5 cm) ...
    pressed_seen: float = 0.02  # ... counted pressed once this low within press_xy of the cap's axis
    press_xy: float = 0.03
    lift_height: float = 0.08  # after the press the TCP rises to this over the cap's top; the cycle ends once
    lifted: float = 0.06  # it is this high over it
    reach_tol: float = 0.003  # the hand this close to its reach (``TouchGains.max_x``), over the socket and not
    # coming down:
    reach_drop_above: float = 0.06  # let go from up to this over it (at development seed 5022, Easy-3, the socket
    # 19 cm out, the hand came no lower than 5.5 cm over it)
    far_x: float = 0.12  # the TCP beyond this x (the socket's side, at the arm's reach) ...
    far_action: float = 0.3  # ... commands translations of at most this (the IK target 3 cm away): a full action
    # there asks for a pose 10 cm away, out of reach, which pd_ee_delta_pose's IK fails to solve and drops, and the
    # arm stood still over the socket for up to 60 decisions (development seed 5007, Easy-3)


@dataclass
class Cycle:
    """One env's check under way: the battery (index from 0; None between cycles) and the stage it is at."""

    battery: int | None = None
    stage: str = "pick"
    seen: np.ndarray | None = None  # where the battery was at the last decision


class CheckGoal(NamedTuple):
    """Where a chunk heads: ``point`` (the TCP's), with the fingers at ``grip`` (``close``: closed, the TCP measured
    there),
    coming down a funnel (``funnel``) or rising straight first (``rise_first``)."""

    point: np.ndarray
    grip: float
    close: bool = False
    funnel: bool = False
    rise_first: bool = True


class BatteryCheckController(ScriptedTouchController):
    """Checks, one cycle at a time, each battery its prompt's checklist does not name (``hard``: putting it back in
    its slot before the press)."""

    stateful = True

    def __init__(self, prompt_template: PromptTemplate, hard: bool, chunk_len: int = 8,
                 gains: TouchGains | None = None, check: CheckGains | None = None):
        super().__init__(chunk_len, gains or TouchGains(max_step=0.025, arrive_tol=0.002, max_x=REACH_X),
                         vocabulary=(), field="checklist", prompt_template=prompt_template, key="battery")
        self.hard, self.check = hard, check or CheckGains()
        self.cycles: list[Cycle] = []

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.cycles = [Cycle() for _ in seeds]

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.cycles[i] = Cycle()

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        batteries = as_numpy(extra["battery_positions"]).astype(np.float64)
        slots = as_numpy(extra["slot_positions"]).astype(np.float64)
        socket = as_numpy(extra["socket_position"]).astype(np.float64)
        button = as_numpy(extra["button_position"]).astype(np.float64)  # the cap's top
        qpos = as_numpy(obs["agent"]["qpos"]).astype(np.float64)
        velocity = tcp_velocity(qpos, as_numpy(obs["agent"]["qvel"]))
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            goal = self._cycle_goal(self.cycles[i], p, tcp[i, :3], qpos[i, 7:9].sum(), batteries[i], slots[i],
                                    socket[i], button[i])
            if goal is None:
                chunks[i, :, -1] = GRIP_CLOSED  # every battery checked: hold still
            else:
                chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, goal)
        return chunks

    def _cycle_goal(self, cycle: Cycle, parsed: ParsedPrompt, pos: np.ndarray, gap: float, batteries: np.ndarray,
                    slots: np.ndarray, socket: np.ndarray, cap: np.ndarray) -> CheckGoal | None:
        """Where to head: the cycle under way's goal, or (between cycles) the next battery's; None when the
        checklist names every battery."""
        for _ in range(2):  # a cycle that ends here hands over to the next at once
            if cycle.battery is None:
                cycle.battery, cycle.stage, cycle.seen = self._next_battery(parsed, len(batteries)), "pick", None
            if cycle.battery is None:
                return None
            goal = self._goal(cycle, pos, gap, batteries, slots, socket, cap)
            if goal is not None:
                return goal
        return None

    @staticmethod
    def _next_battery(parsed: ParsedPrompt, n_batteries: int) -> int | None:
        """The first battery (index from 0) whose slot the prompt's checklist does not name, or None."""
        done = stated_checklist(parsed)
        return next((k for k in range(n_batteries) if k + 1 not in done), None)

    def _goal(self, cycle: Cycle, pos: np.ndarray, gap: float, batteries: np.ndarray, slots: np.ndarray,
              socket: np.ndarray, cap: np.ndarray) -> CheckGoal | None:
        """Advance ``cycle`` by what this observation shows (``gap``: between the fingers), then where to head (None:
        the cycle has ended)."""
        c, k = self.check, cycle.battery
        battery = batteries[k]
        held = c.held_gap[0] <= gap <= c.held_gap[1] and np.linalg.norm(battery - pos) <= c.held_reach
        in_socket = np.linalg.norm(battery[:2] - socket[:2]) <= c.seated and battery[2] <= socket[2] + c.seated_z
        home = np.linalg.norm(battery[:2] - slots[k, :2]) <= c.home
        moving = cycle.seen is not None and np.linalg.norm(battery - cycle.seen) > c.at_rest
        coming_down = cycle.seen is not None and cycle.seen[2] - battery[2] > c.at_rest
        cycle.seen = battery.copy()
        if cycle.stage in ("pick", "extract") and held:
            cycle.stage = "insert" if cycle.stage == "pick" else "return"
        elif cycle.stage in ("insert", "return") and not held:
            if moving:  # just let go: wait until it comes to rest (Easy's env snaps it home from the socket)
                return CheckGoal(pos.copy(), GRIP_PICK, rise_first=False)
            if cycle.stage == "insert" and self.hard and in_socket:
                cycle.stage = "extract"
            elif home and (cycle.stage == "return" or not self.hard):  # Easy's seated and snapped home, Hard's back
                cycle.stage = "leave" if cycle.stage == "return" else "press"
            else:  # dropped on the way: pick it up where it lies
                cycle.stage = "pick"
        elif cycle.stage == "leave" and pos[2] >= c.clear_height - c.cleared:
            cycle.stage = "press"
        elif cycle.stage == "press" and np.linalg.norm(pos[:2] - cap[:2]) <= c.press_xy \
                and pos[2] <= cap[2] + c.pressed_seen:
            cycle.stage = "lift"
        elif cycle.stage == "lift" and pos[2] >= cap[2] + c.lifted:
            cycle.battery = None
            return None
        if cycle.stage in ("pick", "extract"):
            point = battery + (0.0, 0.0, c.grasp_above)  # close once the TCP is measured there: closed where it was
            # predicted to arrive, the fingers met a battery 1 cm off and pushed it, held it by its side and lost it
            return CheckGoal(point, GRIP_PICK, close=bool(np.linalg.norm(pos - point) <= c.grasp_tol), funnel=True)
        if cycle.stage in ("insert", "return"):
            seat = socket if cycle.stage == "insert" else slots[k]
            hand = pos - battery  # the battery sits off the TCP in the fingers: steer the battery
            off, over = float(np.linalg.norm(battery[:2] - seat[:2])), float(battery[2] - seat[2])
            into_socket = self.hard and cycle.stage == "insert"
            release = c.set_above if cycle.stage == "return" else c.hard_drop_above if self.hard else c.drop_above
            at_reach = pos[0] >= self.gains.max_x - c.reach_tol and not coming_down  # can come no lower (nor
            # nearer): at development seed 5037 the hand bounced 3 mm up and down there to the episode's end
            if off <= (c.hard_release_tol if into_socket else c.release_tol) and \
                    over <= (max(release, c.reach_drop_above) if at_reach else release):
                return CheckGoal(pos.copy(), GRIP_PICK, rise_first=False)
            low = over < c.approach - c.over_tol  # on its way down into the seat
            if off <= (c.lower_tol if low else c.over_tol) and over <= c.approach + c.over_tol:
                height = seat[2] + max(c.seat_above, over - c.lower_step)  # down a step, centred again at each
            else:  # come over the seat from above; off it low down, rise clear of its walls first
                height = seat[2] + c.approach if off <= c.near else c.carry_height
            return CheckGoal(np.array([seat[0], seat[1], height]) + hand, GRIP_CLOSED, rise_first=off > c.near)
        if cycle.stage == "leave":  # straight up, the fingers open: closed low down they would take it along again
            return CheckGoal(np.array([pos[0], pos[1], c.clear_height]), GRIP_PICK, rise_first=False)
        if cycle.stage == "press":
            return CheckGoal(cap + (0.0, 0.0, c.press_height), GRIP_CLOSED, funnel=True)
        return CheckGoal(cap + (0.0, 0.0, c.lift_height), GRIP_CLOSED, rise_first=False)

    def _waypoint(self, pos: np.ndarray, goal: Any) -> np.ndarray:
        """The goal's point; from low down and far sideways, straight up to the clear height first; coming down onto a
        battery or the button, never below a funnel over it, and from below the funnel straight up onto it (rising to
        the clear height instead, the hand on its way down the funnel, 4 cm sideways, turned back up, and the chunk's
        rise-then-dive swung it 2.5 cm off and onto the battery's top)."""
        g, point = self.gains, np.asarray(goal.point, dtype=np.float64)
        sideways = float(np.linalg.norm(point[:2] - pos[:2]))
        funnel = point[2] + min(g.hover_height, g.funnel_slope * sideways)
        rise_to = funnel if goal.funnel else self.check.clear_height  # not the goal's height: straight up over the
        # socket at the arm's reach (x 19 cm), the hand stopped at 18 cm (development seed 5019, Easy-3)
        if goal.rise_first and sideways > self.check.near and pos[2] < rise_to - 0.02:
            return np.array([pos[0], pos[1], rise_to])
        if goal.funnel:
            return np.array([point[0], point[1], funnel])
        return point

    def _grip(self, pos: np.ndarray, goal: Any) -> float:
        return GRIP_CLOSED if goal.close else goal.grip

    def _chunk(self, tcp_pose: np.ndarray, step: np.ndarray, goal: Any) -> np.ndarray:
        """The planned chunk, its translations shortened near the arm's reach (``CheckGains.far_x``)."""
        chunk = super()._chunk(tcp_pose, step, goal)
        if tcp_pose[0] > self.check.far_x:
            norms = np.linalg.norm(chunk[:, :3], axis=1, keepdims=True)
            chunk[:, :3] *= np.minimum(1.0, self.check.far_action / np.maximum(norms, 1e-9))
        return chunk


__all__ = ["BatteryCheckController", "CheckGains", "CheckGoal", "Cycle", "GRIP_PICK", "STAGES"]
