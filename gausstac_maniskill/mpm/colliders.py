"""The MPM's view of its rigid colliders inside a substep (:func:`collider_contact`).

The colliders themselves (shapes, signed distances) are :mod:`gausstac_maniskill.geometry.colliders`;
its public names are importable here too. Contact (:mod:`gausstac_maniskill.mpm.solver`): the
non-penetration constraint is enforced on particles (default) or on grid nodes, with Coulomb
friction coefficient ``friction``; ``sticky=True`` removes all tangential slip. The reaction
force and torque each collider receives are accumulated per control step.
"""

import taichi as ti

from ..geometry.colliders import (Box, Capsule, Collider, HalfSpace, MeshCollider, Sphere, local_sdf,
                                  signed_distance)
from ..geometry.kinematics import frame_at

__all__ = ["collider_contact", "Collider", "Sphere", "Box", "Capsule", "HalfSpace", "MeshCollider",
           "signed_distance"]


@ti.func
def collider_contact(S: ti.template(), k, x, dt):
    """φ, world normal and collider velocity at world point x for collider k of the scene S
    (``kernels.Scene``: ``col_kind``, ``col_prm``, ``col_frames``, ``sdf``, ``sdf_info``).

    The collider moves from its frame's start to its end pose during this substep
    (``S.col_frames``: :func:`~gausstac_maniskill.geometry.kinematics.write_frames` rows); its
    velocity at x is the finite difference of the material point of the collider that
    sits at x at the end of the substep.
    """
    R0, t0, R1, t1 = frame_at(S.col_frames, k)
    q = R1.transpose() @ (x - t1)
    prm = ti.Vector([S.col_prm[k, 0], S.col_prm[k, 1], S.col_prm[k, 2], S.col_prm[k, 3]])
    phi, n_local = local_sdf(S.col_kind[k], prm, S.sdf, S.sdf_info, k, q)
    v = (x - (R0 @ q + t0)) / dt
    return phi, R1 @ n_local, v
