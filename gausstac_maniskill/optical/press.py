"""A ball pressed into a sensor's flat gel, solved at equilibrium and imaged: the scene of the
sensors' calibration frames, so that a simulated image can be set beside a real one.

The gel is the preset's layer (thickness, E, ν) bonded to a rigid base
(:func:`~gausstac_maniskill.fem.layer_body`), pressed by a rigid ball:

* :func:`press_gel` solves it: frictionless, a quarter of the layer (the press is symmetric),
  with the product's default pad model (``model="linear"``: linear cut-cell FEM, the contact read
  at the deformed surface, as the pads read it) or finite strain (``"neo_hookean"``).
* :func:`slide_gel` presses and then drags the ball sideways with Coulomb friction on the whole
  layer (linear): the surface of a slide, for its marker flow.
* :func:`image` turns a solved gel into the sensor's image at a pixel: the top face's
  displacement, interpolated bicubically, is inverted so that each pixel sees the material point
  that has moved over it, smoothed at the cells' scale (:data:`SMOOTHING`); no pixel of the
  surface lies inside the ball.
* :func:`press_sphere` is both at once.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import ConfigError
from ..fem import Indenter, layer_body
from .presets import Preset, preset as _preset
from .render import marker_positions, render_rgb

__all__ = ["PressedGel", "Press", "press_gel", "slide_gel", "image", "press_sphere"]


@dataclass
class PressedGel:
    """A solved gel under a ball, in the layer's frame (SI units; x along the image's columns,
    y along its rows, the ball's axis at x = y = 0 at rest).

    Attributes:
        fields: [4, n, n] on the top face's cell centres, at ``(k + 0.5 - n / 2) * element``
            along each axis: indentation [m] (towards the camera), displacement along x and y
            [m], and 1 where the cell carries contact force (0 elsewhere).
        element: the cells' edge [m].
        ball_radius: [m]; ball_xy: [2] where its axis is now [m]; press_depth: its lowest
            point below the undeformed surface [m].
        force: [3] the gel's force on the ball [N]: z the normal force (positive), x and y friction.
        model: the pad model that solved it; residual: its finite-strain residual (0: linear).
        result: the solver's :class:`~gausstac_maniskill.fem.ContactResult` (to warm-start
            the next solve).
    """

    fields: np.ndarray
    element: float
    ball_radius: float
    ball_xy: np.ndarray
    press_depth: float
    force: np.ndarray
    model: str
    residual: float
    result: object


@dataclass
class Press:
    """A solved gel imaged by the sensor (pixels: column then row).

    Attributes:
        rgb: [H, W, 3] uint8 the sensor's image, markers drawn.
        depth: [H, W] indentation [m] (towards the camera) of the deformed surface over each pixel.
        shear: [H, W, 2] tangential displacement [m] (along the columns, along the rows) of the
            gel's point that rests under each pixel.
        markers: [N, 2] the markers' places [px]; marker_rest: [N, 2] their rest places.
        contact_radius_px: the radius [px] of the disc of the contact's area as the camera sees it.
        gel: the :class:`PressedGel` imaged.
    """

    rgb: np.ndarray
    depth: np.ndarray
    shear: np.ndarray
    markers: np.ndarray
    marker_rest: np.ndarray
    contact_radius_px: float
    gel: PressedGel

    def __iter__(self):  # rgb, markers, contact_radius_px = press
        return iter((self.rgb, self.markers, self.contact_radius_px))


#: The imaged surface is smoothed by a Gaussian of this many cells' σ: the cells' bicubic
#: interpolation leaves ripples of their spacing that the lookup's fine tilt bins would show as
#: stripes; the solve resolves nothing finer.
SMOOTHING = 0.5


def _smooth(z: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """``z`` [H, W] convolved with a Gaussian of ``sigma_px`` pixels (edges replicated)."""
    k = int(math.ceil(3 * sigma_px))
    if k < 1:
        return z
    g = torch.exp(-0.5 * (torch.arange(-k, k + 1, dtype=z.dtype) / sigma_px) ** 2)
    g = g / g.sum()
    z = F.pad(z[None, None], (k, k, k, k), mode="replicate")
    z = F.conv2d(z, g.view(1, 1, 1, -1))
    return F.conv2d(z, g.view(1, 1, -1, 1))[0, 0]


@functools.lru_cache(maxsize=4)
def _layer(thickness: float, half_width: float, element: float, E: float, nu: float, model: str, quarter: bool):
    return layer_body(thickness, half_width, element, E, nu, model=model, quarter=quarter)


def _ball_sdf(radius: float):
    """The ball's signed distance in its own frame (centre at the origin): (φ [S] m, normal [S, 3])."""
    def sdf(q):
        r = np.linalg.norm(q, axis=1)
        return r - radius, q / np.maximum(r, 1e-12)[:, None]

    return sdf


