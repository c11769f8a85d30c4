"""ManiSkill sensors: the 3D Gaussian Splatting camera and the soft-pad tactile sensor.

* :class:`GaussianSplatCamera` is a ManiSkill :class:`~mani_skill.sensors.camera.Camera`
  (so ``obs["sensor_data"][uid]`` holds its ``rgb`` [B, H, W, 3] uint8 and ``depth``
  [B, H, W, 1] int16 millimetres, exactly like a SAPIEN camera, and ``get_params`` gives
  ``extrinsic_cv`` / ``cam2world_gl`` / ``intrinsic_cv``). Its picture is the scene's
  Gaussians (hand links; pads and soft objects as deformed by the co-simulator), composited
  with depth over SAPIEN's render of the rest of the scene (the hand hidden there), or over
  a plain colour. By default the hand's, pads' and objects' Gaussians are shaded with the
  SAPIEN scene's lights, as SAPIEN shades their meshes. Configure it with
  :class:`GaussianSplatCameraConfig`, a ``CameraConfig`` with two more fields, anywhere a
  ``CameraConfig`` goes (task sensors, human render cameras).
* :class:`TactileSensor` gives the per-pad maps ``{pad: {"depth" [B, H, W] m,
  "shear" [B, H, W, 2] m, "force" [B, H, W] N}}`` that :class:`GaussTacEnv
  <gausstac_maniskill.tasks.base.GaussTacEnv>` puts in the top-level ``obs["tactile"]``.

Both read a *scene source* owned by the environment (one
:class:`~gausstac_maniskill.cosim.GaussTacSim` per parallel env); they do not step
anything themselves.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch
from mani_skill.sensors.base_sensor import BaseSensor, BaseSensorConfig
from mani_skill.sensors.camera import Camera, CameraConfig

from .errors import ConfigError
from .optical import pad_images
from .tactile.extract import MAP_KEYS

__all__ = ["GaussianSplatCameraConfig", "GaussianSplatCamera", "TactileSensor", "TactileSensorConfig",
           "TACTILE_KEYS"]

#: The maps a :class:`TactileSensor` puts in the observation, per pad.
TACTILE_KEYS = ("depth", "shear", "force")


@dataclass
class GaussianSplatCameraConfig(CameraConfig):
    """A ``CameraConfig`` (uid, pose or mount, width, height, fov or intrinsic, near, far)
    for a :class:`GaussianSplatCamera`.

    Attributes:
        background: ``"sapien"`` composites the Gaussians, with depth, over SAPIEN's
            render of the scene without the hand (tables, rigid objects, anything with no
            Gaussians); an RGB triple in [0, 1] composites them over that plain colour.
        lighting: how the Gaussians' colours relate to the scene's lights.
            ``"scene"`` (default): the lit Gaussians (hand, pads, objects; colours are
            albedo) are shaded every frame with the ambient and directional lights of the
            SAPIEN scene the camera is in, like SAPIEN's diffuse shading of meshes
            (:mod:`gausstac_maniskill.splat.lighting`); captured layers keep their colours.
            ``"baked"``: every Gaussian's colour is drawn as stored (unlit). A
            :class:`~gausstac_maniskill.splat.lighting.Lighting`: these lights instead of
            the scene's.
    """

    background: object = "sapien"
    lighting: object = "scene"

    def __post_init__(self):
        super().__post_init__()
        from .splat.lighting import Lighting

        if not isinstance(self.lighting, Lighting) and self.lighting not in ("scene", "baked"):
            raise ConfigError(f"GaussianSplatCameraConfig({self.uid!r}).lighting={self.lighting!r}: use 'scene', "
                              "'baked' or a gausstac_maniskill.splat.lighting.Lighting")
        bg = self.background
        if isinstance(bg, str):
            if bg != "sapien":
                raise ConfigError(f"GaussianSplatCameraConfig({self.uid!r}).background={bg!r}: use 'sapien' "
                                  "or an RGB triple in [0, 1]")
        else:
            rgb = np.asarray(bg, dtype=np.float64).reshape(-1)
            if rgb.shape != (3,) or not np.all(np.isfinite(rgb)) or rgb.min() < 0 or rgb.max() > 1:
                raise ConfigError(f"GaussianSplatCameraConfig({self.uid!r}).background={bg!r} must be 'sapien' "
                                  "or an RGB triple in [0, 1]")
            self.background = tuple(float(v) for v in rgb)


class SplatSource:
    """What a :class:`GaussianSplatCamera` renders; the environment implements it.

    ``render(viewmats [B,4,4], Ks [B,3,3], width, height, background, background_depth,
    lighting=None)`` returns ``(rgb [B,H,W,3] float in [0,1], depth [B,H,W] m (inf where
    empty))``, shading env b's lit Gaussians with ``lighting[b]`` (a
    :class:`~gausstac_maniskill.splat.lighting.Lighting`; ``lighting=None``: unlit), and
    ``hidden()`` is a context manager during which SAPIEN does not draw what the
    Gaussians replace (the hand). ``background_key()`` returns a numpy array that is
    equal between two calls (``np.array_equal``) only if nothing SAPIEN draws in that
    background moved, or ``None`` when the source cannot tell (then every picture is
    taken anew).
    """

    def render(self, viewmats, Ks, width, height, background, background_depth,
               lighting=None):  # pragma: no cover
        raise NotImplementedError

    def hidden(self):  # pragma: no cover
        return contextlib.nullcontext()

    def background_key(self):  # pragma: no cover
        return None


class GaussianSplatCamera(Camera):
    """A ManiSkill camera whose picture comes from the 3D Gaussian Splatting rasterizer.

    It owns a SAPIEN camera like any ``Camera`` (pose, mount, intrinsics and, with
    ``background="sapien"``, the picture of the rest of the scene). The environment
    attaches the scene with :meth:`attach`; until then, capturing raises a clear error.
    SAPIEN's background picture is reused while neither this camera (pose, intrinsics)
    nor anything drawn in it moved (the source's ``background_key``); a change that moves
    nothing (a material or light colour) is not seen: call :meth:`invalidate_background`
    after one (GaussTac environments do so at every reset). The scene's lights (with
    ``lighting="scene"``) are read again at the same moments.
    Output keys and dtypes follow SAPIEN's minimal shader: ``rgb`` uint8 [B, H, W, 3],
    ``depth`` int16 [B, H, W, 1] in millimetres (0 where nothing is seen).
    ``position``/``segmentation`` (if asked for) are SAPIEN's, of the whole scene (a second
    SAPIEN picture, taken only then); soft deformation does not show in them.
    """

    config: GaussianSplatCameraConfig

    def __init__(self, camera_config: GaussianSplatCameraConfig, scene, articulation=None):
        super().__init__(camera_config, scene, articulation)
        self._init_splat()

    def _init_splat(self) -> None:
        self.source: SplatSource | None = None
        self._images: dict[str, torch.Tensor] | None = None
        #: SAPIEN's background as (rgb [B,H,W,3] in [0,1], depth [B,H,W] m, inf where empty)
        self._background: tuple[torch.Tensor, torch.Tensor] | None = None
        self._background_key: np.ndarray | None = None  # what it was taken of
        self._lighting: list | None = None  # per env, read from SAPIEN (lighting="scene")
        #: number of SAPIEN background pictures taken (a reused one does not count)
        self.background_renders = 0

    @classmethod
    def adopt(cls, camera: Camera) -> "GaussianSplatCamera":
        """Turn a ``Camera`` that ManiSkill built from a :class:`GaussianSplatCameraConfig`
        into a splat camera, reusing its SAPIEN camera (ManiSkill's ``_setup_sensors``
        builds a plain ``Camera`` for every ``CameraConfig``)."""
        obj = cls.__new__(cls)
        obj.__dict__.update(camera.__dict__)
        obj._init_splat()
        return obj

    def attach(self, source: SplatSource) -> None:
        """Render ``source``'s Gaussians from now on."""
        self.source = source
        self.invalidate_background()

    def invalidate_background(self) -> None:
        """Take SAPIEN's background picture anew, and read the scene's lights again, at the
        next capture."""
        self._background = self._background_key = None
        self._lighting = None

    def lighting(self) -> list | None:
        """The :class:`~gausstac_maniskill.splat.lighting.Lighting` of each env's SAPIEN scene
        (``config.lighting="scene"``), the configured one repeated, or None (``"baked"``)."""
        from .splat.lighting import Lighting

        cfg = self.config.lighting
        if cfg == "baked":
            return None
        cams = self.camera._render_cameras
        if isinstance(cfg, Lighting):
            return [cfg] * len(cams)
        if self._lighting is None:
            self._lighting = [Lighting.from_sapien(cam.entity.scene) for cam in cams]
        return self._lighting

    def _background_state(self) -> np.ndarray | None:
        """The source's background key plus this camera's poses and intrinsics (None: unknown)."""
        key = self.source.background_key()
        if key is None:
            return None
        parts = [np.asarray(key, dtype=np.float64).ravel()]
        for cam in self.camera._render_cameras:
            pose = cam.global_pose
            parts += [np.asarray(pose.p, np.float64), np.asarray(pose.q, np.float64),
                      np.asarray(cam.get_intrinsic_matrix(), np.float64).ravel(),
                      np.array([cam.get_near(), cam.get_far()], np.float64)]
        return np.concatenate(parts)

    def capture(self):
        from .splat.rasterizer import one_torch_thread

        with one_torch_thread():
            self._capture()

    def _capture(self):
        if self.source is None:
            raise ConfigError(f"GaussianSplatCamera {self.config.uid!r} has no scene attached; it works in "
                              "GaussTac environments (gausstac_maniskill.tasks.base.GaussTacEnv)")
        self._images = None
        if self.config.background != "sapien":
            return
        key = self._background_state()
        if key is not None and self._background is not None and self._background_key is not None \
                and np.array_equal(key, self._background_key):
            return  # nothing SAPIEN draws there moved: its picture would be the same
        with self.source.hidden():
            super().capture()
            # read the picture now, while the hand is hidden
            obs = super().get_obs(rgb=True, depth=True, position=False, segmentation=False)
        # (kept on SAPIEN's device: the rasterizer takes it from there to the Taichi arch's,
        # so on physx_cuda with Taichi cuda the picture never visits the host)
        d = obs["depth"][..., 0].float() / 1000.0
        self._background = (obs["rgb"][..., :3].float() / 255.0,
                            torch.where(d > 0, d, torch.full_like(d, float("inf"))))
        self._background_key = key
        self.background_renders += 1

    def _render(self) -> dict[str, torch.Tensor]:
        if self._images is not None:
            return self._images
        from .splat.rasterizer import one_torch_thread

        with one_torch_thread():
            self._images = self._render_images()
        return self._images

    def _render_images(self) -> dict[str, torch.Tensor]:
        cfg = self.config
        # (the two matrices of get_params() that a picture needs, not the model matrix too)
        ext = torch.as_tensor(self.camera.get_extrinsic_matrix(), dtype=torch.float32).reshape(-1, 3, 4)
        B = ext.shape[0]
        view = torch.cat([ext.cpu(), torch.tensor([0.0, 0.0, 0.0, 1.0]).expand(B, 1, 4)], dim=1)
        K = torch.as_tensor(self.camera.get_intrinsic_matrix(), dtype=torch.float32).reshape(-1, 3, 3).cpu()
        if cfg.background == "sapien":
            bg, bg_depth = self._background
        else:
            bg, bg_depth = cfg.background, None
        rgb, depth = self.source.render(view, K, cfg.width, cfg.height, bg, bg_depth, lighting=self.lighting())
        device = ext.device  # the camera's (as_tensor keeps a tensor's device)
        # empty pixels (inf, or NaN) read 0 mm, as in SAPIEN's depth; in-place: fewer temporaries
        mm = torch.nan_to_num(depth * 1000.0, nan=0.0, posinf=0.0, neginf=0.0)
        return {
            "rgb": rgb.clamp(0, 1).mul_(255.0).add_(0.5).to(torch.uint8).to(device),
            "depth": mm.round_().clamp_(0, 32767).to(torch.int16)[..., None].to(device),
        }

    def get_obs(self, rgb: bool = True, depth: bool = True, position: bool = True, segmentation: bool = True,
                normal: bool = False, albedo: bool = False, apply_texture_transforms: bool = True):
        out = {}
        images = self._render() if (rgb or depth) else {}
        if rgb:
            out["rgb"] = images["rgb"]
        if depth:
            out["depth"] = images["depth"]
        if position or segmentation:
            # SAPIEN's, of the whole scene (hand visible): the splatted hand lies on its mesh
            # (median depth difference 1 mm, see tests/test_sensors.py)
            super().capture()
            out.update(super().get_obs(rgb=False, depth=False, position=position, segmentation=segmentation,
                                       normal=False, albedo=False))
        return out


