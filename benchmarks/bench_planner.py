"""Global planner benchmark: Curio's planner against pyastar2d, scikit-image's MCP and heapq A*.

``curio bench planner [--map YAML] [--pairs N] [--seed N]``

The map is a map_server map (``--map``) or, by default, a generated 2000 × 2000 grid at 0.05 m
(100 m × 100 m) with 20 % of its cells covered by random rectangles (0.3–2.5 m sides), made
deterministically from the seed. It is inflated by Curio's :class:`~curio.nav.costmap.Costmap`
with the shipped config (footprint, padding, inflation radius, scaling). N start/goal pairs
(default 50) are drawn from the seed in the free space of that inflated costmap (cost < 253),
inside its largest 8-connected region and more than 3 m apart.

Every subject plans the same pairs on the same costs. The per-cell traversal cost is Curio's
(``1 + cost_penalty · cost / 252``; cost ≥ 253 impassable):

* ``curio``: :class:`~curio.nav.planner.GlobalPlanner` (weighted A* in numba, shortcut and
  smoothed path).
* ``pyastar2d``: C++ A*, 8-connected, a move costs the weight of the cell entered (diagonals as
  much as straight steps); its path is the raw cell path.
* ``skimage_mcp``: ``skimage.graph.MCP_Geometric``, Dijkstra with exact diagonal geometry (the
  geometric optimum of the 8-connected grid with this cost model); raw cell path.
* ``python_heapq``: a plain-Python ``heapq`` A* with the same cost model as Curio's search
  (optimal, heuristic weight 1), run on the first few pairs only (it is slow; the row says
  how many).

MCP and pyastar2d may cut a diagonal past the corner of a blocked cell; Curio and the heapq
A* do not, so their optimum can be a hair longer.

Figures: time per plan (median, mean, p99 in ms, wall clock; ``cpu_median_ms``/``cpu_mean_ms``
the same in thread CPU time, which a busy machine disturbs less), success rate, mean path length,
and ratios: time against Curio's (median) and path length against MCP's (mean of per-pair
ratios; ``cpu_vs_curio`` compares median CPU times). Path length is the Euclidean length of the
returned polyline. For Curio,
``grid_path_vs_mcp`` also compares its raw A* cell path (before shortcutting and smoothing).
"""

from __future__ import annotations

import heapq
import math
import time
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from curio.commands.bench import BenchOptions
from curio.core.clock import wall_perf_counter
from curio.core.config import REPO_ROOT, load_config
from curio.core.geometry import Pose2D
from curio.estimation.maps import OccupancyGrid, load_map
from curio.nav.api import NavError
from curio.nav.costmap import Costmap
from curio.nav.planner import GlobalPlanner, narrow_cost, traversal_lut
from curio.robot import RobotModel

DEFAULT_SIZE = 2000
DEFAULT_RES_M = 0.05
OBSTACLE_FRACTION = 0.20
MIN_PAIR_DISTANCE_M = 3.0
PYTHON_PAIRS = 5


def generate_map(seed: int, size: int = DEFAULT_SIZE, resolution_m: float = DEFAULT_RES_M,
                 fraction: float = OBSTACLE_FRACTION) -> OccupancyGrid:
    """A square map with ``fraction`` of its cells covered by random rectangles (0.3–2.5 m)."""
    rng = np.random.default_rng(seed)
    occ = np.zeros((size, size), dtype=bool)
    target = fraction * occ.size
    mean_area = (1.4 / resolution_m) ** 2
    covered = 0
    while covered < target:
        k = max(1, int((target - covered) / mean_area / 2))
        hs = (rng.uniform(0.3, 2.5, k) / resolution_m).astype(np.int64) + 1
        ws = (rng.uniform(0.3, 2.5, k) / resolution_m).astype(np.int64) + 1
        rs = rng.integers(0, size, k)
        cs = rng.integers(0, size, k)
        for r, c, h, w in zip(rs, cs, hs, ws, strict=True):
            occ[r:r + h, c:c + w] = True
        covered = int(occ.sum())
    data = np.where(occ, 100, 0).astype(np.int8)
    return OccupancyGrid(data, resolution_m, Pose2D(0.0, 0.0, 0.0), name=f"random-{seed}")


