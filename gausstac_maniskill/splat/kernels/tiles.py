"""Stage 2 of the rasterizer: tile binning. :func:`_emit_keys` writes one 64-bit key
``(camera·tiles + tile) << 32 | float_bits(depth)`` per (Gaussian, touched 16×16 tile) and
its value (the Gaussian and the part of its pixel box inside the tile); one stable
``torch.sort`` of the keys (in ``splat.rasterizer``) then orders every tile's Gaussians front
to back."""
# no `from __future__ import annotations`: Taichi reads the kernels' annotations at runtime

import taichi as ti

from .common import B_TILES, B_X, B_Y, B_Z, TILE, TILE_BITS, _i32_3, _i64_1, _split


@ti.kernel
def _emit_keys(ends: _i64_1, bins: _i32_3, tiles_x: ti.i32, tiles_per_cam: ti.i32, keys: _i64_1,
               vals: _i64_1, one_camera: ti.template()):
    """One key per (Gaussian, touched tile): (camera·tiles + tile) << 32 | depth bits, and
    its value: the part of the Gaussian's box inside the tile (4 bits each: first column,
    last column, first row, last row, tile-local) << 32 | Gaussian index. ``ends`` [C·N]:
    the inclusive prefix sum of the tile counts, so (camera c, Gaussian g) writes from
    ends[c·N + g] - its count on.

    Positive float32 depths compare like their bit patterns read as integers,
    so sorting the keys sorts by tile, then front to back.
    """
    for i in range(bins.shape[0] * bins.shape[1]):
        c, g = _split(i, bins.shape[1], one_camera)
        count = bins[c, g, B_TILES]
        off = ends[c * bins.shape[1] + g] - count
        if count > 0:
            x0, x1 = bins[c, g, B_X] & 0xFFFF, bins[c, g, B_X] >> 16
            y0, y1 = bins[c, g, B_Y] & 0xFFFF, bins[c, g, B_Y] >> 16
            zbits = ti.cast(bins[c, g, B_Z], ti.i64)
            if count == 1:  # (most Gaussians: one entry, no loops)
                _emit_entry(keys, vals, off, c * tiles_per_cam, tiles_x, x0 >> TILE_BITS, y0 >> TILE_BITS,
                            x0, x1, y0, y1, zbits, g)
            else:
                for ty in range(y0 >> TILE_BITS, ((y1 - 1) >> TILE_BITS) + 1):  # pixel boxes are >= 0
                    for tx in range(x0 >> TILE_BITS, ((x1 - 1) >> TILE_BITS) + 1):
                        _emit_entry(keys, vals, off, c * tiles_per_cam, tiles_x, tx, ty, x0, x1, y0, y1, zbits, g)
                        off += 1


@ti.func
def _emit_entry(keys: ti.template(), vals: ti.template(), off: ti.i64, first_tile: ti.i32, tiles_x: ti.i32,
                tx: ti.i32, ty: ti.i32, x0: ti.i32, x1: ti.i32, y0: ti.i32, y1: ti.i32, zbits: ti.i64, g: ti.i32):
    """Entry ``off`` of :func:`_emit_keys`: Gaussian g's box [x0, x1) × [y0, y1) in tile (tx, ty)."""
    rx0 = ti.max(x0 - tx * TILE, 0)
    rx1 = ti.min(x1 - tx * TILE, TILE) - 1
    ry0 = ti.max(y0 - ty * TILE, 0)
    ry1 = ti.min(y1 - ty * TILE, TILE) - 1
    tile = ti.cast(first_tile + ty * tiles_x + tx, ti.i64)
    keys[off] = (tile << 32) | zbits
    part = rx0 | (rx1 << 4) | (ry0 << 8) | (ry1 << 12)
    vals[off] = (ti.cast(part, ti.i64) << 32) | ti.cast(g, ti.i64)
