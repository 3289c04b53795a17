"""A 2-D pose graph with robust loop-closure edges, solved by sparse Levenberg–Marquardt.

Nodes are poses ``(x, y, yaw)`` in ``map`` (metres, radians); an edge ``(i, j, z, Ω)`` says that
node j, seen from node i, is at ``z`` (j's pose in i's frame) with information ``Ω`` (3×3,
1/m² and 1/rad², in i's frame). The error of an edge is ``e = z⁻¹ ⊖ (xᵢ⁻¹ ⊕ xⱼ)`` — its
translation rotated into z's frame, its angle wrapped — and the graph minimises
``Σ ρ(eᵀΩe)``, node 0 held fixed (the gauge: the map frame is the first pose).

The linear algebra is ``scipy.sparse``: each iteration assembles the sparse normal equations
from vectorised per-edge Jacobians and solves them with SuperLU (``spsolve``); a 2 000-node graph
takes a few milliseconds an iteration.

**Robust edges.** Loop closures come from scan matching in places that may look alike; one wrong
closure with a plain quadratic cost bends the whole map. Edges marked ``robust`` use *dynamic
covariance scaling* (P. Agarwal, G. D. Tipaldi, L. Spinello, C. Stachniss, W. Burgard,
*Robust map optimization using dynamic covariance scaling*, ICRA 2013): each iteration scales
the edge's information by ``s² = min(1, 2Φ/(Φ + χ²))²``, a closed form of switchable
constraints — an edge that agrees with the rest (small χ²) keeps its full weight, one that
disagrees fades out instead of pulling. :meth:`PoseGraph.outliers` then names the robust edges
whose χ² stays large so the caller can drop them for good.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D, wrap_angles

__all__ = ["OptimizeResult", "PoseGraph", "adjoint", "to_local_info"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


def to_local_info(info: F64, yaw: float) -> F64:
    """Information of a pose's ``(x, y, yaw)`` perturbed in the parent frame → perturbed in the
    pose's own frame (the convention of edge information here), given the pose's ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    r = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(r.T @ info @ r, dtype=np.float64)


