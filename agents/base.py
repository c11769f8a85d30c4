"""What a ManiSkill hand agent needs to carry GaussTac pads, and a wrapper that adds
them to any registered hand agent by link names.

An agent becomes a GaussTac agent by having the class attributes of
:class:`GaussTacAgent`: the pads (:class:`~gausstac_maniskill.config.PadSpec`), the URDF
their collision meshes come from, and optionally a folder of hand Gaussians
(``gaussians.ply`` + ``links.json``) for the splat camera.

One thing changes in SAPIEN: a pad link collides with its **rigid core**, its collision
geometry without the soft layer (:func:`~gausstac_maniskill.tactile.pad_core_meshes`). The
soft pad handles contact in the layer in front of the core, and an object that reaches
the core stops the finger (it can never pass through). The agent loads a copy of its
URDF with those collision meshes (:func:`core_urdf`, written once to
:func:`~gausstac_maniskill.assets.cache_path`). Controllers, keyframes, visuals and every
other link are the agent's own.
"""
from __future__ import annotations

import difflib
import os
from functools import lru_cache
from typing import Mapping, Sequence

from mani_skill.agents.base_agent import BaseAgent
from mani_skill.agents.registration import REGISTERED_AGENTS, register_agent

from ..config import PadSpec
from ..errors import AssetError, ConfigError
from ..task_checks import check_optical
# the hand Gaussians folder's readers (re-exported: agents name their folder here)
from ..splat.asset import load_hand_closed_links, load_hand_gaussians, load_hand_lod  # noqa: F401
from ..urdf import link_names

__all__ = ["GaussTacAgent", "add_gausstac_pads", "core_meshes", "core_urdf", "load_hand_gaussians"]


class GaussTacAgent:
    """Mixin of hand agents with soft GaussTac pads (put it before the ManiSkill agent class).

    Attributes:
        gausstac_pads: the pads; ``PadSpec.name`` is the key in ``obs["tactile"]``.
        gausstac_urdf: URDF with the pad links' collision meshes (default: ``urdf_path``).
        gausstac_gaussians: folder holding the hand's ``gaussians.ply`` and ``links.json``
            (link-local Gaussians); ``None``: the splat camera draws pads and soft objects
            over SAPIEN's render of the rigid hand.
        gausstac_core: pad links collide in SAPIEN with their rigid core (default). ``False``
            keeps the URDF's collision meshes (the rigid fingertip then stops before the
            pad compresses).
        gausstac_optical: the optical sensors its pads carry, as a task's ``optical=`` takes
            them (a preset for every pad, or ``{pad: preset}``); a task's own ``optical=``
            overrides it. None: none.
    """

    gausstac_pads: tuple = ()
    gausstac_urdf: str | None = None
    gausstac_gaussians: str | None = None
    gausstac_core: bool = True
    gausstac_optical = None

    def __init__(self, *args, **kwargs):
        if self.gausstac_pads and self.gausstac_core and self.urdf_path:
            self.urdf_path = str(core_urdf(type(self)))  # before ManiSkill loads the articulation
        super().__init__(*args, **kwargs)

    @classmethod
    def pad_urdf(cls) -> str:
        """The URDF the pads are built from."""
        return cls.gausstac_urdf or cls.urdf_path


def core_urdf(agent: type) -> str:
    """The agent's URDF (``agent.urdf_path``, what SAPIEN loads) with each pad link's
    collision geometry replaced by its rigid core, built from the pad meshes of
    ``agent.pad_urdf()`` (its convex pieces, :func:`~gausstac_maniskill.tactile.pad_core_meshes`).
    Written once per content to
    ``cache_path("cores", <hash>)``; the path of the URDF is returned.

    Raises:
        AssetError: a URDF or pad mesh is missing.
        ConfigError: a pad leaves no core (see :func:`~gausstac_maniskill.tactile.pad_core_meshes`).
    """
    return _core_urdf(agent.uid, str(agent.urdf_path), agent.pad_urdf(), tuple(agent.gausstac_pads))


@lru_cache(maxsize=16)
def _core_urdf(uid: str, urdf: str, pad_urdf: str, pads: tuple) -> str:
    import hashlib

    from ..cache import cache_dir
    from ..tactile import pad_mesh
    from ..tactile.pad import CORE_DEPTH
    from ..urdf import write_urdf_with_meshes

    _check_pad_links(uid, pad_urdf, pads)
    by_link = _pads_by_link(pads)
    meshes = {link: pad_mesh(specs[0], pad_urdf) for link, specs in by_link.items()}
    key = hashlib.sha1()
    for path in (urdf, pad_urdf):
        key.update(os.path.abspath(path).encode())
        with open(path, "rb") as f:
            key.update(f.read())
    for link, specs in sorted(by_link.items()):
        key.update(repr([(s.link, s.axis, s.cone_deg, s.thickness, CORE_DEPTH) for s in specs]).encode())
        key.update(meshes[link].vertices.tobytes())
    return str(write_urdf_with_meshes(urdf, cache_dir("cores", key.hexdigest()[:16]), _link_cores(by_link, meshes),
                                      stem="core"))


def core_meshes(agent: type) -> dict[str, list]:
    """Pad link name -> the convex pieces of its rigid core (``trimesh.Trimesh``, link frame,
    metres), as :func:`core_urdf` gives them to SAPIEN."""
    from ..tactile import pad_mesh

    by_link = _pads_by_link(agent.gausstac_pads)
    return _link_cores(by_link, {link: pad_mesh(specs[0], agent.pad_urdf()) for link, specs in by_link.items()})


