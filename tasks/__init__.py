"""GaussTac tasks, registered with ManiSkill on import (``gym.make("GaussTac-...-v1")``)."""
from .. import agents as _agents  # noqa: F401 - the tasks make GaussTac agents: register them first
from .._registry import drop_light

drop_light()  # the light gymnasium entries of ``import gausstac_maniskill``: register_env below replaces them

from .base import GaussTacEnv  # noqa: E402
from .gesture import GESTURES, GestureEnv  # noqa: E402
from .touch import TouchEnv  # noqa: E402,F401
from .press_cube import PressCubeEnv  # noqa: E402
from .slide_cube import SlideCubeEnv  # noqa: E402
from .squeeze_sponge import SqueezeSpongeEnv  # noqa: E402
from .grasp_lift import GraspLiftCubeEnv  # noqa: E402
from .grasp_sponge import GraspSqueezeSpongeEnv  # noqa: E402

del drop_light
__all__ = ["GaussTacEnv", "GestureEnv", "GESTURES", "PressCubeEnv", "SlideCubeEnv", "SqueezeSpongeEnv", "GraspLiftCubeEnv",
           "GraspSqueezeSpongeEnv"]
