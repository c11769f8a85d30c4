"""Pose sources: rigid hand link poses ``[B, L, 4, 4]`` from SAPIEN or MuJoCo."""
from .base import PoseSource, resolve_names
from .mujoco_source import ALLEGRO_CONTACT_EXCLUDES, MujocoPoseSource
from .sapien_source import SapienPoseSource

ALLEGRO_TIP_LINKS = ["link_15.0_tip", "link_3.0_tip", "link_7.0_tip", "link_11.0_tip"]
"""Allegro fingertip links: thumb, index, middle, ring (ManiSkill's order)."""

__all__ = [
    "PoseSource", "MujocoPoseSource", "SapienPoseSource", "resolve_names",
    "ALLEGRO_CONTACT_EXCLUDES", "ALLEGRO_TIP_LINKS",
]
