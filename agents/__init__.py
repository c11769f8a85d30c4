"""GaussTac hand agents (registered with ManiSkill on import)."""
from .allegro import ALLEGRO_PAD_NAMES, AllegroHandRightGaussTac, FloatingAllegroHandRightGaussTac  # noqa: F401
from .ability import ABILITY_PAD_LINKS, FloatingAbilityHandRightGaussTac  # noqa: F401
from .allegro_touch import AllegroHandRightTouchGaussTac  # noqa: F401
from .dclaw import DClawGaussTac  # noqa: F401
from .trifinger import TriFingerProGaussTac  # noqa: F401
from .base import GaussTacAgent, add_gausstac_pads, load_hand_gaussians

__all__ = ["GaussTacAgent", "AllegroHandRightGaussTac", "ALLEGRO_PAD_NAMES", "add_gausstac_pads",
           "load_hand_gaussians", "AllegroHandRightTouchGaussTac", "DClawGaussTac", "TriFingerProGaussTac"]
