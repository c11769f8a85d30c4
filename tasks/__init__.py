"""GaussTac tasks, registered with ManiSkill on import (``gym.make("GaussTac-...-v1")``)."""
from .base import GaussTacEnv
from .gesture import GESTURES, GestureEnv
from .touch import TouchEnv  # noqa: F401
from .press_cube import PressCubeEnv
from .slide_cube import SlideCubeEnv
from .squeeze_sponge import SqueezeSpongeEnv

__all__ = ["GaussTacEnv", "GestureEnv", "GESTURES", "PressCubeEnv", "SlideCubeEnv", "SqueezeSpongeEnv"]
