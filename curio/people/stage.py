"""The people stage of the local controller: drive among people by predicting them.

The stages before it (pure pursuit, regulation, the costmap guard) choose an arc; this stage
reviews it against the tracked people (``/people``, ``map``) within
``interaction_radius_m``, predicted at constant velocity over ``horizon_s``:

1. **Candidates** — the chosen arc at its target speed, the same arc slower, *stop* on it,
   nine curvatures at full and half speed, side-steps (a hard or half bend to either side
   for 1 or 2 s, then straight on, at full and half speed: the lane change the others cannot
   express), and backing off when someone walks straight at the rover. Within
   ``near_distance_m`` of a person ahead (who is not walking away) the speed is at most
   ``near_speed_mps``.
   Each is rolled out from the current speed under the acceleration limits (braking twice as
   hard).
2. **Hard rule: never drive at a person** — a candidate that comes nearer than
   ``min_distance_m`` to a person (footprint to body, ``person_radius_m`` around a track)
   and nearer than stopping would come to them over the horizon is out; so is one whose
   footprint meets a lethal costmap cell within ``collision_horizon_s``. Stopping is always
   allowed (stepping aside from someone walking at the rover is allowed too: it keeps the
   closest approach farther than stopping would).
3. **Comfort** — each person has a comfortable distance, ``passing_distance_m`` beside and
   behind them growing to ``head_on_distance_m`` in front of someone walking (the rover
   ahead of their motion); a track that never walked (a pillar? someone standing since the
   rover came) only asks ``min_distance_m``. For someone walking it grows with the
   prediction's uncertainty, ``prediction_growth_mps`` per second ahead for the first 2 s.
   For each person the worst squared shortfall over the horizon counts (nearer times weigh
   more); a candidate's cost is what its motion *adds* to the worst that stopping would
   leave (someone walking up behind the rover is not its doing), plus a fifth of the whole
   (so it steps aside from someone walking at it and a dodge that ends farther away wins
   over standing there), against progress towards the lookahead point and bending away from
   the chosen curvature. Coming nearer than
   ``min_distance_m`` to anyone (even where stopping would too: someone walking at the rover)
   costs ten times more than any discomfort, so the rover rather dodges. When the chosen arc
   is allowed and costs (almost) nothing, it is kept as it is.
4. **Yield, then "Excuse me"** — when the best is to stand still the rover *yields*
   (``YIELDING``: the progress checks pause, for up to ``yield_max_s``). After
   ``excuse_me_after_s`` it says ``excuse_me_text`` (every ``excuse_me_interval_s`` at most)
   and for ``assertive_s`` the comfortable distances shrink to ``min_distance_m``, so it
   creeps past a person who does not move rather than freezing for ever; meanwhile a track
   that never walked (a pillar or a box the size of a person) is left to the costmap and
   the safety stage, as any obstacle is.

While it steers round someone the controller does not start turning in place back to its
path (:meth:`PeopleStage.steering`): the stage's arcs take it back once they have passed.
Turning in place (to the path, or to a goal's heading) follows the hard rule too: it waits
while the turn it makes (its direction and size, not the whole circle the corners could
sweep) would bring the footprint nearer than ``min_distance_m`` to someone, and nearer than
where the turn began (:meth:`PeopleStage.review_turn`; "Excuse me" as above; after
``yield_max_s`` the progress checks run again). In a narrow
passage (the costmap says the footprint's corners are near a wall) the comfortable distances
are ``min_distance_m``: stopping in a doorway helps nobody through it. The prediction's room
for someone walking still applies there (wait for a walker rather than meet them in the
doorway) until "Excuse me" was said.

**Movers with known intent** (:attr:`PeopleStage.movers`, optional): other rovers of a fleet
(``curio/fleet/intent.py``) join the people as obstacles whose future is *known*: predicted
along their planned path, not on a straight line, each with its own radius (a circle round its
footprint) instead of ``person_radius_m``; one that stands asks only ``min_distance_m``. A
person track on top of a mover (the tracker took the rover for a person) is dropped, and
"Excuse me" is said only when a person is near (the assertive shrink happens all the same).

With :attr:`PeopleStage.stop_short` (the guide sets it on the way to a tour stop) a goal
with people standing on it counts as reached within ``stop_short_m``: the rover keeps its
distance instead of pushing into the group. The safety stage's stop zone still has the last
word on every command.

The rollouts and the scores are compiled (:mod:`curio.people.stage_kernel`): the same
floating-point operations, in the same order, as numpy would do them (the simulator's reports
are compared byte for byte), each candidate scored once per review.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from curio.core.config import ControllerConfig, PeopleConfig
from curio.core.geometry import Pose2D, approach, wrap_angle
from curio.core.messages import PeopleTracks
from curio.nav.controller import ControlStatus, LocalController, Review
from curio.nav.costs import LETHAL, NO_INFORMATION, cost_at_distance
from curio.people.stage_kernel import (
    combine_costs,
    path_clearances,
    people_clearances,
    rollout_candidates,
    score_candidates,
    score_params,
    situation,
)
from curio.robot import RobotModel

__all__ = ["PeopleStage"]

F64 = npt.NDArray[np.float64]

STEP_S = 0.1
STALE_S = 1.0  # tracks older than this are ignored
WALKING_MPS = 0.3
W_PROGRESS = 1.0
W_COMFORT = 30.0
W_BEND = 0.3
W_SAFE = 300.0
BACK_OFF_MPS = 0.1
COMFORT_SLACK = 1e-3  # a comfort cost this small is nobody's concern
STEERING_S = 1.5
TURN_STEP_RAD = 0.1  # the turn in place is checked at this spacing (corners 4 cm apart)
TURN_GAP_S = 0.3  # a turn in place not reviewed for this long has ended
TURN_SAME_RAD = 0.2  # a target heading this close to the last one is the same turn
GROWTH_CAP_S = 2.0  # the comfortable distance grows with the prediction for this long
ROVER_MARGIN_M = 0.25  # a person track this near a known rover's circle is that rover (m)
_COST_WEIGHTS = np.array([W_SAFE, W_COMFORT, W_PROGRESS, W_BEND])  # for combine_costs


def _dense(a: F64) -> F64:
    """``a`` as a C-contiguous array (a copy only when it is not one). The kernels are compiled
    once per array layout, and a slice's layout depends on its shape (one tracked person makes
    ``people[:, :4]`` contiguous, two do not): passing dense arrays keeps the kernels to the one
    variant ``curio warmup`` compiles, so nothing compiles inside the running loop (it did at a
    kidnap: seconds of CPU on a Pi and ~6 MB of LLVM memory kept for good)."""
    return np.ascontiguousarray(a)


class PeopleStage:
    """Reviews the controller's arc against predicted people (see the module docstring).

    Args:
        cfg: ``people``.
        ccfg: ``nav.controller`` (speeds, accelerations, the collision horizon).
        robot: the robot model (footprint, speed on an arc).
        tracks: the latest ``/people`` message (None before the first).

    Attributes:
        movers: optional; called with the horizon's times (s from now), returns obstacles
            with known futures (``now`` ``(J, 5)``, ``future`` ``(J, K, 2)``, ``radius_m``
            ``(J,)``: :class:`curio.fleet.intent.KnownMovers`).
        rovers: optional; the other rovers the fleet link knows of now, ``(J, 3)`` x, y
            (``map``, m) and a radius round each footprint (m). A person track on one of them
            is that rover, not a person: dropped (the right-of-way rule and, with
            ``fleet.traffic.predict_peers``, the movers deal with rovers; taking a rover that
            holds at a doorway's staging point for a person made the one with the right of way
            yield to it — ``curio bench fleet`` deadlocks).
    """

    def __init__(self, cfg: PeopleConfig, ccfg: ControllerConfig, robot: RobotModel,
                 tracks: Callable[[], PeopleTracks | None]) -> None:
        self.cfg = cfg
        self.ccfg = ccfg
        self.robot = robot
        self.tracks = tracks
        self.footprint = np.asarray(robot.footprint_points, dtype=np.float64)
        self.reach_m = float(np.max(np.hypot(self.footprint[:, 0], self.footprint[:, 1])))
        k = max(2, math.ceil(cfg.horizon_s / STEP_S))
        self.times: F64 = np.arange(k + 1, dtype=np.float64) * STEP_S
        self.weights: F64 = np.linspace(1.0, 0.4, k + 1)
        self.stop_short = False
        self.on_excuse_me: list[Callable[[str], None]] = []
        self._yield_since: float | None = None
        self._last_excuse_s = -math.inf
        self._assertive_until_s = -math.inf
        # The turn in place under way: the heading it started from and its target (rad,
        # map), and when it was last reviewed (s).
        self._turn: tuple[float, float, float] | None = None
        self.excuse_me_count = 0
        self.reviews = 0
        self.changed = 0
        self._changed_at_s = -math.inf
        self.last_costs: tuple[F64, ...] = ()  # the last review's numbers (for inspection)
        self.movers: Callable[[F64], Any] | None = None
        self.rovers: Callable[[], F64] | None = None
        self._futures: F64 = np.zeros((0, len(self.times), 2))  # of the rows after the people
        self._persons = 0  # people (not movers) in the last people_near
        self._turns: dict[tuple[float, float], F64] = {}  # _turning_rows' (kmax, vmax)

    # -- people ------------------------------------------------------------------------------
    def people_near(self, pose: Pose2D, now_s: float) -> F64:
        """``(J, 6)`` tracked people (then the movers) within reach, predicted to ``now_s``:
        x, y, vx, vy (map, m, m/s), 1 for a track that walked (0: it never did), and how much
        larger than ``person_radius_m`` its body is (m; 0 for people)."""
        return self._with_movers(self._people(pose, now_s), pose)

    def _people(self, pose: Pose2D, now_s: float) -> F64:
        msg = self.tracks()
        if msg is None or not msg.tracks or now_s - msg.stamp > STALE_S:
            return np.zeros((0, 6))
        dt = max(0.0, now_s - msg.stamp)
        reach = self.cfg.interaction_radius_m + self.reach_m
        rows = []
        for t in msg.tracks:
            x, y = t.x_m + t.vx_mps * dt, t.y_m + t.vy_mps * dt
            if math.hypot(x - pose.x, y - pose.y) > reach:
                continue
            vx, vy = t.vx_mps, t.vy_mps
            sp = math.hypot(vx, vy)
            if sp < 0.1:
                vx = vy = 0.0
            elif sp > 2.0:
                vx, vy = vx * 2.0 / sp, vy * 2.0 / sp
            rows.append((x, y, vx, vy, 1.0 if t.walked else 0.0, 0.0))
        people = np.array(rows, dtype=np.float64).reshape(-1, 6)
        rovers = self.rovers() if self.rovers is not None and len(people) else None
        if rovers is not None and len(rovers):
            d = np.hypot(people[:, None, 0] - rovers[None, :, 0],
                         people[:, None, 1] - rovers[None, :, 1])
            people = people[(d > rovers[None, :, 2] + ROVER_MARGIN_M).all(axis=1)]
        return people

    def _with_movers(self, people: F64, pose: Pose2D) -> F64:
        """``people`` followed by the movers within reach (their futures kept for the
        review); a person track within a mover's radius is the mover."""
        self._futures = np.zeros((0, len(self.times), 2))
        self._persons = len(people)
        known = self.movers(self.times) if self.movers is not None else None
        if known is None or len(known.now) == 0:
            return people
        reach = self.cfg.interaction_radius_m + self.reach_m
        now, radius = known.now, known.radius_m
        near = np.hypot(now[:, 0] - pose.x, now[:, 1] - pose.y) <= reach + radius
        if not near.any():
            return people
        now, radius = now[near], radius[near]
        if len(people):
            d = np.hypot(people[:, None, 0] - now[None, :, 0], people[:, None, 1] - now[None, :, 1])
            people = people[(d > radius[None, :]).all(axis=1)]
            self._persons = len(people)
        self._futures = np.ascontiguousarray(known.future[near])
        extra = np.maximum(radius - self.cfg.person_radius_m, 0.0)
        return np.vstack([people, np.column_stack([now[:, :5], extra])])

    def _goal_taken(self, ctl: LocalController, people: F64) -> bool:
        """Whether someone stands where the rover would stand at its goal."""
        goal = ctl.goal
        if goal is None or len(people) == 0:
            return False
        need = self.reach_m + self.cfg.person_radius_m + self.cfg.passing_distance_m
        return bool((np.hypot(people[:, 0] - goal.x, people[:, 1] - goal.y)
                     < need + people[:, 5]).any())

    # -- candidates --------------------------------------------------------------------------
    def _candidates(self, target: float, kappa: float, kmax: float, near: bool,
                    approaching: bool) -> F64:
        """``(M, 4)`` target speed (m/s), first curvature (1/m), when it ends (s) and the
        curvature after it; row 0 the chosen arc, row 3 stopping on it."""
        vmax = self.ccfg.max_speed_mps
        if near:
            vmax = min(vmax, self.cfg.near_speed_mps)
        v_nom = min(max(target, 0.0), vmax)
        never = math.inf
        turns = self._turning_rows(kmax, vmax)
        cands = np.empty((4 + len(turns) + (1 if approaching else 0), 4))
        cands[:4] = ((v_nom, kappa, never, kappa), (0.6 * v_nom, kappa, never, kappa),
                     (0.3 * v_nom, kappa, never, kappa), (0.0, kappa, never, kappa))
        cands[4:4 + len(turns)] = turns
        if approaching:
            cands[-1] = (-BACK_OFF_MPS, 0.0, never, 0.0)
        return cands

    def _turning_rows(self, kmax: float, vmax: float) -> F64:
        """The candidates that do not depend on the chosen arc: the nine curvatures and the
        side-steps (rows 4 on of :meth:`_candidates`). Kept per ``(kmax, vmax)``: the robot
        model is fixed, as the footprint is."""
        key = (kmax, vmax)
        rows = self._turns.get(key)
        if rows is not None:
            return rows
        never = math.inf
        out: list[tuple[float, float, float, float]] = []
        for k in np.linspace(-kmax, kmax, 9):
            v = min(vmax, self.robot.max_speed_on_arc_mps(float(k)))
            out += [(v, float(k), never, float(k)), (0.5 * v, float(k), never, float(k))]
        for k in (-kmax, -0.5 * kmax, 0.5 * kmax, kmax):
            v = min(vmax, self.robot.max_speed_on_arc_mps(float(k)))
            for t_bend in (1.0, 2.0):
                out += [(v, float(k), t_bend, 0.0), (0.5 * v, float(k), 2.0 * t_bend, 0.0)]
        rows = np.array(out, dtype=np.float64)
        rows.setflags(write=False)
        if len(self._turns) >= 8:  # kmax and the speed limit take a few values
            self._turns.clear()
        self._turns[key] = rows
        return rows

    @staticmethod
    def _narrow(ctl: LocalController, pose: Pose2D) -> bool:
        """Whether the rover stands in a narrow passage (a wall nearer than its corners)."""
        cm = ctl.costmap
        if cm is None:
            return False
        limit = cost_at_distance(cm.circumscribed_radius_m - cm.inscribed_radius_m,
                                 cm.cost_scaling_factor)
        cost = cm.cost_at(pose.x, pose.y)
        return bool(limit <= cost < NO_INFORMATION)

    def _costmap_ok(self, ctl: LocalController, poses: F64) -> npt.NDArray[np.bool_]:
        if ctl.costmap is None:
            return np.ones(len(poses), dtype=bool)
        k = max(2, math.ceil(self.ccfg.collision_horizon_s / STEP_S) + 1)
        costs = ctl.trajectory_costs(poses[:, :k])
        start_hit = costs[:, 0] >= LETHAL
        return ~((costs[:, 1:] >= LETHAL).any(axis=1) & ~start_hit)

    # -- the review --------------------------------------------------------------------------
    def first_too_near(self, poses: F64, step_s: float, now_s: float) -> npt.NDArray[np.int64]:
        """For each arc of ``poses`` ``(M, K, 3)`` (``map``; pose ``k`` is ``k · step_s`` from
        now), the index of its first pose that comes nearer than ``min_distance_m`` to a
        person predicted to that time *and* nearer than standing still at the first pose
        would (the hard rule: never drive at a person); ``K`` where there is none. The
        controller's own manoeuvres (making room to turn) drive only what this allows."""
        m_n, k_n = poses.shape[0], poses.shape[1]
        people = self.people_near(Pose2D(*(float(v) for v in poses[0, 0])), now_s)
        first = np.full(m_n, k_n, dtype=np.int64)
        if len(people) == 0 or m_n == 0:
            return first
        times = np.arange(k_n, dtype=np.float64) * step_s
        dist = np.empty((m_n, k_n, len(people)))
        people_clearances(_dense(poses), times, _dense(people[:, :4]), self.footprint,
                          self.cfg.person_radius_m, dist)
        still = np.empty((1, k_n, len(people)))
        people_clearances(_dense(np.repeat(poses[:1, :1], k_n, axis=1)), times,
                          _dense(people[:, :4]), self.footprint, self.cfg.person_radius_m,
                          still)
        dist -= people[None, None, :, 5]
        still -= people[None, None, :, 5]
        near = np.any((dist < self.cfg.min_distance_m) & (dist < still - 0.02), axis=2)
        hit = near.any(axis=1)
        first[hit] = near[hit].argmax(axis=1)
        return first

    def wait_for_people(self, now_s: float, detail: str) -> Review:
        """The review for a rover that waits because a manoeuvre of its own would drive at
        someone: yielding (the progress checks pause, "Excuse me" when it is time) for up to
        ``yield_max_s``."""
        if self._note_yield(now_s) < self.cfg.yield_max_s:
            return Review(0.0, 0.0, ControlStatus.YIELDING, detail, hold_progress=True)
        return Review(0.0, 0.0, ControlStatus.AVOIDING, f"still {detail}")

    def steering(self, now_s: float) -> bool:
        """Whether the stage changed the motion in the last 1.5 s (it is steering round
        someone: the controller should not turn in place back to its path meanwhile)."""
        return now_s - self._changed_at_s < STEERING_S

    def review_turn(self, pose: Pose2D, now_s: float, turn_rad: float) -> Review | None:
        """None when turning in place by ``turn_rad`` (rad, counter-clockwise positive) would
        not bring the footprint nearer than ``min_distance_m`` to anyone (predicted to each
        moment of the turn) than it was where the turn began (the hard rule, as for any
        arc); else wait for them. Only the turn the rover makes counts, not the whole circle
        its corners could sweep: someone beside it need not step back for a turn that swings
        the corners away from them. A turn under way is judged from where it began, so one
        that was clear to start does not stop half-way for a standing person."""
        target = pose.yaw + turn_rad
        turn = self._turn
        if turn is None or now_s - turn[2] > TURN_GAP_S or \
                abs(wrap_angle(turn[1] - target)) > TURN_SAME_RAD:
            turn = (pose.yaw, target, now_s)
        self._turn = (turn[0], turn[1], now_s)
        steps = max(2, math.ceil(abs(turn_rad) / TURN_STEP_RAD) + 1)
        poses = np.empty((1, steps + 1, 3))
        poses[0, :, 0], poses[0, :, 1] = pose.x, pose.y
        poses[0, 0, 2] = turn[0]  # the reference: where the turn began
        poses[0, 1:, 2] = pose.yaw + np.linspace(0.0, turn_rad, steps)
        # Turning from a standstill averages about half the top rate.
        step_s = abs(turn_rad) / (steps - 1) / (0.5 * self.ccfg.max_angular_radps)
        if self.first_too_near(poses, step_s, now_s)[0] > steps:
            return None
        self._turn = None  # waiting: the next turn starts afresh from where it stands
        if self._note_yield(now_s) < self.cfg.yield_max_s:
            return Review(0.0, 0.0, ControlStatus.YIELDING,
                          "waiting for people to step back before turning",
                          hold_progress=True)
        return Review(0.0, 0.0, ControlStatus.AVOIDING,
                      "still waiting for people to step back before turning")

    def review(self, controller: LocalController, pose: Pose2D, now_s: float,
               linear_mps: float, target_mps: float, kappa: float, aim: tuple[float, float],
               kmax: float, dist_goal_m: float) -> Review | None:
        """The stage (see the module docstring); None: no person matters, keep the arc."""
        people = self.people_near(pose, now_s)
        if len(people) == 0:
            self._yield_since = None
            return None
        if now_s < self._assertive_until_s:
            # "Excuse me" did not move them: a track that never walked (a pillar, a box, a
            # statue the size of a person) is an obstacle like any other from now on.
            keep = people[:, 4] > 0.5
            keep[self._persons:] = True  # the movers (other rovers) after the people stay
            self._persons = int(keep[:self._persons].sum())
            people = people[keep]
            if len(people) == 0:
                return None
        self.reviews += 1
        if self.stop_short and dist_goal_m <= self.cfg.stop_short_m and self._goal_taken(
                controller, people):
            return Review(0.0, kappa, ControlStatus.FOLLOWING,
                          "people stand at the stop: keeping my distance", arrived=True)
        best, cands, near = self._choose(controller, pose, now_s, people, target_mps, kappa,
                                         kmax, aim)
        if best == 0 and not near:
            self._yield_since = None
            return None
        self.changed += 1
        self._changed_at_s = now_s
        return self._command(controller, now_s, cands[best], target_mps)

    def _choose(self, ctl: LocalController, pose: Pose2D, now_s: float, people: F64,
                target: float, kappa: float, kmax: float,
                aim: tuple[float, float]) -> tuple[int, F64, bool]:
        """The best candidate's row, the candidates, and whether a person is near."""
        near, approaching = self._situation(pose, people)
        cands = self._candidates(target, kappa, kmax, near, approaching)
        scores = _Scores(self, ctl, pose, now_s, people, cands, kappa, kmax, aim)
        if not near:  # first the chosen arc (and stopping) alone: most of the time it is fine
            cost, comfort = scores.upto(4)
            if comfort[0] <= COMFORT_SLACK and math.isfinite(cost[0]):
                return 0, cands, near  # nobody minds the chosen arc: keep it
        cost, comfort = scores.upto(len(cands))  # (the first four are not scored again)
        poses = scores.poses
        if comfort[0] <= COMFORT_SLACK and math.isfinite(cost[0]) and \
                self._costmap_ok(ctl, poses[:1])[0]:
            return 0, cands, near
        # The cheapest candidates first; the costmap is asked only until one fits (each
        # candidate's answer is its own): the cheapest alone, as it nearly always fits, then
        # four at a time. Stopping needs no answer.
        ranked = np.argsort(cost, kind="stable")
        order: list[int] = ranked[np.isfinite(cost[ranked])].tolist()
        k = 0
        while k < len(order):
            batch = order[k:k + (4 if k else 1)]
            k += len(batch)
            if batch[0] == 3:
                return 3, cands, near
            fits = self._costmap_ok(ctl, poses[batch])
            for i, ok in zip(batch, fits.tolist(), strict=True):
                if ok or i == 3:
                    return i, cands, near
        return 3, cands, near

    def _situation(self, pose: Pose2D, people: F64) -> tuple[bool, bool]:
        """Whether someone ahead is near (slow down: unless they walk away from the rover
        anyway) and someone walks straight at the rover (offer backing off)."""
        now_d = np.empty((1, 1, len(people)))
        people_clearances(np.array([[[pose.x, pose.y, pose.yaw]]]), self.times[:1],
                          _dense(people[:, :4]), self.footprint, self.cfg.person_radius_m,
                          now_d)
        near, approaching = situation(
            now_d, np.array([pose.x, pose.y, math.cos(pose.yaw), math.sin(pose.yaw)]),
            _dense(people), self.cfg.near_distance_m, WALKING_MPS)
        return bool(near), bool(approaching)

    def _note_yield(self, now_s: float) -> float:
        """The rover waits for people: start the clock, say "Excuse me" when it is time;
        return how long it has waited (s)."""
        if self._yield_since is None:
            self._yield_since = now_s
        waited = now_s - self._yield_since
        cfg = self.cfg
        if waited >= cfg.excuse_me_after_s and now_s - self._last_excuse_s >= \
                cfg.excuse_me_interval_s:
            self._last_excuse_s = now_s
            self._assertive_until_s = now_s + cfg.assertive_s
            if self._persons:  # nobody to say it to when only another rover waits
                self.excuse_me_count += 1
                for listener in list(self.on_excuse_me):
                    listener(cfg.excuse_me_text)
        return waited

    def _command(self, ctl: LocalController, now_s: float, cand: F64,
                 target: float) -> Review:
        """The review for the chosen candidate; the yield timer and "Excuse me"."""
        v_c, k_c = float(cand[0]), float(cand[1])  # the first step of the candidate
        up = self.ccfg.max_accel_mps2 * ctl.dt_s
        v = approach(ctl.commanded_mps, v_c, up if v_c >= ctl.commanded_mps else 2.0 * up)
        if v_c > 0.02 or target <= 0.02:
            self._yield_since = None
            return Review(v, k_c, ControlStatus.AVOIDING, "giving way to people")
        waited = self._note_yield(now_s)
        if waited < self.cfg.yield_max_s:
            return Review(v, k_c, ControlStatus.YIELDING, "waiting for people to pass",
                          hold_progress=True)
        return Review(v, k_c, ControlStatus.AVOIDING, "still waiting for people to pass")


