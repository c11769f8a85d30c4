"""``allegro_hand_right_gausstac``: ManiSkill's Allegro right hand with soft pads on its
four fingertips (they replace the FSR pads of ``allegro_hand_right_touch``)."""
from __future__ import annotations

from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.allegro_hand.allegro import AllegroHandRight

from ..assets import asset_path
from ..config import PadSpec
from ..tactile import ALLEGRO_TIPS
from ..urdf import default_hand_urdf
from .base import GaussTacAgent

__all__ = ["AllegroHandRightGaussTac", "ALLEGRO_PAD_NAMES"]

#: Pad ids of the Allegro tips, in ``ALLEGRO_TIPS`` order (thumb, index, middle, ring).
ALLEGRO_PAD_NAMES = ("thumb", "index", "middle", "ring")


@register_agent(override=True)
class AllegroHandRightGaussTac(GaussTacAgent, AllegroHandRight):
    """Allegro right hand; pads ``thumb``, ``index``, ``middle``, ``ring`` (4 mm Dragon Skin 10
    silicone, E = 0.26 MPa, ν = 0.48, 16×16 taxels over 20 mm) on the palmar side (+x) of the tips."""

    uid = "allegro_hand_right_gausstac"
    gausstac_pads = tuple(PadSpec(link=link, name=name) for link, name in zip(ALLEGRO_TIPS, ALLEGRO_PAD_NAMES))
    gausstac_urdf = default_hand_urdf()
    gausstac_gaussians = str(asset_path("allegro_hand_right"))
