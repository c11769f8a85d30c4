"""Trilinear hexahedra (Q1) on a voxel lattice, linear elasticity.

Every element is a cube of edge ``size`` [m] on a regular lattice, so one 24×24 element
matrix serves them all. Its deviatoric part is integrated with 2×2×2 Gauss points and its
volumetric part with one point at the centre (selective reduced integration, Hughes 1980,
Int. J. Numer. Meth. Eng. 15:1413; for a parallelepiped it equals the B-bar method with a
constant volume change per element). The volume change is then one value per element, which
keeps the element free of volumetric locking as ν → 0.5.

A body may also be made of *cut cells* (the finite cell method, Parvizian, Düster & Rank 2007,
Comput. Mech. 41:121): each cube carries a ``fill``, the material's relative stiffness at n³
sub-cell points (1 where the cube holds the material, a tiny one where it is empty). Its
deviatoric part is then integrated over those sub-cells and its volume change, still one value
per element, weighted by their mean. A curved layer is so represented by the cubes that its
surface cuts, instead of a staircase of whole cubes.

Node numbering of an element: corner c = (i, j, k) ∈ {0, 1}³ is node ``4i + 2j + k``
(:data:`CORNERS`); degrees of freedom are node-major, 3 per node (x, y, z).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

__all__ = ["CORNERS", "VoxelBody", "voxel_body", "element_stiffness", "stiffness", "trilinear", "dissection_order",
           "neo_hookean_forces", "neo_hookean_remainder", "strain_points", "centre_state", "subcell_points"]

#: Corner offsets (i, j, k) of an element's 8 nodes, in node order.
CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.int64)


@dataclass(frozen=True)
class VoxelBody:
    """A body made of cube elements on a lattice (immutable description).

    Attributes:
        origin: [3] position [m] of lattice node (0, 0, 0).
        size: element edge [m].
        voxels: [E, 3] int, lattice index of each element's lowest corner.
        nodes: [V, 3] int, lattice index of each node.
        element_nodes: [E, 8] int, node of each element corner (order :data:`CORNERS`).
        fill: None (every element a whole cube of the material) or [E, n³] cut cells: the
            material's relative stiffness at each element's sub-cell points
            (:func:`subcell_points`), each standing for 1/n³ of the cube (module docstring).
    """

    origin: np.ndarray
    size: float
    voxels: np.ndarray
    nodes: np.ndarray
    element_nodes: np.ndarray
    fill: np.ndarray | None = None

    @property
    def subcells(self) -> int:
        """n, the sub-cells per axis of the cut cells (0 for whole cubes)."""
        return 0 if self.fill is None else round(self.fill.shape[1] ** (1 / 3))

    def first(self, n: int) -> "VoxelBody":
        """The body's first ``n`` elements, on the same nodes (their numbering kept)."""
        return VoxelBody(self.origin, self.size, self.voxels[:n], self.nodes, self.element_nodes[:n],
                         None if self.fill is None else self.fill[:n])

    @property
    def num_dofs(self) -> int:
        return 3 * len(self.nodes)

    def element_dofs(self) -> np.ndarray:
        """[E, 24] degrees of freedom of each element (node-major)."""
        return (self.element_nodes[:, :, None] * 3 + np.arange(3)).reshape(len(self.voxels), 24)