def _check_press(sensor: Preset, radius: float, depth: float, element: float) -> float:
    gel = sensor.gel
    if not (math.isfinite(radius) and radius > 0):
        raise ConfigError(f"press: radius={radius!r} m must be a positive number")
    if not (math.isfinite(depth) and 0 < depth < min(radius, gel.thickness)):
        raise ConfigError(f"press: depth={depth!r} m must be in (0, {min(radius, gel.thickness):g}) "
                          f"(below the ball's radius and the gel's {gel.thickness:g} m thickness)")
    if gel.curvature_radius is not None:
        raise ConfigError(f"press: sensor {sensor.name!r} has a curved gel; only flat gels are pressed")
    if not (math.isfinite(element) and 0 < element <= gel.thickness / 2):
        raise ConfigError(f"press: element={element!r} m must be in (0, {gel.thickness / 2:g}] (two cells "
                          "through the gel at least)")
    return gel.thickness / round(gel.thickness / element)  # a whole number of cells through the layer


def _top_fields(body, res) -> np.ndarray:
    """[4, nx, ny] (x-major, then y) on the top face of ``body`` solved as ``res``: the
    indentation [m] (towards the camera), the displacement along x and y [m], and 1 where the
    point carries contact force."""
    order = np.lexsort((body.points[:, 1], body.points[:, 0]))
    n = int(round(math.sqrt(body.num_points)))
    u = res.displacement[order]
    values = np.stack([-u[:, 2], u[:, 0], u[:, 1], (np.abs(res.force[order]).sum(1) > 0)], 1)
    return values.reshape(n, n, 4).transpose(2, 0, 1)


def _mirror(field: np.ndarray, odd: tuple[bool, bool]) -> np.ndarray:
    """A quarter's field [n, n] (x ≥ 0, y ≥ 0) mirrored to the whole layer [2n, 2n]; ``odd``
    (across x = 0, across y = 0): the field changes sign across that symmetry plane."""
    fx = np.concatenate([(-1 if odd[0] else 1) * field[::-1], field], 0)
    return np.concatenate([(-1 if odd[1] else 1) * fx[:, ::-1], fx], 1)


def press_gel(sensor, radius: float | None, depth: float, model: str = "linear",
              element: float = 0.25e-3, half_width: float | None = None, warm: PressedGel | None = None,
              max_iterations: int = 200) -> PressedGel:
    """The gel of ``sensor`` (a :class:`~.presets.Preset`, its name or a calibration folder)
    pressed ``depth`` [m] by a rigid frictionless ball of ``radius`` [m] (None: the preset's
    calibration ball).

    Solved with the pad model ``model`` on cubes of edge ``element`` [m] over a quarter of
    half-width ``half_width`` [m] (default: twice the gel's thickness; the surface beyond it is
    taken as undeformed); ``warm``: a press of the same set-up to start from (finite strain)."""
    sensor = _preset(sensor)
    gel = sensor.gel
    radius = sensor.ball_radius if radius is None else float(radius)
    element = _check_press(sensor, radius, float(depth), float(element))
    half_width = 2 * gel.thickness if half_width is None else float(half_width)
    body = _layer(gel.thickness, half_width, element, gel.E, gel.nu, model, True)
    pose = np.eye(4)
    pose[2, 3] = gel.thickness + radius - depth
    res = body.solve(Indenter(_ball_sdf(radius), pose), geometry="deformed",
                     warm=None if warm is None else warm.result, max_iterations=max_iterations)
    q = _top_fields(body, res)
    fields = np.stack([_mirror(q[0], (False, False)), _mirror(q[1], (True, False)),
                       _mirror(q[2], (False, True)), _mirror(q[3], (False, False))])
    total = -4.0 * res.force.sum(0) * [0.0, 0.0, 1.0]  # the quarter's in-plane forces cancel on the whole layer
    return PressedGel(fields, element, radius, np.zeros(2), float(depth), total, model, float(res.residual), res)


