"""Exceptions raised by gausstac_maniskill. Each message names the file or field at fault."""
from __future__ import annotations


class GaussTacError(Exception):
    """Base class of every error this package raises on purpose."""


class ConfigError(GaussTacError, ValueError):
    """A description (material, pad, solver setting) has an invalid field."""


class AssetError(GaussTacError, ValueError):
    """An input file (mesh, .ply, URDF) is missing or malformed."""


class SimulationError(GaussTacError, RuntimeError):
    """The simulation reached an invalid state (NaN, particle left the grid, ...)."""


class ResolutionWarning(UserWarning):
    """A simulated feature spans too few grid cells for its result to be converged."""


class AssetWarning(UserWarning):
    """An input file loads but looks wrong: mis-scaled, very large, or with values that
    suggest a different convention. The message names the file, the field and a fix."""


class SimulationWarning(UserWarning):
    """The simulation met a state it cannot resolve physically (a pad torn from its link
    by an object pushed into its core, or dragged off it) and recovered from it; the message
    says what it did and at which step."""


class CostWarning(UserWarning):
    """A scene runs far slower than it could with another setting; the message says what a
    step costs this way and which option avoids it."""
