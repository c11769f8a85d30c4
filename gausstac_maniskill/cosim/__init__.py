"""The co-simulator of one scene (:class:`GaussTacSim`): soft pads on hand links, objects,
Gaussians. :mod:`.scene` builds, steps and reads a scene; :mod:`.sleep` decides which pads an
object nears; :mod:`.rows` gives the particle rows the splat camera reads; :mod:`.state` the
scene's state."""
from ..pads.mpm import REST_TOLERANCE
from ..urdf import default_hand_urdf  # noqa: F401  (the default URDF of a scene's pads)
from .scene import GaussTacSim

__all__ = ["GaussTacSim", "REST_TOLERANCE"]