def slide_gel(sensor, radius: float | None, depth: float, distance: float, steps: int = 8,
              friction: float = 1.0, element: float = 0.5e-3, half_width: float | None = None
              ) -> list[PressedGel]:
    """The ball of ``radius`` [m] (None: the preset's) pressed ``depth`` [m] into the gel of
    ``sensor`` and dragged ``distance`` [m] along x in ``steps`` equal steps with Coulomb
    friction ``friction`` (the whole layer, linear): one :class:`PressedGel` per step, the
    press first."""
    sensor = _preset(sensor)
    gel = sensor.gel
    radius = sensor.ball_radius if radius is None else float(radius)
    element = _check_press(sensor, radius, float(depth), float(element))
    if not (math.isfinite(distance) and steps >= 1 and friction >= 0):
        raise ConfigError(f"slide_gel: distance={distance!r} m, steps={steps!r}, friction={friction!r}: the "
                          "distance must be finite, steps >= 1 and friction >= 0")
    half_width = 2 * gel.thickness + abs(distance) if half_width is None else float(half_width)
    body = _layer(gel.thickness, half_width, element, gel.E, gel.nu, "linear", False)
    out, warm = [], None
    for x in np.linspace(0.0, distance, steps + 1):
        pose = np.eye(4)
        pose[:3, 3] = [x, 0.0, gel.thickness + radius - depth]
        warm = body.solve(Indenter(_ball_sdf(radius), pose, friction=friction), geometry="deformed", warm=warm)
        out.append(PressedGel(_top_fields(body, warm), element, radius, np.array([x, 0.0]), float(depth),
                              -warm.force.sum(0), "linear", 0.0, warm))
    return out


def image(gel: PressedGel, sensor, center_px=None, markers: bool = True) -> Press:
    """The sensor's image of the solved ``gel``, the ball's rest axis over pixel ``center_px``
    (column, row; default: the image centre); ``markers``: draw the preset's dots (their places
    are returned either way)."""
    sensor = _preset(sensor)
    cam = sensor.camera
    cx, cy = ((cam.width - 1) / 2, (cam.height - 1) / 2) if center_px is None else map(float, center_px)
    mm = cam.mm_per_px * 1e-3
    xs = (torch.arange(cam.width, dtype=torch.float64) - cx) * mm
    ys = (torch.arange(cam.height, dtype=torch.float64) - cy) * mm
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    n = gel.fields.shape[1]
    reach = (n - 1) / 2 * gel.element  # the outermost cell centres, at ±reach
    table = torch.from_numpy(np.ascontiguousarray(gel.fields, dtype=np.float64))[None]

    def sample(x, y):  # the fields [4, H, W] at layer places x, y [H, W] [m]; beyond ±reach: none
        grid = torch.stack([y / reach, x / reach], -1)[None]
        at = F.grid_sample(table, grid, mode="bicubic", padding_mode="zeros", align_corners=True)[0]
        return at * ((x.abs() <= reach) & (y.abs() <= reach))

    lagrange = at = sample(xx, yy)  # at the material point that rests under each pixel
    for _ in range(8):  # the material point that has moved over each pixel: X + u(X) = pixel
        at = sample(xx - at[1], yy - at[2])
    R = gel.ball_radius
    rho2 = (xx - gel.ball_xy[0]) ** 2 + (yy - gel.ball_xy[1]) ** 2
    ball = torch.where(rho2 < R * R, gel.press_depth - R + torch.sqrt((R * R - rho2).clamp(min=0)),
                       torch.full_like(rho2, -math.inf))  # the ball's surface as an indentation [m]
    indent = _smooth(torch.maximum(at[0], ball), SMOOTHING * gel.element / mm)
    indent = torch.maximum(indent, ball)[None].float()
    shear = torch.stack([lagrange[1], lagrange[2]], -1)[None].float()
    rest, places = marker_positions(shear, indent, sensor)
    rgb = render_rgb(indent, sensor, markers=places if markers else None)[0].numpy()
    contact = float((at[3] > 0.5).sum())
    return Press(rgb=rgb, depth=indent[0].numpy(), shear=shear[0].numpy(), markers=places[0].numpy(),
                 marker_rest=rest.numpy(), contact_radius_px=math.sqrt(contact / math.pi), gel=gel)


def press_sphere(sensor, radius: float | None, depth: float, center_px=None, markers: bool = True,
                 **kwargs) -> Press:
    """The sensor's image of a ball of ``radius`` [m] (None: the preset's calibration ball) pressed
    ``depth`` [m] into its gel over pixel ``center_px`` (column, row, as the data packs'
    ``touch_center``): :func:`press_gel` (``kwargs`` go to it) imaged by :func:`image`.
    ``rgb, markers, contact_radius_px = press_sphere(...)`` unpacks the :class:`Press`."""
    sensor = _preset(sensor)
    return image(press_gel(sensor, radius, depth, **kwargs), sensor, center_px, markers)
