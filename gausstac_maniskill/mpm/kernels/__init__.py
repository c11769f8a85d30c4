"""Taichi kernels of the MLS-MPM solver (APIC transfers, quadratic B-splines), one module per job:
:mod:`.layout` (argument packs, the substep's box and switches, constants), :mod:`.slabs` (scheduling
of the particle loops), :mod:`.grid` (grid update, pinning, bond ghosts), :mod:`.transfer` (P2G, G2P,
F-bar), :mod:`.contact` (colliders, two fields), :mod:`.pressure` (implicit cell pressure),
:mod:`.readouts` (reductions read back), :mod:`.launch` (the launched kernels). Every kernel takes
ndarrays in argument packs, so one compiled set serves every MPMWorld in the process, on cpu and cuda."""
from .layout import (ActiveBox, BIG, BOND, BOND_REACH, BOND_STRETCH, BOX, DAMPING, DX, DYNAMIC, FIELD_MU, FILL, Flags,
                     GX, GY, GZ, Grid, KINEMATIC, MARGIN, MAX_STRETCH, NCHUNK, NDF, NDF2, NDI, NDI2, NDM, NDV, NDV2,
                     NDV4, NDV6, N_ACTIVE, N_COL, N_ENVS, N_GROUPS, N_KIN, N_LINKS, N_WALLS, Order, PIN_FRACTION,
                     Particles, Placement, REACH, RECOVERY, Reduction, SHARE, SLAB_CAP, SOFT_CONTACT, Scene, World,
                     mat3, vec3, vec4)  # noqa: F401
from .slabs import (TASK_SPREAD, add_to, chunk_bounds, scatter_particles, scatter_tasks, slab_range, sort_into_slabs,
                    spread_item, spread_tasks)  # noqa: F401
from .grid import (bond_ghosts, clear_grid, field_offset, free_node, grid_update, link_motion_at, node_position,
                   pinned, slip_walls)  # noqa: F401
from .transfer import (bspline_weights, elastic_stress, fbar_stress_at, g2p, limit_stretch, nodal_volume_change, p2g,
                       p2g_particle, report_stress, stencil, stress_at, volume_particle, volume_scatter)  # noqa: F401
from .contact import (beyond_bound, contact_apply, contact_particle, contact_scatter, field_contact,
                      mass_gradient)  # noqa: F401
from .pressure import (CG_DONE, CG_ROWS, CG_RZ, CG_RZ0, PRESSURE_TOL, cell_apply, cell_node, cg_apply, cg_start,
                       cg_update, gather_cells, number_cells, pressure_solve, slot_sum)  # noqa: F401
from .readouts import (chunk_health, energies, group_drift, reduce_contact, torn_particles)  # noqa: F401
from .launch import (advance, fbar_update, fill_mass, follow_links, kinematic_update, prepare, reset_contact,
                      stress_pass, substep, write_binding_frames)  # noqa: F401
