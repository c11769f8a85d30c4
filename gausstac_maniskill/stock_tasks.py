"""Touch for ManiSkill's own tasks: :func:`make_tactile` turns a registered ManiSkill task into the
same task with GaussTac pads on its hand.

The task keeps its scene, reward, success, control modes, cameras and ``max_episode_steps``. Its
hand becomes the agent's GaussTac twin (the same agent class with pads added by link name:
:func:`twin_agent`), and the observations gain ``obs["tactile"]``. The mechanism is the GaussTac
tasks' own (:class:`~gausstac_maniskill.tasks.base.GaussTacEnv`): the new class puts
:class:`StockTask` and ``GaussTacEnv`` in front of the stock task class, so ManiSkill's hooks run
the task's code and the pads' around it. What the pads feel is read from the task's scene: every
actor and articulation link other than the hand, one collider per collision shape (boxes,
spheres, capsules and planes exactly, other shapes as signed distance fields of their meshes);
dynamic actors take the pads' reaction (``two_way``). Units: SI.
"""
from __future__ import annotations

import difflib
import warnings

import numpy as np

from .errors import ConfigError, SimulationWarning

__all__ = ["make_tactile", "twin_agent", "hands_with_pads", "StockTask"]

#: a mesh collider's SDF box is built over its bounds: larger static meshes (a room, a table
#: top given as a mesh) are left out of what the pads feel [m, diagonal of the bounding box]
MAX_MESH_EXTENT = 0.5


def hands_with_pads() -> dict[str, str]:
    """``{stock agent uid: its GaussTac twin's uid}``: the ManiSkill hands that have a twin with
    pads (an agent class made of :class:`~gausstac_maniskill.agents.GaussTacAgent` and the stock
    agent, as :func:`~gausstac_maniskill.agents.add_gausstac_pads` makes)."""
    return {twin.__bases__[-1].uid: twin.uid for twin in _twin_classes()}


def _twin_classes() -> list[type]:
    """Every agent class with pads whose last base is a stock ManiSkill agent: the registered
    ones and the shipped twins of the stock tasks' hands."""
    from mani_skill.agents.registration import REGISTERED_AGENTS

    from .agents import GaussTacAgent, dclaw, trifinger

    found = {e.agent_cls for e in REGISTERED_AGENTS.values() if issubclass(e.agent_cls, GaussTacAgent)}
    found |= {c for c in (dclaw.DClawGaussTac, trifinger.TriFingerProGaussTac) if c is not None}  # None: no asset
    return sorted((c for c in found if c.gausstac_pads and not issubclass(c.__bases__[-1], GaussTacAgent)),
                  key=lambda c: c.uid)


def twin_agent(uid) -> type:
    """The GaussTac twin (agent class with pads) of ManiSkill agent ``uid``: an agent that has
    pads is its own twin.

    Raises:
        ConfigError: no agent with pads derives from it; the message lists the hands that have.
    """
    from mani_skill.agents.registration import REGISTERED_AGENTS

    from .agents import GaussTacAgent

    if isinstance(uid, type):
        cls = uid
    elif isinstance(uid, str) and uid in REGISTERED_AGENTS:
        cls = REGISTERED_AGENTS[uid].agent_cls
    else:
        raise ConfigError(f"make_tactile: the task's robot {uid!r} is not a registered ManiSkill agent; hands "
                          f"with GaussTac pads: {sorted(hands_with_pads())}")
    if issubclass(cls, GaussTacAgent) and cls.gausstac_pads:
        return cls
    for twin in _twin_classes():  # every one has pads
        if twin.__bases__[-1] is cls:
            return twin
    have = hands_with_pads()
    near = difflib.get_close_matches(str(getattr(cls, "uid", uid)), list(have), n=2)
    raise ConfigError(f"make_tactile: the task's robot {getattr(cls, 'uid', uid)!r} has no GaussTac pads; hands "
                      f"with pads: {sorted(have)}" + (f" (closest: {near})" if near else "")
                      + ". Give it pads with gausstac_maniskill.agents.add_gausstac_pads(uid, links, ...)")