@dataclass
class TactileSensorConfig(BaseSensorConfig):
    """Configuration of a :class:`TactileSensor`: its ``uid``, the map names it reports, and
    ``optical``: ``{pad: optical sensor}`` (a :class:`~gausstac_maniskill.optical.Preset` sized
    to the pad's layout, :func:`~gausstac_maniskill.optical.pad_preset`) for the pads that also
    report that sensor's image and markers."""

    keys: tuple = TACTILE_KEYS
    optical: dict | None = None


class TactileSensor(BaseSensor):
    """Dense tactile maps of every soft pad, batched over the parallel envs.

    Args:
        config: uid and map names (default ``depth``, ``shear``, ``force``).
        maps_fn: returns the maps of every env, ``{pad: {map name: [B, H, W(, 2)] tensor}}``
            (:meth:`~gausstac_maniskill.batch.BatchedCosim.tactile`, or the env's
            :meth:`~gausstac_maniskill.tasks.GaussTacEnv.tactile`).
        pad_names: pad ids in observation order.
        device: torch device of the observations (the env's).

    :meth:`get_obs` returns ``{pad: {"depth": [B, H, W] m, "shear": [B, H, W, 2] m,
    "force": [B, H, W] N}}`` float32. Depth is positive into the pad; shear is the
    surface displacement along the sensor's x (along the finger) and y; force is the
    normal contact force per taxel. A pad with an optical sensor (``config.optical``) also
    gives ``"rgb"`` [B, H', W', 3] uint8, the sensor's image of the same surface, and
    ``"markers"`` [B, N, 2] float32, its markers' places in that image [px] (column, row).
    """

    def __init__(self, config: TactileSensorConfig, maps_fn: Callable[[], dict],
                 pad_names: Sequence[str], device=None):
        super().__init__(config)
        bad = [k for k in config.keys if k not in MAP_KEYS]
        if bad:
            raise ConfigError(f"TactileSensorConfig.keys: unknown map(s) {bad}; choose from "
                              + ", ".join(repr(k) for k in MAP_KEYS))
        self.maps_fn = maps_fn
        self.pad_names = list(pad_names)
        self.device = device
        self._obs = None

    def capture(self, optical: bool = True):
        """Gather the maps of the last co-simulation step (and, with ``optical``, the optical
        pads' images)."""
        maps = self.maps_fn()
        self._obs = {p: {k: maps[p][k].to(self.device) for k in self.config.keys} for p in self.pad_names}
        for p, sensor in (self.config.optical or {}).items() if optical else ():
            rgb, markers = pad_images(maps[p]["depth"], maps[p]["shear"], sensor)
            self._obs[p]["rgb"], self._obs[p]["markers"] = rgb.to(self.device), markers.to(self.device)

    def get_obs(self, **kwargs):
        if self._obs is None:
            self.capture()
        return self._obs

    def get_params(self):
        return {}

    def get_images(self, obs=None) -> torch.Tensor:
        """Depth maps of all pads side by side as a uint8 image [B, H, W·pads, 3] (0–2 mm)."""
        obs = obs if obs is not None else self.get_obs()
        d = torch.cat([obs[p]["depth"] for p in self.pad_names], dim=-1)
        v = (d / 2e-3).clamp(0, 1)
        return (torch.stack([v, v ** 0.5, 1 - v], -1) * 255).to(torch.uint8)