def _pads_by_link(pads) -> dict[str, list]:
    """Link name -> the pads on it, in order."""
    by_link: dict[str, list] = {}
    for p in pads:
        by_link.setdefault(p.link, []).append(p)
    return by_link


def _link_cores(by_link: dict, meshes: dict) -> dict[str, list]:
    """Link name -> rigid-core pieces, from the link's pads and pad mesh."""
    from ..tactile import pad_core_meshes

    return {link: pad_core_meshes(specs, meshes[link], mesh_name=f"the collision mesh of {link!r}")
            for link, specs in by_link.items()}


def _check_pad_links(agent_uid: str, urdf: str, pads: Sequence[PadSpec]) -> None:
    if not os.path.isfile(urdf):
        raise AssetError(f"{urdf}: URDF of agent {agent_uid!r} not found (GaussTacAgent.gausstac_urdf)")
    names = link_names(urdf)
    for p in pads:
        if p.link not in names:
            near = difflib.get_close_matches(p.link, names, n=3)
            hint = f"; did you mean {near}?" if near else ""
            raise ConfigError(f"pad link {p.link!r} is not a link of agent {agent_uid!r} ({urdf}){hint} "
                              f"Links: {names}")
    pad_names = [p.name for p in pads]
    if len(set(pad_names)) != len(pad_names):
        raise ConfigError(f"agent {agent_uid!r}: pad names must be unique, got {pad_names}")


def add_gausstac_pads(agent: str | type, pad_links: Sequence[str] | Mapping[str, str], *,
                      uid: str | None = None, urdf: str | None = None, gaussians: str | None = None,
                      axes: Mapping[str, Sequence[float]] | None = None,
                      per_link: Mapping[str, Mapping] | None = None, register: bool = True,
                      optical=None, **pad_fields) -> type:
    """A new agent class: ``agent`` (a registered uid or an agent class) with soft pads.

    Args:
        agent: the ManiSkill hand agent, e.g. ``"floating_ability_hand_right"``.
        pad_links: link names that get a pad, or ``{pad name: link name}``.
        uid: uid of the new agent (default ``<agent uid>_gausstac``).
        urdf: URDF with the collision meshes of the pad links (default: the agent's).
        gaussians: optional folder with the hand's ``gaussians.ply`` and ``links.json``.
        axes: per-link outward pad direction in the link frame (default ``pad_fields["axis"]``
            or +x).
        per_link: other :class:`PadSpec` fields per link (e.g. ``{"thumb_L2": {"cone_deg": 30}}``),
            overriding ``pad_fields``.
        register: register the class with ManiSkill under ``uid``.
        optical: optical sensors on the pads (``"gelsight_mini"`` for every pad, or ``{pad name:
            preset}``): their ``obs["tactile"][pad]`` gain ``"rgb"`` and ``"markers"`` in every
            task (:class:`~gausstac_maniskill.tasks.base.GaussTacEnv`'s ``optical``).
        pad_fields: other :class:`PadSpec` fields shared by all pads (``thickness``, ``cone_deg``,
            ``material``, ``layout``).

    Raises:
        ConfigError: unknown agent uid, a link the agent's URDF does not have, duplicate names.
    """
    if isinstance(agent, str):
        if agent not in REGISTERED_AGENTS:
            near = difflib.get_close_matches(agent, list(REGISTERED_AGENTS), n=3)
            raise ConfigError(f"add_gausstac_pads: no registered ManiSkill agent {agent!r}"
                              + (f"; did you mean {near}?" if near else ""))
        base = REGISTERED_AGENTS[agent].agent_cls
    elif isinstance(agent, type) and issubclass(agent, BaseAgent):
        base = agent
    else:
        raise ConfigError(f"add_gausstac_pads: agent must be a registered uid or a BaseAgent class, got {agent!r}")
    if isinstance(pad_links, str) or not pad_links:
        raise ConfigError(f"add_gausstac_pads: pad_links must be a non-empty list of link names, got {pad_links!r}")
    named = dict(pad_links) if isinstance(pad_links, Mapping) else {link: link for link in pad_links}
    axes, per_link = dict(axes or {}), dict(per_link or {})
    stray = sorted(set(axes) - set(named.values())) + sorted(set(per_link) - set(named.values()))
    if stray:
        raise ConfigError(f"add_gausstac_pads: axes/per_link name links without a pad: {stray}; "
                          f"pad links: {sorted(named.values())}")
    pads = []
    for name, link in named.items():
        fields = dict(pad_fields)
        if link in axes:
            fields["axis"] = tuple(axes[link])
        fields.update(per_link.get(link, {}))
        try:
            pads.append(PadSpec(link=link, name=name, **fields))
        except TypeError as e:
            raise ConfigError(f"add_gausstac_pads: pad {name!r} on {link!r}: {e}") from None
    new_uid = uid or f"{base.uid}_gausstac"
    pad_urdf = urdf or base.urdf_path
    _check_pad_links(base.uid, pad_urdf, pads)
    cls = type(base.__name__ + "GaussTac", (GaussTacAgent, base), {
        "uid": new_uid, "gausstac_pads": tuple(pads), "gausstac_urdf": pad_urdf, "gausstac_gaussians": gaussians,
        "gausstac_optical": check_optical(f"add_gausstac_pads({new_uid!r})", optical, 320) or None,
        "__doc__": f"ManiSkill agent {base.uid!r} with GaussTac pads on {list(named.values())}.",
        "__module__": __name__,
    })
    if register:
        register_agent(override=True)(cls)
    return cls
