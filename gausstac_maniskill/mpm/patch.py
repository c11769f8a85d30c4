"""The active patch: a pad's cost follows its contact, not its size.

A pad in contact deforms near the contact and barely moves a few layer thicknesses away. With
``SolverSettings.patch_radius`` set, every control step splits each awake quasi-static group
bound to a link (a pad) into three parts:

* the **patch**: its dynamic particles whose rest place, carried by the link to its pose at the
  start or end of the step, lies within ``patch_radius`` of a collider's surface; simulated;
* the **shell**: every other particle within ``SHELL_CELLS`` grid cells of the patch (link rest
  frame), bound for this step to the link where it is now, deformed, so it pins the grid nodes
  around the patch (a Dirichlet boundary at the patch's current displacement);
* the **frozen** rest: carried rigidly by the link's motion once per control step
  (:func:`carry_rigidly`), at no cost in the substeps.

The error is that of clamping the layer ``patch_radius`` from the contact at the displacement
it had when it left the patch; ``bench patch`` and ``bench pad --curve --patch-radius`` measure
it. The whole group is simulated when no collider is within ``patch_radius``, while a soft
object (the other velocity field) is awake, and after a contact ends until the group is put
back at rest (:meth:`~gausstac_maniskill.mpm.solver.MPMWorld.rest_group`), so a released pad
relaxes everywhere, including the deformation frozen behind a sliding contact.
"""

import numpy as np
import taichi as ti
from scipy import ndimage

from ..geometry.colliders import local_sdf
from ..geometry.kinematics import pose_at
from .kernels import N_COL, NDF, NDF2, NDI, NDV, Particles, Scene

__all__ = ["ActivePatch", "SHELL_CELLS"]

#: Width [grid cells] of the kinematic shell around a patch. A patch particle's stencil
#: reaches 1.5 cells; the shell must bring enough bound mass to pin the nodes at the
#: patch's edge (kernels.PIN_FRACTION).
SHELL_CELLS = 2.0
#: A particle counts as touching a collider when the gap between its rest place and the
#: collider's surface at either end of the step is under this many grid cells.
SEED_CELLS = 0.5


@ti.kernel
def rest_gap(P: Particles, S: Scene, X_rest: NDV, link_poses: NDF2, col_poses: NDF2, cand: NDI, n: ti.i32,
             out: NDF):
    """out[ii]: the smallest gap [m] between particle p = cand[ii]'s surface (its rest place
    X_rest on its link, inflated by its contact radius) and any collider of its env, at the
    start and at the end of the control step (pose rows of kinematics.py)."""
    for ii in range(n):
        p = cand[ii]
        gap = 1e9
        env = S.group_env[P.group[p]]
        for e in ti.static(range(2)):
            R, t = pose_at(link_poses, P.link[p], float(e))
            xw = R @ X_rest[p] + t
            for c in range(S.counts[N_COL]):
                if S.col_env[c] != env:
                    continue
                Rc, tc = pose_at(col_poses, c, float(e))
                prm = ti.Vector([S.col_prm[c, 0], S.col_prm[c, 1], S.col_prm[c, 2], S.col_prm[c, 3]])
                phi, _nrm = local_sdf(S.col_kind[c], prm, S.sdf, S.sdf_info, c, Rc.transpose() @ (xw - tc))
                gap = ti.min(gap, phi - P.radius[p])
        out[ii] = gap


@ti.kernel
def bind_in_place(P: Particles, X0: NDV, lst: NDI, n: ti.i32, link_poses: NDF2):
    """Shell particles: their rest coordinate becomes their current place in the link frame
    (at the step's start pose), so the kinematic placement holds them where they are."""
    for ii in range(n):
        p = lst[ii]
        R0, t0 = pose_at(link_poses, P.link[p], 0.0)
        X0[p] = R0.transpose() @ (P.x[p] - t0)


