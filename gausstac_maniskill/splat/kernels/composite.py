"""Stage 3 of the rasterizer: front-to-back α compositing, one thread per camera × 16×16 tile.

Per pixel: α = min(0.99, o·exp(power)) with power = -½ dᵀ Σ'⁻¹ d (compared with the support
bound -ln(255 o) before any exponential is taken); α < 1/255 is skipped; if T·(1-α) < 1e-4 the
pixel is finished *without* this Gaussian (as in the INRIA code); otherwise C += α·T·c,
D += α·T·z, T *= 1-α. With a background depth, a pixel is also finished at the first Gaussian
that reaches it (α ≥ 1/255) beyond the background's depth there (every later one lies deeper
still). The background colour is composited with the remaining T.
"""
# no `from __future__ import annotations`: Taichi reads the kernels' annotations at runtime

import taichi as ti

from .common import (ALPHA_MAX, ALPHA_MIN, R_A, R_B, R_BL, R_C, R_G, R_O, R_R, R_THR, R_U, R_V, R_Z, T_MIN, TILE,
                     _f32_3, _f32_4, _i64_1, _split)


@ti.kernel
def _rasterize_tiles(starts: _i64_1, vals: _i64_1, rec: _f32_3,
                     background: _f32_4, bg_is_image: ti.i32, bg_depth: _f32_3,
                     use_bg_depth: ti.template(), tiles_x: ti.i32, spread: ti.template(),
                     one_camera: ti.template(), out_rgb: _f32_4, out_depth: _f32_3, out_alpha: _f32_3):
    """Front-to-back α compositing, one thread per (camera, 16×16 tile).

    The tile's transmittance T and colour/depth sums live in thread-local arrays
    (pixel index li = row·16 + column); a finished pixel stores -T (T > 0
    otherwise) and has its bit cleared in its row's mask ``live``. A Gaussian whose
    box (in its key's value) covers no unfinished pixel is skipped without reading its
    record; otherwise it visits only the unfinished pixels of its box, row by row, as the
    set bits of ``live & box`` (lowest column first: each pixel still takes its Gaussians
    in depth order, so the picture is the same as visiting every pixel of the box). Each
    tile owns its pixels: no atomics, deterministic.
    """
    C, H, Wd = out_rgb.shape[0], out_rgb.shape[1], out_rgb.shape[2]
    tiles_y = (H + TILE - 1) // TILE
    # Taichi's CPU backend hands a parallel loop out in blocks of at least 512 iterations
    # (adaptive block size): a loop over the 64 tiles of a 128×128 picture would run on one
    # thread. Each tile is therefore ``spread`` iterations (a power of two) of which the first
    # does the work.
    for i in range(C * tiles_y * tiles_x * spread):
        if i & (spread - 1) != 0:
            continue
        c, tile = _split(i >> ti.static(spread.bit_length() - 1), tiles_y * tiles_x, one_camera)
        px0 = (tile % tiles_x) * TILE
        py0 = (tile // tiles_x) * TILE
        px1 = ti.min(px0 + TILE, Wd)
        py1 = ti.min(py0 + TILE, H)
        trans = ti.Vector([1.0] * (TILE * TILE), dt=ti.f32)  # T; -T once finished
        acc_r = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)  # Σ w c
        acc_g = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)
        acc_b = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)
        acc_z = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)  # Σ w z
        z_bg = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)  # the tile's background depth
        if ti.static(use_bg_depth):
            for y, x in ti.ndrange((py0, py1), (px0, px1)):
                z_bg[(y - py0) * TILE + (x - px0)] = bg_depth[c, y, x]
        live = ti.Vector([0] * TILE, dt=ti.u32)  # bit x - px0 of row y - py0: unfinished
        for r in range(py1 - py0):
            live[r] = ti.u32((1 << (px1 - px0)) - 1)
        alive = (px1 - px0) * (py1 - py0)
        j = ti.cast(starts[c * tiles_x * tiles_y + tile], ti.i32)  # the tile's [j, end) in vals
        end = ti.cast(starts[c * tiles_x * tiles_y + tile + 1], ti.i32)
        # the next Gaussian's record is read one step ahead: its cache line is then on
        # its way while this one is drawn (records are visited in depth order, i.e.
        # at random addresses)
        g_next, u_next = 0, 0.0
        if j < end:
            g_next = ti.cast(vals[j], ti.i32)
            u_next = rec[c, g_next, R_U]
        while j < end and alive > 0:  # Gaussians of this tile, front to back
            val = vals[j]
            g, u = g_next, u_next
            j += 1
            if j < end:
                g_next = ti.cast(vals[j], ti.i32)
                u_next = rec[c, g_next, R_U]
            part = ti.cast(val >> 32, ti.i32)  # the Gaussian's box inside this tile
            cx0, cx1 = part & 15, ((part >> 4) & 15) + 1
            cy0, cy1 = (part >> 8) & 15, ((part >> 12) & 15) + 1
            box_bits = ti.u32(((1 << cx1) - 1) & ~((1 << cx0) - 1))
            todo = ti.u32(0)
            for r in range(cy0, cy1):
                todo |= live[r] & box_bits
            if todo != 0:
                v = rec[c, g, R_V]
                A, B, Cc = rec[c, g, R_A], rec[c, g, R_B], rec[c, g, R_C]
                o, z, thr = rec[c, g, R_O], rec[c, g, R_Z], rec[c, g, R_THR]
                cr, cg, cb = rec[c, g, R_R], rec[c, g, R_G], rec[c, g, R_BL]
                half_a = -0.5 * A
                for r in range(cy0, cy1):
                    todo_row = live[r] & box_bits  # the box's unfinished pixels of this row
                    if todo_row != 0:
                        # power = -½(A dx² + C dy²) - B dx dy along the row
                        y = py0 + r
                        dy = y + 0.5 - v
                        lin = -B * dy
                        const = -0.5 * Cc * dy * dy
                        while todo_row != 0:  # each unfinished pixel once, lowest column first
                            low = todo_row & (~todo_row + ti.u32(1))
                            todo_row ^= low
                            col = 31 - ti.math.clz(ti.cast(low, ti.i32))  # CUDA's clz takes i32, not u32
                            dx = px0 + col + 0.5 - u
                            power = (half_a * dx + lin) * dx + const
                            if power >= thr:  # inside the support: o·exp(power) may reach 1/255
                                li = r * TILE + col
                                T = trans[li]  # > 0: its bit in live is set
                                alpha = ti.min(ALPHA_MAX, o * ti.exp(power))
                                if alpha >= ALPHA_MIN:
                                    T_next = T * (1.0 - alpha)
                                    hidden = False
                                    if ti.static(use_bg_depth):
                                        hidden = z > z_bg[li]  # behind the background surface
                                    if hidden or T_next < T_MIN:
                                        # finished *before* this Gaussian
                                        trans[li] = -T
                                        alive -= 1
                                        live[r] &= ~low
                                    else:
                                        w = alpha * T  # blending weight
                                        acc_r[li] += w * cr
                                        acc_g[li] += w * cg
                                        acc_b[li] += w * cb
                                        acc_z[li] += w * z
                                        trans[li] = T_next
        # write out, compositing the background with the remaining transmittance
        for y, x in ti.ndrange((py0, py1), (px0, px1)):
            li = (y - py0) * TILE + (x - px0)
            T = ti.abs(trans[li])
            by, bx = y * bg_is_image, x * bg_is_image
            out_rgb[c, y, x, 0] = acc_r[li] + T * background[c, by, bx, 0]
            out_rgb[c, y, x, 1] = acc_g[li] + T * background[c, by, bx, 1]
            out_rgb[c, y, x, 2] = acc_b[li] + T * background[c, by, bx, 2]
            out_depth[c, y, x] = acc_z[li]
            out_alpha[c, y, x] = 1.0 - T