def adjoint(t: Pose2D) -> F64:
    """The SE(2) adjoint of ``t``: ``t ⊕ δ ⊕ t⁻¹ ≈ Adj(t) δ`` for a small ``δ`` (x, y, yaw)."""
    c, s = np.cos(t.yaw), np.sin(t.yaw)
    return np.array([[c, -s, t.y], [s, c, -t.x], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, slots=True)
class OptimizeResult:
    """Outcome of :meth:`PoseGraph.optimize`: iterations run and the (robust) cost before/after."""

    iterations: int
    cost_before: float
    cost_after: float


def _errors(x: F64, ii: I64, jj: I64, z: F64) -> tuple[F64, F64, F64, F64, F64, F64]:
    """Edge errors ``(m, 3)`` and what the Jacobians need (rotation and the relative offset)."""
    xi, xj = x[ii], x[jj]
    ci, si = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    dx = xj[:, 0] - xi[:, 0]
    dy = xj[:, 1] - xi[:, 1]
    d0 = ci * dx + si * dy  # R_i^T (t_j - t_i)
    d1 = -si * dx + ci * dy
    ex = cz * (d0 - z[:, 0]) + sz * (d1 - z[:, 1])
    ey = -sz * (d0 - z[:, 0]) + cz * (d1 - z[:, 1])
    et = wrap_angles(xj[:, 2] - xi[:, 2] - z[:, 2])
    return np.stack([ex, ey, et], axis=1), ci, si, cz, sz, np.stack([d0, d1], axis=1)


def _jacobians(ci: F64, si: F64, cz: F64, sz: F64, d: F64) -> tuple[F64, F64]:
    """``A = ∂e/∂xᵢ`` and ``B = ∂e/∂xⱼ``, each ``(m, 3, 3)``."""
    m = len(ci)
    a = np.zeros((m, 3, 3))
    b = np.zeros((m, 3, 3))
    r00 = cz * ci - sz * si  # (R_i R_z)^T
    r01 = cz * si + sz * ci
    r10 = -sz * ci - cz * si
    r11 = -sz * si + cz * ci
    g0, g1 = d[:, 1], -d[:, 0]  # ∂/∂θ_i of R_i^T (t_j - t_i)
    a[:, 0, 0], a[:, 0, 1] = -r00, -r01
    a[:, 1, 0], a[:, 1, 1] = -r10, -r11
    a[:, 0, 2] = cz * g0 + sz * g1
    a[:, 1, 2] = -sz * g0 + cz * g1
    a[:, 2, 2] = -1.0
    b[:, 0, 0], b[:, 0, 1] = r00, r01
    b[:, 1, 0], b[:, 1, 1] = r10, r11
    b[:, 2, 2] = 1.0
    return a, b


class PoseGraph:
    """Nodes and edges (see the module docstring); grows as the mapper adds to it.

    Args:
        dcs_phi: Φ of dynamic covariance scaling for robust edges (χ² units).
    """

    def __init__(self, dcs_phi: float = 5.0) -> None:
        self.dcs_phi = dcs_phi
        self._nodes: list[tuple[float, float, float]] = []
        self._x: F64 | None = None
        self.ii: list[int] = []
        self.jj: list[int] = []
        self.z: list[tuple[float, float, float]] = []
        self.info: list[F64] = []
        self.robust: list[bool] = []
        self.active: list[bool] = []
        self._robust_on = True

    # --- building ------------------------------------------------------------------------------
    def add_node(self, pose: Pose2D) -> int:
        """Add a node at ``pose`` (``map``); return its index."""
        self._sync()
        self._nodes.append(pose.as_tuple())
        return len(self._nodes) - 1

    def add_edge(self, i: int, j: int, z: Pose2D, info: F64, robust: bool = False) -> int:
        """Add the constraint "j is at ``z`` in i's frame" with information ``info``."""
        n = len(self)
        if not (0 <= i < n and 0 <= j < n) or i == j:
            raise ValueError(f"edge ({i}, {j}) needs two distinct nodes of 0..{n - 1}")
        self.ii.append(i)
        self.jj.append(j)
        self.z.append(z.as_tuple())
        self.info.append(np.asarray(info, dtype=np.float64).reshape(3, 3))
        self.robust.append(robust)
        self.active.append(True)
        return len(self.ii) - 1

    def deactivate(self, edge: int) -> None:
        """Drop an edge from the optimisation (it stays listed, inactive)."""
        self.active[edge] = False

    def __len__(self) -> int:
        return len(self._nodes) if self._x is None else len(self._x)

    def _sync(self) -> None:
        if self._x is not None:
            self._nodes = [tuple(r) for r in self._x.tolist()]  # type: ignore[misc]
            self._x = None

    @property
    def poses(self) -> F64:
        """``(N, 3)`` node poses (a copy)."""
        if self._x is not None:
            return self._x.copy()
        return np.array(self._nodes, dtype=np.float64).reshape(-1, 3)

    def pose(self, i: int) -> Pose2D:
        """Node ``i``'s pose."""
        r = self._x[i] if self._x is not None else self._nodes[i]
        return Pose2D(float(r[0]), float(r[1]), float(r[2]))

    def set_poses(self, x: F64) -> None:
        """Replace every node pose (``(N, 3)``)."""
        if x.shape != (len(self), 3):
            raise ValueError(f"expected ({len(self)}, 3) poses, got {x.shape}")
        self._x = np.array(x, dtype=np.float64)

    # --- solving -------------------------------------------------------------------------------
    def _arrays(self) -> tuple[I64, I64, F64, F64, npt.NDArray[np.bool_]]:
        act = np.array(self.active, dtype=bool)
        ii = np.array(self.ii, dtype=np.int64)[act]
        jj = np.array(self.jj, dtype=np.int64)[act]
        z = np.array(self.z, dtype=np.float64).reshape(-1, 3)[act]
        info = np.stack(self.info)[act] if self.info else np.zeros((0, 3, 3))
        rob = np.array(self.robust, dtype=bool)[act]
        return ii, jj, z, info, rob

    def _weights(self, chi2: F64, rob: npt.NDArray[np.bool_]) -> F64:
        if not self._robust_on:
            return np.ones_like(chi2)
        s = np.minimum(1.0, 2.0 * self.dcs_phi / (self.dcs_phi + chi2))
        return np.where(rob, s * s, 1.0)

    def _cost(self, x: F64, ii: I64, jj: I64, z: F64, info: F64,
              rob: npt.NDArray[np.bool_]) -> float:
        e = _errors(x, ii, jj, z)[0]
        chi2 = np.einsum("mi,mij,mj->m", e, info, e)
        s = np.sqrt(self._weights(chi2, rob))
        # The switchable-constraint cost s²χ² + Φ(1 − s)² at its optimal s (= 1: plain χ²).
        return float(np.sum(s * s * chi2 + np.where(rob, self.dcs_phi * (1.0 - s) ** 2, 0.0)))

    def chi2(self) -> F64:
        """χ² = eᵀΩe of every edge at the current poses (inactive edges included)."""
        if not self.ii:
            return np.zeros(0)
        x = self.poses
        z = np.array(self.z, dtype=np.float64).reshape(-1, 3)
        e = _errors(x, np.array(self.ii), np.array(self.jj), z)[0]
        return np.asarray(np.einsum("mi,mij,mj->m", e, np.stack(self.info), e))

    def outliers(self, chi2_max: float) -> list[int]:
        """Active robust edges whose χ² exceeds ``chi2_max``."""
        c = self.chi2()
        return [k for k in range(len(c)) if self.active[k] and self.robust[k] and c[k] > chi2_max]

    def _system(self, x: F64, ii: I64, jj: I64, z: F64, info: F64,
                rob: npt.NDArray[np.bool_]) -> tuple[Any, F64]:
        import scipy.sparse as sp  # here: scipy.sparse is imported only when mapping

        n = len(x)
        e, ci, si, cz, sz, d = _errors(x, ii, jj, z)
        chi2 = np.einsum("mi,mij,mj->m", e, info, e)
        om = info * self._weights(chi2, rob)[:, None, None]
        a, b = _jacobians(ci, si, cz, sz, d)
        at_o = np.einsum("mki,mkl->mil", a, om)
        bt_o = np.einsum("mki,mkl->mil", b, om)
        blocks = (np.einsum("mil,mlj->mij", at_o, a), np.einsum("mil,mlj->mij", at_o, b),
                  np.einsum("mil,mlj->mij", bt_o, a), np.einsum("mil,mlj->mij", bt_o, b))
        r3 = np.arange(3)
        rows, cols, vals = [], [], []
        for blk, bi, bj in zip(blocks, (ii, ii, jj, jj), (ii, jj, ii, jj), strict=True):
            rr = (3 * bi)[:, None, None] + r3[None, :, None]
            cc = (3 * bj)[:, None, None] + r3[None, None, :]
            rows.append(np.broadcast_to(rr, blk.shape).ravel())
            cols.append(np.broadcast_to(cc, blk.shape).ravel())
            vals.append(blk.ravel())
        h = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * n, 3 * n))
        g = np.zeros(3 * n)
        np.add.at(g, (3 * ii)[:, None] + r3[None, :], np.einsum("mil,ml->mi", at_o, e))
        np.add.at(g, (3 * jj)[:, None] + r3[None, :], np.einsum("mil,ml->mi", bt_o, e))
        return h, g

    def optimize(self, iterations: int = 20, tolerance: float = 1e-6,
                 robust: bool = True) -> OptimizeResult:
        """Levenberg–Marquardt on the graph (node 0 fixed); updates the node poses.

        ``robust=False`` treats every edge as quadratic (DCS off) — for the first solve after
        closures that must pull the graph far: DCS scales an edge by its χ² *at the current
        estimate*, so a correct closure that has yet to undo a metre of drift would start
        switched off.
        """
        self._robust_on = robust
        try:
            return self._optimize(iterations, tolerance)
        finally:
            self._robust_on = True

    def _optimize(self, iterations: int, tolerance: float) -> OptimizeResult:
        """Gauss–Newton with a backtracking line search: one sparse factorisation an
        iteration; a step that does not lower the cost is halved (up to six times)."""
        x = self.poses
        n = len(x)
        ii, jj, z, info, rob = self._arrays()
        if n < 2 or len(ii) == 0:
            return OptimizeResult(0, 0.0, 0.0)
        cost0 = cost = self._cost(x, ii, jj, z, info, rob)
        it = 0
        for it in range(1, iterations + 1):  # noqa: B007
            import scipy.sparse as sp
            from scipy.sparse.linalg import spsolve

            h, g = self._system(x, ii, jj, z, info, rob)
            h = h[3:, 3:].tocsc()
            damped = h + sp.diags(1e-9 * np.maximum(h.diagonal(), 1.0))
            step = np.asarray(spsolve(damped.tocsc(), -g[3:], permc_spec="MMD_AT_PLUS_A"),
                              dtype=np.float64).reshape(n - 1, 3)
            if not np.all(np.isfinite(step)) or float(np.max(np.abs(step))) < tolerance:
                break
            alpha, new = 1.0, np.inf
            for _ in range(7):
                xn = x.copy()
                xn[1:] += alpha * step
                xn[:, 2] = wrap_angles(xn[:, 2])
                new = self._cost(xn, ii, jj, z, info, rob)
                if new < cost:
                    break
                alpha *= 0.5
            if not new < cost:
                break
            x = xn
            done = (cost - new) <= 1e-9 * cost
            cost = new
            if done:
                break
        self._x = x
        return OptimizeResult(it, cost0, cost)
