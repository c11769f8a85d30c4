"""GaussTac for ManiSkill: visuo-tactile simulation for dexterous robot hands.

Soft fingertip pads and deformable objects are simulated with a Taichi MLS-MPM
co-simulator driven by rigid link poses (SAPIEN or MuJoCo); a 3D Gaussian
Splatting camera renders them. Units are SI throughout (m, kg, s, Pa).

``import gausstac_maniskill`` registers the GaussTac agents
(``allegro_hand_right_gausstac``, ...) and tasks (``GaussTac-*-v1``) with ManiSkill.
"""

__version__ = "0.1.0"


def _register() -> None:
    """Import the agents and tasks so that ManiSkill's registries know them."""
    try:
        import mani_skill  # noqa: F401
    except ImportError:  # pragma: no cover - the MPM/splat parts work without ManiSkill
        return
    from . import agents, tasks  # noqa: F401


_register()