def sample_pairs(traversable: npt.NDArray[np.bool_], resolution_m: float, n: int, seed: int
                 ) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """``n`` (start, goal) cells in the largest 8-connected traversable region, > 3 m apart."""
    labels, count = ndimage.label(traversable, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        raise ValueError("the map has no free space for the rover")
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    cells = np.argwhere(labels == int(np.argmax(sizes)))
    rng = np.random.default_rng(seed)
    min_cells = MIN_PAIR_DISTANCE_M / resolution_m
    pairs: list[tuple[tuple[int, int], tuple[int, int]]] = []
    tries = 0
    while len(pairs) < n:
        tries += 1
        if tries > 1000 * n:
            raise ValueError(f"could not find {n} pairs more than {MIN_PAIR_DISTANCE_M} m apart")
        a, b = cells[rng.integers(0, len(cells), 2)]
        if math.hypot(*(a - b)) > min_cells:
            pairs.append(((int(a[0]), int(a[1])), (int(b[0]), int(b[1]))))
    return pairs


def cell_path_length_m(cells: npt.NDArray[np.int64], resolution_m: float) -> float:
    """Length of a path of ``(row, col)`` cells, metres."""
    if len(cells) < 2:
        return 0.0
    d = np.diff(np.asarray(cells, dtype=np.float64), axis=0)
    return float(np.hypot(d[:, 0], d[:, 1]).sum() * resolution_m)


def heapq_astar(weights: npt.NDArray[np.float64], start: tuple[int, int],
                goal: tuple[int, int]) -> list[tuple[int, int]] | None:
    """Plain-Python A* with Curio's search model: 8-connected, step cost = length × mean of the
    two cells' weights, no diagonal step past the corner of a blocked cell, octile heuristic."""
    h, w = weights.shape
    wl = weights.tolist()
    sqrt2 = math.sqrt(2.0)
    moves = [(-1, -1, sqrt2), (-1, 0, 1.0), (-1, 1, sqrt2), (0, -1, 1.0), (0, 1, 1.0),
             (1, -1, sqrt2), (1, 0, 1.0), (1, 1, sqrt2)]
    gr, gc = goal

    def heur(r: int, c: int) -> float:
        dx, dy = abs(c - gc), abs(r - gr)
        return dx + dy + (sqrt2 - 2.0) * min(dx, dy)

    g: dict[tuple[int, int], float] = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    closed: set[tuple[int, int]] = set()
    heap = [(heur(*start), start)]
    while heap:
        _, u = heapq.heappop(heap)
        if u in closed:
            continue
        if u == goal:
            path = [u]
            while u in parent:
                u = parent[u]
                path.append(u)
            return path[::-1]
        closed.add(u)
        ur, uc = u
        wu = wl[ur][uc]
        gu = g[u]
        for dr, dc, length in moves:
            vr, vc = ur + dr, uc + dc
            if not (0 <= vr < h and 0 <= vc < w):
                continue
            wv = wl[vr][vc]
            if wv < 0.0:
                continue
            if dr and dc and (wl[ur + dr][uc] < 0.0 or wl[ur][uc + dc] < 0.0):
                continue  # no corner cutting, as in Curio's search
            v = (vr, vc)
            if v in closed:
                continue
            ng = gu + length * 0.5 * (wu + wv)
            if ng < g.get(v, math.inf):
                g[v] = ng
                parent[v] = u
                heapq.heappush(heap, (ng + heur(vr, vc), v))
    return None


def _summary(subject: str, times_ms: list[float], cpu_ms: list[float], ok: list[bool],
             lengths: dict[int, float], mcp_lengths: dict[int, float],
             curio_median_ms: float | None, note: str = "") -> dict[str, Any]:
    t = np.asarray(times_ms, dtype=np.float64)
    cpu = np.asarray(cpu_ms, dtype=np.float64)
    ratios = [lengths[i] / mcp_lengths[i] for i in lengths if i in mcp_lengths
              and mcp_lengths[i] > 0]
    median = float(np.median(t)) if t.size else float("nan")
    row: dict[str, Any] = {
        "subject": subject,
        "pairs": len(times_ms),
        "success_rate": float(np.mean(ok)) if ok else 0.0,
        "median_ms": median,
        "mean_ms": float(t.mean()) if t.size else float("nan"),
        "p99_ms": float(np.percentile(t, 99)) if t.size else float("nan"),
        "cpu_median_ms": float(np.median(cpu)) if cpu.size else float("nan"),
        "cpu_mean_ms": float(cpu.mean()) if cpu.size else float("nan"),
        "mean_length_m": float(np.mean(list(lengths.values()))) if lengths else float("nan"),
        "length_vs_mcp": float(np.mean(ratios)) if ratios else float("nan"),
        "time_vs_curio": (median / curio_median_ms) if curio_median_ms else 1.0,
    }
    if note:
        row["note"] = note
    return row


def run(opts: BenchOptions) -> list[dict[str, Any]]:
    """Run the benchmark; one row per subject."""
    cfg = load_config(REPO_ROOT / "config.toml", [])
    if opts.map_yaml:
        grid = load_map(opts.map_yaml)
    else:
        grid = generate_map(opts.seed)
    n_pairs = opts.pairs if opts.pairs is not None else 50
    costmap = Costmap(grid, RobotModel.from_config(cfg.robot), cfg.nav.costmap)
    costs = costmap.costs()
    res = grid.resolution_m
    origin = grid.origin
    # The planner as the navigation stack builds it (with the narrow-passage term); the peers
    # search the same per-cell weights.
    nc = narrow_cost(costmap.inscribed_radius_m, costmap.circumscribed_radius_m,
                     cfg.nav.costmap.cost_scaling_factor)
    planner = GlobalPlanner(cfg.nav.planner, narrow_cost=nc)
    lut = traversal_lut(cfg.nav.planner.cost_penalty, cfg.nav.planner.allow_unknown, nc,
                        cfg.nav.planner.narrow_penalty)
    cell_w = lut[costs]  # per-cell traversal cost, < 0 impassable
    traversable = cell_w >= 0.0
    pairs = sample_pairs(traversable, res, n_pairs, opts.seed)
    print(f"map {grid.name or 'generated'}: {grid.width} x {grid.height} cells at {res:g} m, "
          f"{100.0 * float(grid.occupied_mask().mean()):.1f} % obstacles, "
          f"{100.0 * float(traversable.mean()):.1f} % traversable after inflation; "
          f"{len(pairs)} pairs, seed {opts.seed}")

    def centre(cell: tuple[int, int]) -> Pose2D:
        x, y = origin.transform_point((cell[1] + 0.5) * res, (cell[0] + 0.5) * res)
        return Pose2D(x, y, 0.0)

    try:
        import pyastar2d
        from skimage.graph import MCP_Geometric
    except ImportError:
        raise SystemExit("the planner benchmark's peers are missing: pip install -e '.[bench]' "
                         "in the repository (pyastar2d, scikit-image)") from None
    mcp_costs = np.where(traversable, cell_w, np.inf)
    py_w = np.where(traversable, cell_w, np.inf).astype(np.float32)
    hq_w = np.where(traversable, cell_w, -1.0)
    n_py = min(PYTHON_PAIRS, len(pairs))

    def run_curio(s: tuple[int, int], g: tuple[int, int]) -> tuple[float | None, float | None]:
        try:
            result = planner.plan_detailed(centre(s), centre(g), costs, res, origin)
        except NavError as exc:
            print(f"  curio failed from {s} to {g}: {exc}")
            return None, None
        return result.length_m, cell_path_length_m(result.grid_path, res)

    def run_mcp(s: tuple[int, int], g: tuple[int, int]) -> tuple[float | None, float | None]:
        mcp = MCP_Geometric(mcp_costs, fully_connected=True)
        cum, _ = mcp.find_costs([s], [g])
        if not np.isfinite(cum[g]):
            return None, None
        return cell_path_length_m(np.asarray(mcp.traceback(g), dtype=np.int64), res), None

    def run_pyastar(s: tuple[int, int], g: tuple[int, int]) -> tuple[float | None, float | None]:
        path = pyastar2d.astar_path(py_w, s, g, allow_diagonal=True)
        if path is None:
            return None, None
        return cell_path_length_m(np.asarray(path, dtype=np.int64), res), None

    def run_heapq(s: tuple[int, int], g: tuple[int, int]) -> tuple[float | None, float | None]:
        hpath = heapq_astar(hq_w, s, g)
        if hpath is None:
            return None, None
        return cell_path_length_m(np.asarray(hpath, dtype=np.int64), res), None

    subjects = {"curio": run_curio, "pyastar2d": run_pyastar, "skimage_mcp": run_mcp,
                "python_heapq": run_heapq}
    times: dict[str, list[float]] = {k: [] for k in subjects}
    cpu: dict[str, list[float]] = {k: [] for k in subjects}
    ok: dict[str, list[bool]] = {k: [] for k in subjects}
    lengths: dict[str, dict[int, float]] = {k: {} for k in subjects}
    raw_len: dict[int, float] = {}  # Curio's A* cell path before shortcutting and smoothing
    planner.warm_up()
    # The subjects take turns on each pair, so a change in the machine's load hits them alike.
    for i, (s, g) in enumerate(pairs):
        for name, fn in subjects.items():
            if name == "python_heapq" and i >= n_py:
                continue
            t0, c0 = wall_perf_counter(), time.thread_time()
            length, raw = fn(s, g)
            times[name].append((wall_perf_counter() - t0) * 1e3)
            cpu[name].append((time.thread_time() - c0) * 1e3)
            ok[name].append(length is not None)
            if length is not None:
                lengths[name][i] = length
            if raw is not None:
                raw_len[i] = raw

    curio_median = float(np.median(times["curio"]))
    curio_cpu_median = float(np.median(cpu["curio"]))
    m_len = lengths["skimage_mcp"]
    rows: list[dict[str, Any]] = []
    for name in subjects:
        note = f"first {n_py} pairs only (slow)" if name == "python_heapq" else ""
        rows.append(_summary(name, times[name], cpu[name], ok[name], lengths[name], m_len,
                             curio_median, note=note))
    for row in rows:
        row["cpu_vs_curio"] = row["cpu_median_ms"] / curio_cpu_median if curio_cpu_median else 1.0
    raw_ratios = [raw_len[i] / m_len[i] for i in raw_len if i in m_len and m_len[i] > 0]
    rows[0]["grid_path_vs_mcp"] = float(np.mean(raw_ratios)) if raw_ratios else float("nan")
    for row in rows:
        row["map"] = grid.name or "generated"
    return rows
