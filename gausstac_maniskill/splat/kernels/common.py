"""What the rasterizer's kernels share: the rules of the picture (α bounds, dilation, support,
back faces), the tile size, the layouts of the per-(camera, Gaussian) record and bin entry,
the Taichi array types of the kernels' arguments, and the flat camera × item loop index."""
# no `from __future__ import annotations`: Taichi reads the kernels' annotations at runtime

import math

import taichi as ti

TILE_BITS = 4  #: log2 of the tile edge
TILE = 1 << TILE_BITS  #: tile edge in pixels (16); tile of pixel x >= 0: x >> TILE_BITS
ALPHA_MIN = 1.0 / 255.0  #: contributions below this α are skipped
ALPHA_MAX = 0.99  #: α clamp (keeps T > 0)
T_MIN = 1e-4  #: a pixel is finished when T would fall below this
DILATION = 0.3  #: px² added to the 2D covariance's diagonal (anti-aliasing)
FOV_CLAMP = 1.3  #: the Jacobian is evaluated at x/z clamped to 1.3 tan(fov/2)
K_MAX = math.sqrt(2.0 * math.log(255.0))  #: support radius (in σ) of an opaque Gaussian
SUPPORT_SLACK = 1.001  #: the support radius k is taken this much larger (rounding; the α test decides)
#: a one-sided Gaussian is culled when n·v > BACKFACE_COS |n||v| (n its normal, v the view ray)
BACKFACE_COS = 0.0
NEVER_CULLED = 2.0  #: the cosine bound of a Gaussian that is not one-sided (n·v <= |n||v| < 2|n||v|)

# One record per (camera, Gaussian), written by _project, read by the tiles: screen centre,
# conic (Σ'⁻¹: a, b, c), opacity, depth z, colour and the support bound -ln(255 o) on the
# exponent (padded to 16 floats: one 64-byte cache line). Binning reads a separate 16-byte
# entry: number of tiles touched (0: culled), x0 | x1 << 16, y0 | y1 << 16 (the pixel box
# [x0, x1) × [y0, y1)) and the depth's bits.
REC = 16
R_U, R_V, R_A, R_B, R_C, R_O, R_Z, R_R, R_G, R_BL, R_THR = range(11)
B_TILES, B_X, B_Y, B_Z = range(4)

_f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
_f32_2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
_f32_3 = ti.types.ndarray(dtype=ti.f32, ndim=3)
_f32_4 = ti.types.ndarray(dtype=ti.f32, ndim=4)
_i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
_i32_2 = ti.types.ndarray(dtype=ti.i32, ndim=2)
_i32_3 = ti.types.ndarray(dtype=ti.i32, ndim=3)
_i64_1 = ti.types.ndarray(dtype=ti.i64, ndim=1)


@ti.func
def _split(i: ti.i32, n: ti.i32, one_camera: ti.template()):
    """(camera, item) of the flat index i over cameras × n items; with ``one_camera`` it is
    (0, i) without the integer division, which costs as much as a small loop body."""
    c, k = 0, i
    if ti.static(not one_camera):
        c, k = ti.raw_div(i, n), ti.raw_mod(i, n)  # (i >= 0: no floor correction)
    return c, k