class StockTask:
    """What a stock ManiSkill task needs on top of :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`
    (put first: ``type(name, (StockTask, GaussTacEnv, Task), {})``): its own robot swapped for the
    twin, its own scene, cameras and ground, and colliders for what the pads touch."""

    ground_altitude = None  # the task builds its own ground
    #: pads feel the task's dynamic actors both ways (their reaction pushes the object)
    stock_two_way = True

    def __init__(self, *args, camera: str | None = None, **kwargs):
        self._stock_camera = camera
        super().__init__(*args, robot_uids=None, camera="sapien" if camera is None else camera, **kwargs)

    def _stock(self):
        """``super()`` from the stock task's side: the hooks of the task itself."""
        from .tasks.base import GaussTacEnv

        return super(GaussTacEnv, self)

    def _load_agent(self, options: dict, initial_agent_poses=None, *args, **kwargs):
        stock = self.robot_uids
        self.robot_uids = twin_agent(stock)  # ManiSkill builds an agent given as a class
        try:
            super()._load_agent(options, initial_agent_poses, *args, **kwargs)
        finally:
            self.robot_uids = stock  # the task's scene code reads its own uid ("dclaw" in robot_uids ...)

    def _load_scene(self, options: dict):
        self._stock()._load_scene(options)
        self._register_scene_colliders()

    def _stock_sensor_configs(self) -> list:
        """The stock task's sensor configs, as a list (ManiSkill allows one config alone)."""
        configs = self._stock()._default_sensor_configs
        return list(configs) if isinstance(configs, (list, tuple)) else [configs]

    @property
    def _default_sensor_configs(self):
        configs = self._stock_sensor_configs()
        if self._stock_camera == "splat":
            configs.append(self._camera_config("splat_camera", self.splat_size))
        return configs

    @property
    def _default_human_render_camera_configs(self):
        return self._stock()._default_human_render_camera_configs

    def _splat_camera_pose(self):
        configs = self._stock_sensor_configs()
        return configs[0].pose if configs else super()._splat_camera_pose()

    def _register_scene_colliders(self) -> None:
        """One MPM rigid object per collision shape of every actor and articulation link of the
        scene other than the hand's (env 0's shapes: ``physx_cpu`` runs one env)."""
        bodies = list(self.scene.actors.items())
        for art_name, art in self.scene.articulations.items():
            if art is not self.agent.robot:
                bodies += [(f"{art_name}/{link.name}", link) for link in art.links]
        for name, body in bodies:
            comp = _rigid_component(body)
            if comp is None:
                continue
            dynamic = getattr(body, "px_body_type", "static") == "dynamic"
            for i, shape in enumerate(comp.collision_shapes):
                made = _collider(shape, f"{name}/{i}")
                if made is None:
                    continue
                collider, offset = made
                self.add_mpm_rigid(f"{name}/{i}", body, collider, offset=offset,
                                   two_way=dynamic and self.stock_two_way and hasattr(body, "_bodies"))


def _rigid_component(body):
    """The physx rigid component of env 0's entity of a ManiSkill actor or link (None: none)."""
    import sapien

    obj = body._objs[0]
    if isinstance(obj, sapien.physx.PhysxRigidBaseComponent):
        return obj
    return obj.find_component_by_type(sapien.physx.PhysxRigidBaseComponent)


#: PhysX capsules and planes lie along their local x axis, ours along z: the collider's frame
#: in the shape's (a quarter turn about y takes z to x)
_Z_TO_X = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def _collider(shape, name: str):
    """(collider, its pose in the body frame [4, 4]) for a PhysX collision shape, or None for a
    mesh too large to sample (:data:`MAX_MESH_EXTENT`, with a warning)."""
    import sapien

    from .geometry import Box, Capsule, HalfSpace, MeshCollider, Sphere
    from .transforms import make_pose, quat_to_matrix

    px = sapien.physx
    pose = shape.local_pose
    offset = make_pose(np.asarray(pose.p, np.float64), quat_to_matrix(np.asarray(pose.q, np.float64)))
    mat = shape.physical_material
    friction = float(mat.dynamic_friction) if mat is not None else 0.5
    if isinstance(shape, px.PhysxCollisionShapeBox):
        return Box(half_extents=tuple(float(h) for h in shape.half_size), friction=friction, name=name), offset
    if isinstance(shape, px.PhysxCollisionShapeSphere):
        return Sphere(radius=float(shape.radius), friction=friction, name=name), offset
    if isinstance(shape, px.PhysxCollisionShapeCapsule):
        return (Capsule(radius=float(shape.radius), half_length=float(shape.half_length), friction=friction,
                        name=name), offset @ _Z_TO_X)
    if isinstance(shape, px.PhysxCollisionShapePlane):
        return HalfSpace(friction=friction, name=name), offset @ _Z_TO_X
    mesh = _shape_mesh(shape)
    if mesh is None:
        return None
    extent = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    if extent > MAX_MESH_EXTENT:
        warnings.warn(f"make_tactile: {name} is a mesh {extent:.2f} m across (over {MAX_MESH_EXTENT} m): the pads "
                      f"do not feel it", SimulationWarning, stacklevel=4)
        return None
    return MeshCollider(mesh=mesh, friction=friction, name=name), offset


