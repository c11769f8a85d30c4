"""Scheduling of the particle loops: the slab sort and its two colours, thread-block spreading.

Particle-to-grid without atomics (the CPU): particles are counting-sorted into *slabs* two cells
thick along the longer of the grid's x and y axes (z is fastest in memory: z slabs would share
cache lines). A stencil with base cell b touches nodes b..b+2, so slabs s and s+2 never write
the same node: the even slabs scatter in parallel, then the odd ones, each slab in a fixed
order, so a substep is bit-reproducible for any number of threads. With ``atomic`` (GPUs, which
need thousands of threads) every particle scatters in its own thread with atomic adds (the same
sums in a run-dependent order: not bit-reproducible).
"""
import taichi as ti

from .layout import BIG, NCHUNK

# Taichi 1.7's CPU backend hands a range-for to its threads in blocks of at least 512
# iterations (its "adaptive" block size, which neither loop_config(block_dim=...) nor
# cpu_block_dim_adaptive=False changes), so a loop over the ~10 slabs of a pad would run
# on one thread. A serial-by-design loop over a few heavy items (slabs, chunks) therefore
# spreads them TASK_SPREAD iterations apart: each block holds one item, the other iterations
# do nothing. The work and its order are the same; only the threads that take it change.
TASK_SPREAD = 512


@ti.func
def spread_tasks(n_items):
    """Loop count that puts each of ``n_items`` heavy items in a thread block of its own."""
    return n_items * TASK_SPREAD


@ti.func
def spread_item(q):
    """Item of spread iteration q (see :func:`spread_tasks`), or -1 for a filler iteration."""
    return q // TASK_SPREAD if q % TASK_SPREAD == 0 else -1


@ti.func
def chunk_bounds(W: ti.template(), n: ti.template(), inv_dx: ti.template()):
    """Per chunk of the ``n`` active particles, min/max of the stencil base cell
    (``W.bounds[c]`` = lo xyz, hi xyz; NCHUNK chunks)."""
    ti.loop_config(block_dim=TASK_SPREAD)
    for q in range(spread_tasks(NCHUNK)):  # a thread block per chunk
        c = spread_item(q)
        if c >= 0:
            lo = ti.Vector([BIG, BIG, BIG])
            hi = ti.Vector([-BIG, -BIG, -BIG])
            start = c * n // NCHUNK
            end = (c + 1) * n // NCHUNK
            for ii in range(start, end):
                base = ti.cast(ti.floor(W.x[W.active[ii]] * inv_dx - 0.5), ti.i32)
                lo = ti.min(lo, base)
                hi = ti.max(hi, base)
            for d in ti.static(range(3)):
                W.bounds[c, d] = lo[d]
                W.bounds[c, 3 + d] = hi[d]


@ti.func
def sort_into_slabs(W: ti.template(), n: ti.template(), inv_dx: ti.template(), axis: ti.template(),
        lo_axis: ti.template(), n_slabs: ti.template()):
    """Stable counting sort of the ``n`` active particles by slab (two cells along ``axis``,
    from base cell ``lo_axis``) into ``W.order``, with ``W.slab_start`` the first of each slab."""
    ti.loop_config(serialize=True)
    for s in range(n_slabs + 1):
        W.slab_start[s] = 0
    ti.loop_config(serialize=True)
    for ii in range(n):
        base = ti.cast(ti.floor(W.x[W.active[ii]][axis] * inv_dx - 0.5), ti.i32)
        s = (base - lo_axis) // 2
        W.slab_of[ii] = s
        W.slab_start[s + 1] += 1
    ti.loop_config(serialize=True)
    for s in range(n_slabs):
        W.slab_start[s + 1] += W.slab_start[s]
        W.cursor[s] = W.slab_start[s]
    ti.loop_config(serialize=True)
    for ii in range(n):
        s = W.slab_of[ii]
        W.order[W.cursor[s]] = W.active[ii]
        W.cursor[s] += 1


@ti.func
def scatter_tasks(O: ti.template(), B: ti.template(), flags: ti.template(), color: ti.template()):
    """Loop count of a scatter loop: every sorted particle (``flags.atomic``), or the slabs of
    colour ``color`` (slab 2h + color), spread a block apart (:func:`spread_tasks`)."""
    n = 0
    if ti.static(flags.atomic):
        n = O.slab_start[B.n_slabs]
    else:
        n = spread_tasks((B.n_slabs - color + 1) // 2)
    return n


@ti.func
def slab_range(O: ti.template(), flags: ti.template(), color: ti.template(), q):
    """Sorted particles [lo, hi) of iteration q of a scatter loop (:func:`scatter_tasks`): slab
    2h + color for h = spread_item(q), empty for a filler iteration, or (``flags.atomic``) the
    single particle q."""
    lo, hi = q, q + 1
    if ti.static(not flags.atomic):
        h = spread_item(q)
        lo, hi = 0, 0
        if h >= 0:
            s = 2 * h + color
            lo, hi = O.slab_start[s], O.slab_start[s + 1]
    return lo, hi


@ti.func
def scatter_particles(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template(), body: ti.template()):
    """Run ``body(P, G, S, O, B, flags, p, origin)`` (a ``ti.func``) for every sorted particle p
    (``origin``: the active box's corner, in cells): the even slabs in parallel, then the odd ones,
    each slab's particles in order, in a parallel loop a thread block per slab
    (:func:`scatter_tasks`, :func:`slab_range`); with ``flags.atomic`` a thread per particle.
    The loop is the caller's outermost one (a ``ti.func`` is inlined): call it at a kernel's
    outermost scope, not under a run-time ``if``."""
    origin = ti.Vector([B.ox, B.oy, B.oz])
    for color in ti.static(range(1 if ti.static(flags.atomic) else 2)):
        ti.loop_config(block_dim=128 if ti.static(flags.atomic) else TASK_SPREAD)
        for q in range(scatter_tasks(O, B, flags, color)):
            lo, hi = slab_range(O, flags, color, q)
            for ii in range(lo, hi):
                body(P, G, S, O, B, flags, O.order[ii], origin)


@ti.func
def add_to(a: ti.template(), idx, value, atomic: ti.template()):
    """a[idx] += value: atomically, or as a plain read-modify-write where the slab
    colouring guarantees that no other thread writes a[idx] meanwhile."""
    if ti.static(atomic):
        ti.atomic_add(a[idx], value)
    else:
        a[idx] = a[idx] + value
