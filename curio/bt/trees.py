"""Tree factories: the follow-path tree, the simple two-step tree and the tour guide.

Each factory returns the root of a py_trees 2.x tree; the structure mirrors the original's
(original-system.md §2.1, §2.3) with its fixes:

* The root is a Parallel (SuccessOnAll, not synchronised) whose children are the independent
  data feeds and the priority Selector: a feed never blocks another or the decisions (§9.2).
* The priority Selector has no memory: every tick re-checks the branches from the top, so a
  higher priority pre-empts a running lower one (``terminate(INVALID)`` percolates down).
* Guarded branches are Sequences. "Check Path" keeps memory, so a running help request is not
  dropped by a flickering BLOCKED flag (py_trees 0.6 semantics, §1.0); one-shot branches (Go
  Home, Change Path) have no memory.

Follow-path priorities: E-stop > Pause > battery critical > lost > battery low > (dock) > Go
Home > (undock) > operator route command > blocked (ask for help) > follow path > (docked) >
idle; every tree has the battery and the lost-and-found branches (``curio/bt/unattended.py``)
and, with a dock, Go Home docks. The tour tree adds tour commands; the two-step tree patrols
between two goals under the same upper branches.
"""

from __future__ import annotations

import math
import operator

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import ParallelPolicy

from curio.core.geometry import Pose2D

from .actions import (
    Ask4Help,
    BatteryHome,
    ChangePath,
    ClearKey,
    DriveHome,
    FollowPath,
    HoldEStop,
    Idle,
    MoveClient,
    Pause,
)
from .context import TreeContext
from .feeds import Battery2BB, Blocked2BB, EStop2BB, Follower2BB, Operator2BB
from .follower import TOUR_ROUTE_ID, Route, Stop
from .guards import IsBlocked, check_key
from .unattended import docked_branch, unattended_branches, unattended_feeds, undock_branch

__all__ = ["build_root", "tour_route_from_config"]


def tour_route_from_config(ctx_cfg: object) -> Route | None:
    """The tour (``bt.tour_stops``) as a route, or None without stops."""
    from curio.core.config import BtConfig

    assert isinstance(ctx_cfg, BtConfig)
    if not ctx_cfg.tour_stops:
        return None
    stops = tuple(
        Stop(s.x_m, s.y_m, math.radians(s.yaw_deg) if s.yaw_deg is not None else None,
             name=s.name, dwell_s=s.dwell_s, message=s.message)
        for s in ctx_cfg.tour_stops
    )
    return Route(TOUR_ROUTE_ID, "Tour", stops, loop=ctx_cfg.tour_loop, skip_failed=True)


def _estop_branch(ctx: TreeContext) -> Behaviour:
    return py_trees.composites.Sequence("E-stop", memory=False, children=[
        check_key(ctx, "E-stop?", "estop", True),
        HoldEStop(ctx),
    ])


def _feeds(ctx: TreeContext, operator_feed: Operator2BB) -> list[Behaviour]:
    return [operator_feed, Blocked2BB(ctx), EStop2BB(ctx), Battery2BB(ctx), Follower2BB(ctx),
            *unattended_feeds(ctx)]


def _battery_branch(ctx: TreeContext) -> Behaviour:
    return py_trees.composites.Sequence("Battery", memory=False, children=[
        check_key(ctx, "Battery low?", "battery_home_pending", True),
        BatteryHome(ctx),
    ])


def _follow_priorities(ctx: TreeContext, *, tour: bool) -> list[Behaviour]:
    branches: list[Behaviour] = [_estop_branch(ctx), Pause(ctx)]
    branches += unattended_branches(ctx, _battery_branch(ctx), py_trees.composites.Sequence(
        "Go Home", memory=False, children=[
            check_key(ctx, "GoHome?", "home_request", None, operator.ne),
            DriveHome(ctx),
        ]))
    branches += undock_branch(ctx)
    branches += [
        py_trees.composites.Sequence("Change Path?", memory=False, children=[
            check_key(ctx, "Command?", "command", None, operator.ne),
            ChangePath(ctx),
        ]),
        py_trees.composites.Sequence("Check Path", memory=True, children=[
            IsBlocked(ctx),
            Ask4Help(ctx),
        ]),
        FollowPath(ctx, name="Guide Tour" if tour else "Follow Path"),
        *docked_branch(ctx),
        Idle(ctx),
    ]
    return branches


def _two_step_priorities(ctx: TreeContext) -> list[Behaviour]:
    goals = ctx.cfg.two_step_goals
    home_cfg = ctx.paths.get(0).waypoints[0]
    home = Pose2D(home_cfg.x_m, home_cfg.y_m, home_cfg.yaw_rad or 0.0)
    patrol = [MoveClient(ctx, f"MoveRobot {i + 1}", Pose2D(x, y, yaw))
              for i, (x, y, yaw) in enumerate(goals)]
    if ctx.docker is None:  # no dock: low battery drives home and the patrol waits
        battery: Behaviour = py_trees.composites.Sequence("Battery", memory=True, children=[
            check_key(ctx, "Battery low?", "battery_home_pending", True),
            ClearKey(ctx, "battery_home_pending", False, name="Take Battery"),
            MoveClient(ctx, "MoveRobot Home (battery)", home, home=True),
        ])
    else:
        battery = _battery_branch(ctx)
    go_home = py_trees.composites.Sequence("Go Home", memory=True, children=[
        check_key(ctx, "GoHome?", "home_request", None, operator.ne),
        ClearKey(ctx, "home_request", None, name="Take Request"),
        MoveClient(ctx, "MoveRobot Home", home, home=True),
    ])
    return [
        _estop_branch(ctx),
        Pause(ctx),
        *unattended_branches(ctx, battery, go_home),
        *undock_branch(ctx),
        py_trees.composites.Sequence("Patrol", memory=True, children=[
            check_key(ctx, "Battery ok?", "battery_low", False), *patrol]),
        *docked_branch(ctx),
        Idle(ctx),
    ]


def build_root(ctx: TreeContext, operator_feed: Operator2BB,
               tour_feed: Behaviour | None = None) -> Behaviour:
    """The root of the tree named by ``ctx.tree_kind``.

    Args:
        ctx: the shared context (its ``tree_kind`` picks the tree).
        operator_feed: the OPERATOR feed (the runner keeps it to inject autostart commands and
            to close its subscription).
        tour_feed: the tour store's feed (``curio/bt/tour_feed.py``), ticked before the
            operator feed so that ``start_tour`` runs the tour it names; None: the configured
            ``bt.tour_stops``.
    """
    kind = ctx.tree_kind
    if kind == "two_step":
        priorities = _two_step_priorities(ctx)
    elif kind in ("follow_path", "tour"):
        priorities = _follow_priorities(ctx, tour=kind == "tour")
    else:  # pragma: no cover - the config validates the name
        raise ValueError(f"unknown tree '{kind}'; use follow_path, two_step or tour")
    selector = py_trees.composites.Selector("Priorities", memory=False, children=priorities)
    root = py_trees.composites.Parallel(
        "Root", policy=ParallelPolicy.SuccessOnAll(synchronise=False),
        children=[*([tour_feed] if tour_feed is not None else []),
                  *_feeds(ctx, operator_feed), selector])
    return root
