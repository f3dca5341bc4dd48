"""Heat-method geodesic distance on a tetrahedral mesh (linear finite elements).

Crane, Weischedel and Wardetzky's heat method in three steps, all on the
volume mesh: (1) diffuse heat from the sources for a short time ``t`` (one
backward-Euler step of ``(M + t K) u = 0`` with ``u = 1`` held on the sources);
(2) normalise the heat's gradient on every tetrahedron, ``X = -grad u / |grad u|``,
which points away from the sources along shortest paths *inside* the part;
(3) find the distance ``phi`` whose gradient best fits ``X``: the Poisson
problem ``K phi = div X`` with ``phi = 0`` on the sources. ``K`` is the
stiffness (cotangent) matrix of linear tetrahedra, ``M`` the lumped mass.
Distances go around holes and up the legs of an arch, which is what makes
them useful as a build direction.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse import csgraph

from fabric.slicing.curved.tetmesh import TetMesh
from fabric.wire.errors import SlicerError

__all__ = ["FemOperators", "fem_operators", "heat_distance", "tet_gradients", "node_gradients"]

DIRECT_SOLVE_MAX_NODES = 60000     # above this, conjugate gradients (sparse LU fill-in grows fast in 3D)


@dataclass(frozen=True)
class FemOperators:
    """The linear-tetrahedron operators of one mesh."""

    grad_basis: np.ndarray      # (m, 4, 3) gradient of each node's hat function on each tetrahedron (1/mm)
    volume_mm3: np.ndarray      # (m,) tetrahedron volumes
    stiffness: sp.csr_matrix    # (n, n) K_ij = sum_tets vol * grad_i . grad_j
    mass_mm3: np.ndarray        # (n,) lumped mass: a quarter of each adjacent tetrahedron's volume
    node_tet: sp.csr_matrix     # (n, m) volume weights, rows normalised: tet values -> node averages
    mean_edge_mm: float


def fem_operators(mesh: TetMesh) -> FemOperators:
    """Assemble the stiffness matrix, lumped mass and gradient operators of ``mesh``."""
    p = mesh.nodes[mesh.tets]                                   # (m, 4, 3)
    jac = (p[:, 1:] - p[:, :1])                                  # rows: edges from node 0
    vol = np.linalg.det(jac) / 6.0
    inv = np.linalg.inv(jac)                                     # columns: gradients of nodes 1..3
    g123 = inv.transpose(0, 2, 1)
    grads = np.concatenate([-g123.sum(axis=1, keepdims=True), g123], axis=1)     # (m, 4, 3)
    local = np.einsum("mik,mjk->mij", grads, grads) * vol[:, None, None]
    rows = np.repeat(mesh.tets, 4, axis=1).ravel()
    cols = np.tile(mesh.tets, (1, 4)).ravel()
    n = len(mesh.nodes)
    stiffness = sp.csr_matrix((local.ravel(), (rows, cols)), shape=(n, n))
    mass = np.bincount(mesh.tets.ravel(), weights=np.repeat(vol / 4.0, 4), minlength=n)
    m = len(mesh.tets)
    incidence = sp.csr_matrix((np.repeat(vol, 4), (mesh.tets.ravel(), np.repeat(np.arange(m), 4))), shape=(n, m))
    weight = np.asarray(incidence.sum(axis=1)).ravel()
    node_tet = sp.diags(1.0 / np.maximum(weight, 1e-30)) @ incidence
    e = mesh.edges
    mean_edge = float(np.linalg.norm(mesh.nodes[e[:, 0]] - mesh.nodes[e[:, 1]], axis=1).mean())
    return FemOperators(grads, vol, stiffness, mass, sp.csr_matrix(node_tet), mean_edge)


def tet_gradients(ops: FemOperators, tets: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(m, 3) gradient of a node field on every tetrahedron (constant per element)."""
    return np.einsum("mi,mik->mk", values[tets], ops.grad_basis)