def voxel_body(voxels, origin, size: float, fill=None) -> VoxelBody:
    """The body of elements at lattice indices ``voxels`` [E, 3] (int), lattice origin
    ``origin`` [3] m and element edge ``size`` [m]; shared corners become one node. ``fill``:
    [E, n³] cut cells (:class:`VoxelBody`), each row with some material (> 0 somewhere)."""
    voxels = np.asarray(voxels, np.int64).reshape(-1, 3)
    if not len(voxels):
        raise ConfigError("voxel_body: no element")
    if not size > 0:
        raise ConfigError(f"voxel_body: size={size!r} m must be > 0")
    if len(np.unique(voxels, axis=0)) != len(voxels):
        raise ConfigError("voxel_body: an element appears twice")
    if fill is not None:
        fill = np.asarray(fill, float)
        n = round(fill.shape[-1] ** (1 / 3)) if fill.ndim == 2 else 0
        if fill.shape != (len(voxels), n ** 3) or n < 1:
            raise ConfigError(f"voxel_body: fill has shape {fill.shape}, expected ({len(voxels)}, n³)")
        if not np.isfinite(fill).all() or (fill < 0).any() or not (fill.max(1) > 0).all():
            raise ConfigError("voxel_body: fill must be finite, >= 0, and > 0 somewhere in every element")
    corners = voxels[:, None, :] + CORNERS[None]
    nodes, inverse = np.unique(corners.reshape(-1, 3), axis=0, return_inverse=True)
    return VoxelBody(np.asarray(origin, float).copy(), float(size), voxels, nodes,
                     inverse.reshape(len(voxels), 8), fill)


def _shape_gradients(xi: np.ndarray, size: float) -> np.ndarray:
    """[8, 3] gradients [1/m] of the trilinear shape functions at reference point xi ∈ [−1, 1]³."""
    s = 2.0 * CORNERS - 1.0  # ±1
    f = 0.5 * (1.0 + s * xi)  # [8, 3] one-dimensional factors
    g = np.empty((8, 3))
    g[:, 0] = 0.5 * s[:, 0] * f[:, 1] * f[:, 2]
    g[:, 1] = 0.5 * s[:, 1] * f[:, 0] * f[:, 2]
    g[:, 2] = 0.5 * s[:, 2] * f[:, 0] * f[:, 1]
    return g * (2.0 / size)


def _strain_matrix(g: np.ndarray) -> np.ndarray:
    """[6, 24] small-strain operator (xx, yy, zz, 2xy, 2yz, 2zx) of shape gradients g [8, 3]."""
    B = np.zeros((6, 24))
    for a in range(8):
        gx, gy, gz = g[a]
        B[0, 3 * a], B[1, 3 * a + 1], B[2, 3 * a + 2] = gx, gy, gz
        B[3, 3 * a], B[3, 3 * a + 1] = gy, gx
        B[4, 3 * a + 1], B[4, 3 * a + 2] = gz, gy
        B[5, 3 * a], B[5, 3 * a + 2] = gz, gx
    return B


def _moduli(E: float, nu: float) -> tuple[float, float]:
    """Shear modulus μ = E / (2(1 + ν)) and bulk modulus K = E / (3(1 − 2ν)) [Pa]."""
    return E / (2.0 * (1.0 + nu)), E / (3.0 * (1.0 - 2.0 * nu))


def element_stiffness(size: float, E: float, nu: float) -> np.ndarray:
    """[24, 24] stiffness [N/m] of a cube of edge ``size`` [m] of a linear isotropic solid
    (Young's modulus ``E`` [Pa], Poisson's ratio ``nu`` < 0.5): deviatoric part on 2×2×2
    Gauss points, volumetric part (bulk modulus K = E / (3(1 − 2ν))) on the centre point."""
    if not -1.0 < nu < 0.5:
        raise ConfigError(f"element_stiffness: nu={nu!r} must lie in (-1, 0.5)")
    dev, vol = _split_stiffness(size, E, nu, 1)
    return (dev[0] + vol).reshape(24, 24)