@ti.kernel
def carry_rigidly(P: Particles, lst: NDI, n: ti.i32, dt: ti.f32, link_poses: NDF2):
    """Frozen particles ride with their link over the control step of ``dt`` seconds:
    x ← R_rel (x − t0) + t1, F ← R_rel F, τ ← R_rel τ R_relᵀ (R_rel = R1 R0ᵀ), the rigid
    velocity and velocity gradient of that motion, and no contact."""
    for ii in range(n):
        p = lst[ii]
        R0, t0 = pose_at(link_poses, P.link[p], 0.0)
        R1, t1 = pose_at(link_poses, P.link[p], 1.0)
        Rr = R1 @ R0.transpose()
        xn = Rr @ (P.x[p] - t0) + t1
        P.v[p] = (xn - P.x[p]) / dt
        P.x[p] = xn
        P.C[p] = (R1 - R0) @ R0.transpose() / dt
        P.F[p] = Rr @ P.F[p]
        P.tau[p] = Rr @ P.tau[p] @ Rr.transpose()
        P.impulse[p] = ti.Vector([0.0, 0.0, 0.0])
        P.contact_id[p] = -1


@ti.kernel
def groups_in_contact(P: Particles, active: NDI, n: ti.i32, colliders_only: ti.template(), out: NDI):
    """out[g] = 1 where a particle of group g touched a collider (or, unless ``colliders_only``,
    the other field) this step."""
    for ii in range(n):
        p = active[ii]
        if P.contact_id[p] >= 0 or (not colliders_only and P.contact_id[p] != -1):
            out[P.group[p]] = 1


class ActivePatch:
    """Chooses, each control step, which particles of the pads an
    :class:`~gausstac_maniskill.mpm.solver.MPMWorld` simulates (module docstring).

    Args:
        radius: ``SolverSettings.patch_radius`` [m].
        dx: grid spacing [m] (the shell is ``SHELL_CELLS`` cells wide).
    """

    def __init__(self, radius: float, dx: float):
        self.radius = float(radius)
        self.dx = float(dx)
        self._cells: dict[int, tuple[np.ndarray, tuple]] = {}  # group -> (cell of each particle, dims)
        self._ball = None

    def forget(self) -> None:
        """Drop the per-group cell tables (the world's groups changed)."""
        self._cells = {}

    def cells(self, gid: int, X_rest: np.ndarray) -> tuple[np.ndarray, tuple]:
        """Cell index [N, 3] of each particle of group ``gid`` in its link's rest frame, and the
        table's dimensions (padded by one cell)."""
        if gid not in self._cells:
            pad = 1
            ijk = np.floor(X_rest / self.dx).astype(np.int64)
            ijk -= ijk.min(0) - pad
            self._cells[gid] = (ijk, tuple(int(v) for v in ijk.max(0) + pad + 1))
        return self._cells[gid]

    def split(self, gid: int, X_rest: np.ndarray, dynamic: np.ndarray, gap: np.ndarray):
        """Patch and shell masks [N] of one group from each particle's collider gap [m]
        (:func:`rest_gap`). The contact is where a dynamic particle's gap is under
        ``SEED_CELLS`` cells; the patch is every dynamic particle within the radius of it,
        the shell the next ``SHELL_CELLS`` cells (distances in the link's rest frame).
        Both masks are empty when nothing touches."""
        seed = dynamic & (gap < SEED_CELLS * self.dx)
        if not seed.any():
            return seed, seed
        ijk, dims = self.cells(gid, X_rest)
        marked = np.zeros(dims, bool)
        marked[tuple(ijk[seed].T)] = True
        # distance [m] from each cell to the nearest cell of a particle in contact
        dist = ndimage.distance_transform_edt(~marked)[tuple(ijk.T)] * self.dx
        patch = dynamic & (dist <= self.radius)
        shell = (dist <= self.radius + SHELL_CELLS * self.dx) & ~patch
        return patch, shell