def node_gradients(ops: FemOperators, tets: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(n, 3) gradient of a node field at the nodes: volume-weighted mean of the adjacent elements'."""
    return np.asarray(ops.node_tet @ tet_gradients(ops, tets, values))


def _solve_fixed(matrix: sp.csr_matrix, rhs: np.ndarray, fixed: np.ndarray, fixed_values: np.ndarray,
                 guess: np.ndarray | None = None) -> np.ndarray:
    """Solve ``matrix x = rhs`` with ``x[fixed] = fixed_values`` (symmetric positive definite after reduction);
    ``guess`` starts the iterative solver on large meshes."""
    n = matrix.shape[0]
    free = np.ones(n, dtype=bool)
    free[fixed] = False
    x = np.zeros(n)
    x[fixed] = fixed_values
    a_ff = matrix[free][:, free].tocsc()
    b = rhs[free] - matrix[free][:, fixed] @ fixed_values
    if a_ff.shape[0] <= DIRECT_SOLVE_MAX_NODES:
        x[free] = spla.spsolve(a_ff, b)
    else:
        diag = a_ff.diagonal()
        precond = spla.LinearOperator(a_ff.shape, matvec=lambda v: v / diag)
        start = None if guess is None else guess[free]
        sol, info = spla.cg(a_ff, b, x0=start, rtol=1e-8, maxiter=20000, M=precond)
        if info != 0:
            raise SlicerError("curved slicing: the field solve did not converge", reason="solver", info=int(info))
        x[free] = sol
    if not np.all(np.isfinite(x)):
        raise SlicerError("curved slicing: the field solve gave non-finite values", reason="solver")
    return x


def _edge_distance(mesh: TetMesh, sources: np.ndarray) -> np.ndarray:
    """Shortest-path distance (mm) along the mesh's edges from the nearest source."""
    e = mesh.edges
    w = np.linalg.norm(mesh.nodes[e[:, 0]] - mesh.nodes[e[:, 1]], axis=1)
    n = len(mesh.nodes)
    graph = sp.csr_matrix((w, (e[:, 0], e[:, 1])), shape=(n, n))
    return np.asarray(csgraph.dijkstra(graph, directed=False, indices=sources, min_only=True))


def heat_distance(mesh: TetMesh, ops: FemOperators, sources: np.ndarray, time_r: float = 1.0) -> np.ndarray:
    """Geodesic distance (mm, inside the part) from the ``sources`` nodes to every node.

    ``time_r`` scales the diffusion time ``t = time_r * h^2`` (``h`` the mean
    edge): larger values give smoother, less exact distances.
    """
    if len(sources) == 0:
        raise SlicerError("curved slicing: no source nodes for the distance field", reason="no_sources")
    if len(mesh.nodes) > DIRECT_SOLVE_MAX_NODES:
        # An iterative solver cannot resolve heat that decays to 1e-20 far from the sources, so on large
        # meshes the directions come from the shortest paths along the mesh's edges instead (exact up to
        # the edges' zig-zag, which step 3 smooths out).
        guess = _edge_distance(mesh, sources)
        g = tet_gradients(ops, mesh.tets, -guess)
    else:
        guess = None
        t = time_r * ops.mean_edge_mm ** 2
        heat_op = sp.diags(ops.mass_mm3) + t * ops.stiffness
        u = _solve_fixed(sp.csr_matrix(heat_op), np.zeros(len(mesh.nodes)), sources, np.ones(len(sources)))
        g = tet_gradients(ops, mesh.tets, u)
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    x = -g / np.maximum(norm, 1e-300)
    x[norm[:, 0] < 1e-300] = 0.0
    # divergence of X tested against every hat function: sum over tets of vol * X . grad(hat)
    div = np.einsum("mk,mik->mi", x, ops.grad_basis) * ops.volume_mm3[:, None]
    rhs = np.bincount(mesh.tets.ravel(), weights=div.ravel(), minlength=len(mesh.nodes))
    return _solve_fixed(ops.stiffness, rhs, sources, np.zeros(len(sources)), guess)