@functools.lru_cache(maxsize=16)
def _split_stiffness(size: float, E: float, nu: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of a cube's stiffness [N/m], each [.., 576] (a flattened 24 × 24):
    ``dev`` [n³, 576], the deviatoric part of each of its n × n × n sub-cells (the order of
    :func:`subcell_points`), integrated exactly on the sub-cell's 2×2×2 Gauss points; ``vol``
    [576], the volumetric part of the whole cube, at its centre. Cached (every
    :func:`stiffness` of a body of that size and material needs it): read-only arrays."""
    mu, bulk = _moduli(E, nu)
    m = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    D = 2.0 * mu * (np.diag([1.0, 1.0, 1.0, 0.5, 0.5, 0.5]) - np.outer(m, m) / 3.0)
    gauss = (2.0 * CORNERS - 1.0) / (np.sqrt(3.0) * n)  # a sub-cell's Gauss points about its centre
    w = size ** 3 / (8 * n ** 3)
    dev = np.zeros((n ** 3, 24, 24))
    for q, centre in enumerate(subcell_points(n)):
        for g in gauss:
            B = _strain_matrix(_shape_gradients(centre + g, size))
            dev[q] += B.T @ D @ B * w
    vol = m @ _strain_matrix(_shape_gradients(np.zeros(3), size))  # [24] volume change per unit displacement / volume
    dev, vol = dev.reshape(n ** 3, 576), (bulk * np.outer(vol, vol) * size ** 3).ravel()
    dev.flags.writeable = vol.flags.writeable = False
    return dev, vol


def subcell_points(n: int) -> np.ndarray:
    """[n³, 3] reference coordinates in (−1, 1)³ of the centres of a cube's n × n × n sub-cells."""
    q = (2.0 * np.arange(n) + 1.0) / n - 1.0
    return np.stack(np.meshgrid(q, q, q, indexing="ij"), -1).reshape(-1, 3)


def stiffness(body: VoxelBody, E: float, nu: float):
    """The assembled stiffness [N/m] of ``body``, ``scipy.sparse`` CSR [3V, 3V]."""
    import scipy.sparse as sp

    dofs = body.element_dofs()
    n = len(dofs)
    rows = np.repeat(dofs, 24, axis=1).ravel()
    cols = np.tile(dofs, (1, 24)).ravel()
    if body.fill is None:
        data = np.broadcast_to(element_stiffness(body.size, E, nu).ravel(), (n, 576)).ravel()
    else:  # cut cells: each sub-cell's deviatoric part times its fill, the volumetric part times their mean
        dev, vol = _split_stiffness(body.size, E, nu, body.subcells)
        data = (body.fill @ dev + np.outer(body.fill.mean(1), vol)).ravel()
    return sp.coo_matrix((data, (rows, cols)), shape=(body.num_dofs,) * 2).tocsr()


def trilinear(body: VoxelBody, points, elements) -> tuple[np.ndarray, np.ndarray]:
    """Interpolation of ``points`` [m, 3] (m) from the nodes of their ``elements`` [m] (index
    into ``body.voxels``): returns (nodes [m, 8] int, weights [m, 8]). A point outside its
    element is extrapolated with the same trilinear functions."""
    points = np.asarray(points, float).reshape(-1, 3)
    elements = np.asarray(elements, np.int64).reshape(-1)
    t = (points - body.origin) / body.size - body.voxels[elements]  # local coordinates, 0..1 inside
    w = np.ones((len(points), 8))
    for d in range(3):
        w *= np.where(CORNERS[None, :, d] == 1, t[:, None, d], 1.0 - t[:, None, d])
    return body.element_nodes[elements], w


def dissection_order(nodes: np.ndarray, leaf: int = 64) -> np.ndarray:
    """A nested-dissection elimination order of lattice ``nodes`` [V, 3] (int): the nodes are
    split by the lattice plane through the median of their longest extent, each side is
    ordered the same way, and the plane's nodes come last. A Q1 element couples only nodes
    one lattice step apart, so the plane separates the two sides and the factor fills in
    only within the planes (George 1973). On the product pad at 0.5 mm elements it has 2/3
    of the fill of SuperLU's minimum-degree order, and factors faster."""
    nodes = np.asarray(nodes, np.int64)
    order: list[np.ndarray] = []
    stack: list[tuple[np.ndarray, bool]] = [(np.arange(len(nodes)), False)]
    while stack:  # depth first, separators after both of their sides
        idx, done = stack.pop()
        if done or len(idx) <= leaf:
            order.append(idx)
            continue
        axis = int(np.argmax(np.ptp(nodes[idx], axis=0)))
        c = nodes[idx, axis]
        m = max(int(np.median(c)), int(c.min()) + 1)
        left, plane, right = idx[c < m], idx[c == m], idx[c > m]
        if not len(left) or not len(right):
            order.append(idx)
            continue
        stack += [(plane, True), (right, False), (left, False)]
    return np.concatenate(order)


def _gauss_gradients(size: float) -> tuple[np.ndarray, np.ndarray]:
    """Shape gradients [8 points, 8 nodes, 3] at the 2×2×2 Gauss points and [8, 3] at the centre."""
    gauss = (2.0 * CORNERS - 1.0) / np.sqrt(3.0)
    return np.stack([_shape_gradients(xi, size) for xi in gauss]), _shape_gradients(np.zeros(3), size)


def _det3(F: np.ndarray) -> np.ndarray:
    """Determinants [...] of 3×3 matrices F [..., 3, 3] (written out: NumPy's batched LAPACK
    costs more than the arithmetic on 10⁵ small matrices)."""
    return (F[..., 0, 0] * (F[..., 1, 1] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 1])
            - F[..., 0, 1] * (F[..., 1, 0] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 0])
            + F[..., 0, 2] * (F[..., 1, 0] * F[..., 2, 1] - F[..., 1, 1] * F[..., 2, 0]))