class _Scores:
    """One review's scores of its candidates (:func:`score_candidates`), scored in order and
    each once: first the chosen arc and stopping (rows 0 to 3), the rest when those do not do.

    Each candidate's cost (inf: it drives at someone) and comfort cost come from the people
    predicted every 0.2 s (every other step of :attr:`PeopleStage.times`): the comfortable
    distance of each person (``passing_distance_m`` growing to ``head_on_distance_m`` in front
    of a walker, ``min_distance_m`` for a track that never walked; ``min_distance_m + 0.05`` at
    most in a narrow passage or after "Excuse me"; plus the prediction's growth for a walking
    person), each person's worst time-weighted squared shortfall, what that adds to the worst
    that stopping leaves plus a fifth of it, coming nearer than ``min_distance_m``, progress
    towards the aim and bending away from the chosen curvature (see the module docstring).
    """

    def __init__(self, stage: PeopleStage, ctl: LocalController, pose: Pose2D, now_s: float,
                 people: F64, cands: F64, kappa: float, kmax: float,
                 aim: tuple[float, float]) -> None:
        cfg = stage.cfg
        self.stage = stage
        self.cands = cands
        self.people = _dense(people)
        m_n, j_n = len(cands), len(people)
        self.poses: F64 = np.empty((m_n, len(stage.times), 3))  # the rollouts (map)
        self.work: F64 = np.empty((4, m_n, j_n))
        self.rows: F64 = np.empty((4, m_n))
        n = len(stage._futures)  # the movers (the last rows of people): known futures
        self.futures: F64 = _dense(stage._futures[:, ::2])
        self.radii: F64 = _dense(self.people[j_n - n:, 5] + cfg.person_radius_m)
        self.known: F64 = np.empty((m_n, self.futures.shape[1], n))  # their distances (m)
        self.done = 0  # rows scored
        ax, ay = aim[0] - pose.x, aim[1] - pose.y
        norm = math.hypot(ax, ay) or 1.0
        span = max(stage.ccfg.max_speed_mps * stage.times[-1], 1e-6)
        self.params = score_params(
            pose=(pose.x, pose.y, pose.yaw), v_now=ctl.commanded_mps,
            accel=stage.ccfg.max_accel_mps2, radius=cfg.person_radius_m,
            min_distance=cfg.min_distance_m, passing=cfg.passing_distance_m,
            head_gain=cfg.head_on_distance_m - cfg.passing_distance_m,
            growth=cfg.prediction_growth_mps, growth_cap=GROWTH_CAP_S,
            floor=cfg.min_distance_m + 0.05,  # what the comfortable distances shrink to
            narrow=stage._narrow(ctl, pose), assertive=now_s < stage._assertive_until_s,
            walking=WALKING_MPS, aim=(ax, ay), progress_scale=norm * span,
            bend_scale=2.0 * max(kmax, 1e-6), kappa=kappa)

    def upto(self, hi: int) -> tuple[F64, F64]:
        """The cost and the comfort cost of candidates ``0`` to ``hi`` (scoring those not
        scored yet); the numbers go to :attr:`PeopleStage.last_costs`."""
        stage = self.stage
        lo = self.done
        if hi > lo:
            rollout_candidates(lo, hi, self.cands, stage.times, self.params, self.poses)
            if len(self.futures):  # the movers: along their known future, with their own radius
                path_clearances(_dense(self.poses[lo:hi, ::2]), self.futures, stage.footprint,
                                self.radii, self.known[lo:hi])
            score_candidates(lo, hi, self.cands, stage.times, stage.weights, self.people,
                             self.known, stage.footprint, self.params, stage._persons,
                             self.poses, self.work, self.rows)
            self.done = hi
        # Each candidate's comfort and safety sums over the people: numpy's (pairwise) sums.
        sums = self.work[2:, :hi].sum(axis=2)
        cost = np.empty(hi)
        combine_costs(sums, self.rows, _COST_WEIGHTS, cost)
        comfort = sums[0]
        # rows 0 and 3: progress and the closest approach to anyone
        stage.last_costs = (self.cands[:hi], cost, comfort, self.rows[0, :hi], self.rows[3, :hi])
        return cost, comfort
