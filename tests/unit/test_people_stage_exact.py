"""The people stage's compiled scoring gives the very numbers of the numpy code it replaced.

``reference_choose`` below is that code (the rollout, the comfortable distances, the scores
and the choice, as they were in ``curio/people/stage.py``), with the footprint distance
written out in numpy as the original kernel computed it (a square root per edge). The
simulator is deterministic and its reports are compared byte for byte, so "close" is not
enough: every candidate's cost, comfort, progress and closest approach must be the same
float, bit for bit, over random scenes (people standing, walking at and past the rover, one
on top of it, other rovers with known futures, a narrow passage, "Excuse me").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from curio.core.config import Config
from curio.core.geometry import Pose2D
from curio.nav.costs import LETHAL
from curio.people.stage import PeopleStage
from curio.people.stage_kernel import people_clearances
from curio.robot import RobotModel

F64 = npt.NDArray[np.float64]

WALKING_MPS = 0.3
W_PROGRESS, W_COMFORT, W_BEND, W_SAFE = 1.0, 30.0, 0.3, 300.0
BACK_OFF_MPS = 0.1
COMFORT_SLACK = 1e-3
GROWTH_CAP_S = 2.0


def reference_clearances(poses: F64, times: F64, people: F64, footprint: F64,
                         radii: F64, futures: F64 | None = None) -> F64:
    """``(M, K, J)`` footprint-to-body distances (m) as the original kernel computed them:
    the person's centre in ``base_link``, a square root per edge, the smallest, the sign of
    the crossing count."""
    c = np.vectorize(math.cos)(poses[:, :, 2])[:, :, None]  # libm, as the kernel's
    s = np.vectorize(math.sin)(poses[:, :, 2])[:, :, None]
    if futures is None:
        cx = people[None, None, :, 0] + people[None, None, :, 2] * times[None, :, None]
        cy = people[None, None, :, 1] + people[None, None, :, 3] * times[None, :, None]
    else:
        cx, cy = futures[:, :, 0].T[None], futures[:, :, 1].T[None]  # (1, K, J)
    dx, dy = cx - poses[:, :, 0:1], cy - poses[:, :, 1:2]
    px, py = c * dx + s * dy, -s * dx + c * dy
    best = np.full(px.shape, np.inf)
    inside = np.zeros(px.shape, dtype=bool)
    n = len(footprint)
    for i in range(n):
        ax, ay = footprint[i]
        bx, by = footprint[(i + 1) % n]
        ex, ey = bx - ax, by - ay
        ll = ex * ex + ey * ey
        u = (np.zeros(px.shape) if ll == 0.0
             else np.clip(((px - ax) * ex + (py - ay) * ey) / ll, 0.0, 1.0))
        ddx, ddy = px - ax - u * ex, py - ay - u * ey
        best = np.minimum(best, np.sqrt(ddx * ddx + ddy * ddy))
        cross = (ay > py) != (by > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = ax + (py - ay) * ex / ey
        inside ^= cross & (px < xc)
    return np.where(inside, -best, best) - radii[None, None, :]


def reference_candidates(stage: PeopleStage, target: float, kappa: float, kmax: float,
                         near: bool, approaching: bool) -> F64:
    vmax = stage.ccfg.max_speed_mps
    if near:
        vmax = min(vmax, stage.cfg.near_speed_mps)
    v_nom = min(max(target, 0.0), vmax)
    never = math.inf
    curves = [float(k) for k in np.linspace(-kmax, kmax, 9)]
    bends = [-kmax, -0.5 * kmax, 0.5 * kmax, kmax]
    top = {k: min(vmax, stage.robot.max_speed_on_arc_mps(k)) for k in curves + bends}
    rows = [(v_nom, kappa, never, kappa), (0.6 * v_nom, kappa, never, kappa),
            (0.3 * v_nom, kappa, never, kappa), (0.0, kappa, never, kappa)]
    rows += [(v, k, never, k) for k in curves for v in (top[k], 0.5 * top[k])]
    rows += [(v, k, t, 0.0) for k in bends for t_bend in (1.0, 2.0)
             for v, t in ((top[k], t_bend), (0.5 * top[k], 2.0 * t_bend))]
    rows += [(-BACK_OFF_MPS, 0.0, never, 0.0)] if approaching else []
    return np.array(rows, dtype=np.float64)


def reference_rollout(stage: PeopleStage, pose: Pose2D, v_now: float, cands: F64) -> F64:
    t = stage.times[None, :]
    vc = cands[:, 0:1]
    up = stage.ccfg.max_accel_mps2
    acc = np.where(vc >= v_now, up, -2.0 * up)
    t_ramp = np.abs(vc - v_now) / np.abs(acc)
    tr = np.minimum(t, t_ramp)
    s = v_now * tr + 0.5 * acc * tr * tr + vc * np.maximum(t - t_ramp, 0.0)
    kap = np.where(t < cands[:, 2:3], cands[:, 1:2], cands[:, 3:4])
    ds = np.diff(s, axis=1)
    th = pose.yaw + np.concatenate([np.zeros((len(cands), 1)),
                                    np.cumsum(kap[:, :-1] * ds, axis=1)], axis=1)
    mid = th[:, :-1] + 0.5 * kap[:, :-1] * ds
    x = pose.x + np.concatenate([np.zeros((len(cands), 1)),
                                 np.cumsum(ds * np.cos(mid), axis=1)], axis=1)
    y = pose.y + np.concatenate([np.zeros((len(cands), 1)),
                                 np.cumsum(ds * np.sin(mid), axis=1)], axis=1)
    return np.stack([x, y, th], axis=-1)


def reference_required(stage: PeopleStage, poses: F64, times: F64, people: F64) -> F64:
    cfg = stage.cfg
    px = people[None, None, :, 0] + people[None, None, :, 2] * times[None, :, None]
    py = people[None, None, :, 1] + people[None, None, :, 3] * times[None, :, None]
    rx = poses[:, :, 0:1] - px
    ry = poses[:, :, 1:2] - py
    sp = np.hypot(people[:, 2], people[:, 3])
    with np.errstate(invalid="ignore", divide="ignore"):
        front = (people[None, None, :, 2] * rx + people[None, None, :, 3] * ry) / (
            np.hypot(rx, ry) * np.maximum(sp, 1e-9)[None, None, :])
    front = np.where(sp[None, None, :] > WALKING_MPS, np.clip(np.nan_to_num(front), 0.0,
                                                              1.0), 0.0)
    req = cfg.passing_distance_m + (cfg.head_on_distance_m - cfg.passing_distance_m) * front
    return np.where(people[None, None, :, 4] > 0.5, req, cfg.min_distance_m)


def reference_score(stage: PeopleStage, pose: Pose2D, now_s: float, people: F64, cands: F64,
                    poses: F64, kappa: float, kmax: float, aim: tuple[float, float],
                    narrow: bool) -> tuple[tuple[F64, ...], F64, F64]:
    cfg = stage.cfg
    steps = np.ascontiguousarray(poses[:, ::2])
    times = np.ascontiguousarray(stage.times[::2])
    radii = np.full(len(people), cfg.person_radius_m)
    dist = reference_clearances(steps, times, people[:, :4], stage.footprint, radii)
    n = len(stage._futures)
    if n:
        dist[:, :, -n:] = reference_clearances(steps, times, people[-n:], stage.footprint,
                                               people[-n:, 5] + cfg.person_radius_m,
                                               stage._futures[:, ::2])
    req = reference_required(stage, steps, times, people)
    floor_m = cfg.min_distance_m + 0.05
    if narrow:
        req = np.minimum(req, floor_m)
    walking = (np.hypot(people[:, 2], people[:, 3]) > WALKING_MPS) & (people[:, 4] > 0.5)
    walking[stage._persons:] = False
    req = req + cfg.prediction_growth_mps * np.minimum(times, GROWTH_CAP_S)[None, :, None] \
        * walking[None, None, :]
    if now_s < stage._assertive_until_s:
        req = np.minimum(req, floor_m)
    worst = (np.clip(req - dist, 0.0, None) ** 2
             * stage.weights[::2][None, :, None]).max(axis=1)
    comfort = (np.clip(worst - worst[3:4], 0.0, None) + 0.2 * worst).sum(axis=1)
    closest = dist.min(axis=1)
    bad = ((closest < cfg.min_distance_m) & (closest < closest[3:4] - 0.02)).any(axis=1)
    bad[3] = False
    ax, ay = aim[0] - pose.x, aim[1] - pose.y
    norm = math.hypot(ax, ay) or 1.0
    span = max(stage.ccfg.max_speed_mps * stage.times[-1], 1e-6)
    progress = ((poses[:, -1, 0] - pose.x) * ax + (poses[:, -1, 1] - pose.y) * ay) / (
        norm * span)
    bend = np.abs(cands[:, 1] - kappa) / (2.0 * max(kmax, 1e-6))
    unsafe = (np.clip(cfg.min_distance_m - closest, 0.0, None) ** 2).sum(axis=1)
    cost = (W_SAFE * unsafe + W_COMFORT * comfort - W_PROGRESS * progress
            + W_BEND * bend)
    cost[bad] = np.inf
    return (cands, cost, comfort, progress, closest.min(axis=1)), cost, comfort


def reference_situation(stage: PeopleStage, pose: Pose2D, people: F64) -> tuple[bool, bool]:
    now_d = reference_clearances(np.array([[[pose.x, pose.y, pose.yaw]]]), stage.times[:1],
                                 people[:, :4], stage.footprint,
                                 np.full(len(people), stage.cfg.person_radius_m))
    now_d -= people[None, None, :, 5]
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    ahead = (people[:, 0] - pose.x) * c + (people[:, 1] - pose.y) * s
    towards = people[:, 2] * c + people[:, 3] * s
    near = bool(((now_d[0, 0] < stage.cfg.near_distance_m) & (ahead > 0.0)
                 & (towards < WALKING_MPS)).any())
    approaching = bool(((ahead > 0) & (towards < -WALKING_MPS)
                        & (now_d[0, 0] < 1.5)).any())
    return near, approaching


class FakeController:
    """What the stage asks of the controller: the speed, and a costmap that finds some poses
    lethal (a pattern of the poses, so the choice goes down the cheapest candidates)."""

    def __init__(self, v: float, every: int) -> None:
        self.commanded_mps = v
        self.costmap = object()
        self.every = every
        self.asked = 0  # candidate arcs asked about

    def trajectory_costs(self, trajs: F64) -> npt.NDArray[np.uint8]:
        self.asked += len(trajs)
        h = np.floor(trajs[..., 0] * 37.0 + trajs[..., 1] * 53.0)
        return np.where(h % self.every == 0, LETHAL, 0).astype(np.uint8)


def reference_choose(stage: PeopleStage, ctl: FakeController, pose: Pose2D, now_s: float,
                     people: F64, target: float, kappa: float, kmax: float,
                     aim: tuple[float, float], narrow: bool) -> tuple[int, F64, bool, Any]:
    """The choice as the numpy code made it (the costmap asked four arcs at a time)."""
    near, approaching = reference_situation(stage, pose, people)
    cands = reference_candidates(stage, target, kappa, kmax, near, approaching)
    k = max(2, math.ceil(stage.ccfg.collision_horizon_s / 0.1) + 1)

    def costmap_ok(p: F64) -> npt.NDArray[np.bool_]:
        costs = ctl.trajectory_costs(p[:, :k])
        return ~((costs[:, 1:] >= LETHAL).any(axis=1) & ~(costs[:, 0] >= LETHAL))

    if not near:
        few = cands[:4]
        poses = reference_rollout(stage, pose, ctl.commanded_mps, few)
        last, cost, comfort = reference_score(stage, pose, now_s, people, few, poses, kappa,
                                              kmax, aim, narrow)
        if comfort[0] <= COMFORT_SLACK and math.isfinite(cost[0]):
            return 0, cands, near, last
    poses = reference_rollout(stage, pose, ctl.commanded_mps, cands)
    last, cost, comfort = reference_score(stage, pose, now_s, people, cands, poses, kappa,
                                          kmax, aim, narrow)
    if comfort[0] <= COMFORT_SLACK and math.isfinite(cost[0]) and costmap_ok(poses[:1])[0]:
        return 0, cands, near, last
    order = [int(i) for i in np.argsort(cost, kind="stable") if math.isfinite(cost[i])]
    for b in range(0, len(order), 4):
        batch = order[b:b + 4]
        for i, ok in zip(batch, costmap_ok(poses[batch]).tolist(), strict=True):
            if ok or i == 3:
                return i, cands, near, last
    return 3, cands, near, last


def random_scene(rng: np.random.Generator, k_n: int, cfg: Config,
                 front_m: float) -> dict[str, Any]:
    """A rover among 1 to 20 people (and sometimes other rovers), all near enough to matter;
    ``front_m``: how far the footprint reaches ahead of ``base_link``."""
    kmax = float(rng.choice([2.2222222222222223, 1.0, 1.7]))
    j = int(rng.integers(1, 21))
    n = int(rng.integers(1, 4)) if rng.random() < 0.25 else 0
    pose = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)), float(rng.uniform(-4, 4)))
    people = np.zeros((j + n, 6))
    spread = float(rng.choice([1.5, 4.0]))
    people[:, 0] = pose[0] + rng.uniform(-spread, spread, j + n)
    people[:, 1] = pose[1] + rng.uniform(-spread, spread, j + n)
    people[:, 2:4] = rng.uniform(-1.5, 1.5, (j + n, 2)) * (rng.random((j + n, 1)) < 0.7)
    people[:, 4] = (rng.random(j + n) < 0.8).astype(float)
    if rng.random() < 0.2:  # someone exactly where the rover is
        people[0, 0:2] = pose[0], pose[1]
    if rng.random() < 0.3:  # someone walking straight at it
        c, s = math.cos(pose[2]), math.sin(pose[2])
        people[0, 0:4] = pose[0] + 1.2 * c, pose[1] + 1.2 * s, -0.8 * c, -0.8 * s
        people[0, 4] = 1.0
    if j > 1 and rng.random() < 0.3:  # someone standing a hair inside the passing distance
        c, s = math.cos(pose[2]), math.sin(pose[2])
        ahead = front_m + cfg.people.person_radius_m + cfg.people.passing_distance_m - 1e-4
        people[1, 0:5] = pose[0] + ahead * c, pose[1] + ahead * s, 0.0, 0.0, 1.0
    futures = np.zeros((n, k_n, 2))
    if n:
        people[j:, 5] = rng.uniform(0.0, 0.5, n)
        steps = rng.uniform(-0.05, 0.05, (n, k_n, 2))
        futures = np.ascontiguousarray(people[j:, None, 0:2] + np.cumsum(steps, axis=1))
    target = float(rng.choice([0.3, 0.37, 0.2, 0.0, -0.1, rng.uniform(-0.1, 0.5)]))
    return {
        "pose": Pose2D(*pose), "people": people, "futures": futures, "persons": j,
        "target": target, "v_now": float(rng.choice([target, 0.0, rng.uniform(-0.1, 0.4)])),
        "kappa": float(rng.choice([0.0, rng.uniform(-kmax, kmax)])), "kmax": kmax,
        "aim": (pose[0] + float(rng.uniform(-3, 3)), pose[1] + float(rng.uniform(-3, 3))),
        "assertive": bool(rng.random() < 0.2), "narrow": bool(rng.random() < 0.2),
        "every": int(rng.choice([2, 3, 5, 1000])),
    }


def _same(a: F64, b: F64) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("seed", range(4))
def test_the_choice_and_its_numbers_are_those_of_the_numpy_code(
        cfg: Config, monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    robot = RobotModel.from_config(cfg.robot)
    rng = np.random.default_rng(seed)
    now_s = 100.0
    asked = [0, 0]
    for _ in range(60):
        stage = PeopleStage(cfg.people, cfg.nav.controller, robot, lambda: None)
        scene = random_scene(rng, len(stage.times), cfg, float(stage.footprint[:, 0].max()))
        stage._futures, stage._persons = scene["futures"], scene["persons"]
        stage._assertive_until_s = now_s + 1.0 if scene["assertive"] else -math.inf
        narrow = bool(scene["narrow"])
        monkeypatch.setattr(PeopleStage, "_narrow",
                            staticmethod(lambda ctl, pose, narrow=narrow: narrow))
        args = (scene["pose"], now_s, scene["people"], scene["target"], scene["kappa"],
                scene["kmax"], scene["aim"])
        ref_ctl, ctl = (FakeController(scene["v_now"], scene["every"]) for _ in range(2))
        best_ref, cands_ref, near_ref, last_ref = reference_choose(stage, ref_ctl, *args,
                                                                   narrow=narrow)
        best, cands, near = stage._choose(ctl, *args)  # type: ignore[arg-type]
        assert (best, near) == (best_ref, near_ref)
        assert _same(cands, cands_ref)
        assert len(stage.last_costs) == len(last_ref)
        for got, want in zip(stage.last_costs, last_ref, strict=True):
            assert _same(got, want), (got, want)
        asked[0] += ctl.asked
        asked[1] += ref_ctl.asked
    assert asked[0] <= asked[1]  # the costmap is asked about fewer arcs, never more


def test_people_clearances_are_those_of_the_per_edge_distance(cfg: Config) -> None:
    """The kernel takes one square root per point (of the smallest square) and divides only
    where the clamp does not decide: the same distances as a root and a quotient per edge."""
    robot = RobotModel.from_config(cfg.robot)
    rng = np.random.default_rng(7)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    for footprint in (np.asarray(robot.footprint_points, dtype=np.float64), square - 0.5,
                      np.array([[0.4, 0.0], [-0.3, 0.3], [-0.1, 0.0], [-0.3, -0.3]])):
        poses = np.ascontiguousarray(rng.uniform(-2.0, 2.0, (7, 9, 3)))
        times = np.linspace(0.0, 4.0, 9)
        people = np.ascontiguousarray(rng.uniform(-2.0, 2.0, (11, 4)))
        people[0, :2] = poses[0, 0, :2]  # on the rover's centre
        people[1, :2] = poses[0, 0, :2] + footprint[0]  # on a corner
        out = np.empty((7, 9, 11))
        people_clearances(poses, times, people, footprint, 0.25, out)
        want = reference_clearances(poses, times, people, footprint, np.full(11, 0.25))
        assert _same(out, want)


@pytest.mark.parametrize("count", [1, 2, 3])
def test_every_kernel_gets_dense_arrays(cfg: Config, monkeypatch: pytest.MonkeyPatch,
                                        count: int) -> None:
    """numba compiles a kernel once per array layout (``curio warmup`` compiles the dense one):
    whatever the number of people and movers, the stage hands every kernel C-contiguous
    arrays (one person makes ``people[:, :4]`` contiguous, two do not)."""
    import curio.people.stage as stage_module
    from curio.kernels import dispatchers

    kernels = {name.rsplit(".", 1)[1] for name in dispatchers()
               if name.startswith("curio.people.stage_kernel.")}
    seen: dict[str, list[bool]] = {}

    def recording(name: str, kernel: Any) -> Any:
        def call(*args: Any) -> Any:
            seen.setdefault(name, []).extend(
                a.flags.c_contiguous for a in args if isinstance(a, np.ndarray))
            return kernel(*args)
        return call

    for name in kernels & set(vars(stage_module)):
        monkeypatch.setattr(stage_module, name, recording(name, getattr(stage_module, name)))
    monkeypatch.setattr(PeopleStage, "_narrow", staticmethod(lambda ctl, pose: False))
    robot = RobotModel.from_config(cfg.robot)
    rng = np.random.default_rng(count)
    for movers in (0, 1, 2):
        stage = PeopleStage(cfg.people, cfg.nav.controller, robot, lambda: None)
        people = np.zeros((count + movers, 6))
        people[:, 0] = np.linspace(0.8, 2.0, count + movers)
        people[:, 1:4] = rng.uniform(-0.5, 0.5, (count + movers, 3))
        people[:, 4] = 1.0
        stage._persons = count
        stage._futures = np.ascontiguousarray(
            np.repeat(people[count:, None, :2], len(stage.times), axis=1))
        for target in (0.3, 0.0):
            stage._choose(FakeController(0.2, 3), Pose2D(0.0, 0.0, 0.0), 0.0,  # type: ignore
                          people, target, 0.0, 2.0, (3.0, 0.0))
    assert {"people_clearances", "situation", "rollout_candidates", "score_candidates",
            "combine_costs", "path_clearances"} <= set(seen)
    assert all(all(dense) for dense in seen.values()), {n: d for n, d in seen.items()
                                                        if not all(d)}