#: cut cubes with less than this share of material stay linear under finite strain. In a cube
#: that is mostly empty, the nodes across the empty part are held only by the material's small
#: shape-function gradients at the far side: the finite-strain forces there drive them metres
#: away (the plate's 1 mm press at 1 mm elements stalls with every cut cube finite, and
#: converges with those under half full kept linear)
CUT_FINITE_SHARE = 0.5


def neo_hookean_forces(body: VoxelBody, u: np.ndarray, E: float, nu: float) -> np.ndarray:
    """Internal nodal forces [V, 3] [N] of ``body`` displaced by ``u`` [V, 3] [m], for the
    decoupled compressible Neo-Hookean solid ψ = μ/2 (J^(−2/3) tr C − 3) + K/2 (ln J)² with the
    same split as :func:`element_stiffness`: the isochoric part on the 2×2×2 Gauss points, the
    volumetric part with J of the element's centre (F-bar: one volume change per element).
    First Piola stresses P = μ J^(−2/3) (F − tr(FᵀF)/3 F⁻ᵀ) and P₀ = K ln J₀ F₀⁻ᵀ, with
    F⁻ᵀ = cof F / J. Its linearisation at u = 0 is :func:`stiffness` exactly (μ = E/(2(1+ν)),
    K = E/(3(1−2ν))): the forces are K u plus :func:`neo_hookean_remainder`.

    Raises:
        FloatingPointError: an element is inverted (J ≤ 0 at a point of its material).
    """
    return (stiffness(body, E, nu) @ u.ravel()).reshape(-1, 3) + neo_hookean_remainder(body, u, E, nu)


def neo_hookean_remainder(body: VoxelBody, u: np.ndarray, E: float, nu: float, points=None) -> np.ndarray:
    """[V, 3] [N] :func:`neo_hookean_forces` less the linear forces K u (:func:`stiffness`):
    the finite-strain remainder P(F) − P_lin(F) of each element's stresses, P_lin = 2μ dev ε
    and K tr(ε₀) I. A whole cube takes it on its 2×2×2 Gauss points (where K's deviatoric part
    is integrated, exactly: so K u plus this is the whole cube's law); a cut cube (``body.fill``)
    at least :data:`CUT_FINITE_SHARE` full on the same points, each weighted by its octant's
    material (sub-cells of fill ≥ ½), the volumetric one at the cube's centre weighted by the
    material of the whole cube. The empty
    sub-cells (the fill of :data:`~.pad.EMPTY_STIFFNESS`, outside the layer) and the cubes
    less full stay linear: they only keep the mesh regular, and under finite strain they
    invert or run away where the surface moves far (the finite cell method's known weakness
    at large strain). Evaluated by a Taichi kernel (:mod:`.neo_hookean`); ``points``: the
    body's :func:`strain_points`, when the caller keeps them (else built here).

    Raises:
        FloatingPointError: an element is inverted (J ≤ 0 at a point of its material).
    """
    from .neo_hookean import remainder_forces

    mu, bulk = _moduli(E, nu)
    return remainder_forces(strain_points(body) if points is None else points, u, mu, bulk)