def _shape_mesh(shape):
    """A PhysX mesh-like shape as a trimesh in the shape's frame (scale applied), or None."""
    import sapien
    import trimesh

    px = sapien.physx
    if isinstance(shape, (px.PhysxCollisionShapeConvexMesh, px.PhysxCollisionShapeTriangleMesh)):
        v = np.asarray(shape.vertices, np.float64) * np.asarray(shape.scale, np.float64)
        f = np.asarray(shape.triangles)
        mesh = trimesh.Trimesh(v, f, process=True)
        return mesh if isinstance(shape, px.PhysxCollisionShapeTriangleMesh) else mesh.convex_hull
    if isinstance(shape, px.PhysxCollisionShapeCylinder):
        c = trimesh.creation.cylinder(radius=float(shape.radius), height=2.0 * float(shape.half_length))
        c.apply_transform(_Z_TO_X)  # PhysX cylinders lie along x
        return c
    return None


def make_tactile(env_id: str, **kwargs):
    """``gym.make(env_id, **kwargs)`` with GaussTac pads on the task's hand.

    ``env_id`` is a registered ManiSkill task (``"RotateSingleObjectInHandLevel0-v1"``,
    ``"RotateValveLevel0-v1"``, ``"TriFingerRotateCubeLevel0-v1"``, ...). ``kwargs`` are
    ``gym.make``'s and the task's, plus the GaussTac options of
    :class:`~gausstac_maniskill.tasks.base.GaussTacEnv` (``mpm_dx``, ``pad_solver``, ...);
    ``camera="splat"`` adds the splat camera to the task's own cameras. A GaussTac task is made
    as it is.

    Raises:
        ConfigError: ``env_id`` is not registered, or its robot has no GaussTac twin (the
            message lists the hands that have pads).
    """
    import gymnasium as gym
    from mani_skill.utils.registration import REGISTERED_ENVS

    from ._registry import register_with_maniskill

    register_with_maniskill()
    if env_id not in REGISTERED_ENVS:
        near = difflib.get_close_matches(env_id, list(REGISTERED_ENVS), n=3)
        raise ConfigError(f"make_tactile: no registered ManiSkill task {env_id!r}"
                          + (f"; did you mean {near}?" if near else ""))
    from .tasks.base import GaussTacEnv

    spec = REGISTERED_ENVS[env_id]
    if issubclass(spec.cls, GaussTacEnv):
        return gym.make(env_id, **kwargs)
    cls = tactile_class(spec.cls)
    tactile_id = f"GaussTac/{env_id}"
    if tactile_id not in gym.registry:
        _register(tactile_id, cls, spec)
    return gym.make(tactile_id, **kwargs)


def tactile_class(task: type) -> type:
    """The class of ``task`` with GaussTac pads (built once per task class)."""
    from .tasks.base import GaussTacEnv

    cached = _CLASSES.get(task)
    if cached is None:
        cached = _CLASSES[task] = type(f"Tactile{task.__name__}", (StockTask, GaussTacEnv, task), {
            "SUPPORTED_ROBOTS": None, "__module__": __name__,
            "__doc__": f"ManiSkill's {task.__name__} with GaussTac pads on its hand (make_tactile)."})
    return cached


_CLASSES: dict[type, type] = {}


def _register(tactile_id: str, cls: type, spec) -> None:
    """Register ``cls`` with ManiSkill and gymnasium under ``tactile_id``, with the stock
    task's episode length and default kwargs."""
    from mani_skill.utils.registration import register_env

    register_env(tactile_id, max_episode_steps=spec.max_episode_steps, override=True,
                 asset_download_ids=list(spec.asset_download_ids or []), **dict(spec.default_kwargs or {}))(cls)