def strain_points(body: VoxelBody, finite_share: float | None = None):
    """Where each element of ``body`` takes its finite-strain remainder
    (:class:`~.neo_hookean.StrainPoints`; :func:`neo_hookean_remainder`): cut cubes with a
    share of material below ``finite_share`` (default :data:`CUT_FINITE_SHARE`) stay linear
    (``math.inf``: every cut cube, the whole cubes alone finite)."""
    finite_share = CUT_FINITE_SHARE if finite_share is None else finite_share
    from .neo_hookean import strain_points as points

    gauss, centre = _gauss_gradients(body.size)
    octants = None if body.fill is None else _octant_shares(body.subcells)
    return points(body, gauss, octants, centre, finite_share)


def _octant_shares(n: int) -> np.ndarray:
    """[n³, 8] the share of each of a cube's n³ sub-cells (:func:`subcell_points`) in the octant
    of each Gauss point (:data:`CORNERS`' order): 1 in one octant, halves for a sub-cell on a mid-plane."""
    xi = subcell_points(n)[:, None, :]  # [n³, 1, 3]
    side = 2.0 * CORNERS[None] - 1.0  # [1, 8, 3] the octant's sign on each axis
    return np.where(xi == 0.0, 0.5, (np.sign(xi) == side).astype(float)).prod(-1)


def centre_state(body: VoxelBody, u: np.ndarray, E: float, nu: float, model: str = "linear"):
    """Deformation gradient F [E, 3, 3] and Cauchy stress σ [E, 3, 3] [Pa] of each element of
    ``body`` displaced by ``u`` [V, 3] [m], at its centre (where its particle sits).

    ``"linear"``: F = I + ∇u, σ = λ tr(ε) I + 2μ ε, ε the symmetric part of ∇u (the mean strain
    of the element's Gauss points: on a cube the trilinear terms cancel between them).
    ``"neo_hookean"``: the law of :func:`neo_hookean_forces`; the isochoric Kirchhoff stress
    μ J^(−2/3) dev(F Fᵀ) averaged over the 2×2×2 Gauss points, the volumetric one K ln J₀ I with
    J₀ of the centre, σ = τ / J₀.
    """
    mu, bulk = _moduli(E, nu)
    G, G0 = _gauss_gradients(body.size)
    ue = u[body.element_nodes]  # [E, 8, 3]
    eye = np.eye(3)
    grad = np.einsum("eai,aj->eij", ue, G0)
    F0 = eye + grad
    if model == "linear":
        lam = bulk - 2.0 * mu / 3.0
        eps = 0.5 * (grad + grad.transpose(0, 2, 1))
        return F0, lam * np.trace(eps, axis1=1, axis2=2)[:, None, None] * eye + 2.0 * mu * eps
    if model != "neo_hookean":
        raise ConfigError(f"centre_state: model={model!r} must be 'linear' or 'neo_hookean'")
    F = eye + np.einsum("eai,gaj->egij", ue, G)
    J = _det3(F)
    B = np.einsum("egij,egkj->egik", F, F)
    dev = B - np.trace(B, axis1=2, axis2=3)[..., None, None] / 3.0 * eye
    tau_iso = (mu * J[..., None, None] ** (-2.0 / 3.0) * dev).mean(1)
    J0 = _det3(F0)
    tau = tau_iso + bulk * np.log(np.maximum(J0, 1e-12))[:, None, None] * eye
    return F0, tau / J0[:, None, None]
