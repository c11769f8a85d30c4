"""A scene's state (:class:`SceneState`, part of :class:`~.scene.GaussTacSim`): its MPM world's
part, link poses, which pads are awake and what the pad solvers keep (the equilibrium pads' last
solutions), as a nested dict or as flat fixed-shape arrays that stack along a batch axis."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import ConfigError


class SceneState:
    """The state of a :class:`~.scene.GaussTacSim` (a part of it)."""

    @property
    def _state_env(self):
        """The env whose part of the world is this scene's state (None: the whole world)."""
        return self.env if self.shared else None

    def state_dict(self) -> dict:
        """Full state (MPM world, link poses, sleep flags); restore with :meth:`load_state_dict`.
        In a shared world, this env's part only: it loads into the same scene alone and back."""
        state = {"world": self.world.state_dict(env=self._state_env),
                 "link_pose": {k: v.copy() for k, v in self._link_pose.items()},
                 "awake": {name: self.is_awake(name) for name in self.pads}}
        for solver in self.solvers.values():  # what the world does not hold (the equilibrium pads' solutions)
            own = solver.state()
            if own:
                state[solver.kind] = own
        return state

    def flat_state(self) -> dict[str, np.ndarray]:
        """The state of :meth:`state_dict` as a flat dict of fixed-shape numpy arrays
        (no ``None``, no nesting), so that several identical scenes stack along a batch
        axis — the form ManiSkill's ``get_state_dict`` and ``RecordEpisode`` store. Pads
        solved at equilibrium add their last solution as ``fem{i}_*`` (i: the pad's index in
        :attr:`pads`; :meth:`EquilibriumPad.flat_state`)."""
        w = self.world.state_dict(env=self._state_env)
        out = {f"p_{k}": v for k, v in w["particles"].items()}
        n_groups = len(w["awake"])
        sleep = np.tile(np.eye(4), (n_groups, 1, 1))
        has_sleep = np.zeros(n_groups, bool)
        for i, T in enumerate(w["sleep_pose"]):
            if T is not None:
                sleep[i], has_sleep[i] = T, True
        out.update(
            link_prev=np.asarray(w["link_prev"], np.float64).reshape(-1, 4, 4),
            link_next=np.asarray(w["link_next"], np.float64).reshape(-1, 4, 4),
            link_twist=np.asarray(w["link_twist"], np.float64).reshape(-1, 6),
            collider_prev=np.asarray(w["collider_prev"], np.float64).reshape(-1, 4, 4),
            collider_pose=np.asarray(w["collider_pose"], np.float64).reshape(-1, 4, 4),
            collider_impulse=np.asarray(w["collider_impulse"], np.float64),
            pair_impulse=np.asarray(w["pair_impulse"], np.float64),
            group_awake=np.asarray(w["awake"], bool), group_sleep_pose=sleep, group_has_sleep_pose=has_sleep,
            scalars=np.array([w["time"], w["step_count"], w["vmax"], w["last_dt_ctrl"]], np.float64),
            link_pose=np.stack([self._link_pose[k] for k in sorted(self._link_pose)]),
            pad_awake=np.array([self.is_awake(k) for k in self.pads], bool),
        )
        for solver in self.solvers.values():
            out.update(solver.flat_state())
        return out

    def load_flat_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a :meth:`flat_state` of a scene built the same way (bit-exact)."""
        names = sorted(self._link_pose)
        if len(state["link_pose"]) != len(names):
            raise ConfigError(f"load_flat_state: state has {len(state['link_pose'])} link poses, this scene "
                              f"tracks {len(names)} links ({names})")
        sc = np.asarray(state["scalars"], np.float64)
        world = {
            "particles": {k[2:]: np.asarray(v) for k, v in state.items() if k.startswith("p_")},
            "link_prev": list(np.asarray(state["link_prev"], np.float64)),
            "link_next": list(np.asarray(state["link_next"], np.float64)),
            "link_twist": list(np.asarray(state["link_twist"], np.float64)) if "link_twist" in state else None,
            "collider_prev": list(np.asarray(state["collider_prev"], np.float64)),
            "collider_pose": list(np.asarray(state["collider_pose"], np.float64)),
            "collider_impulse": np.asarray(state["collider_impulse"], np.float64),
            **{k: np.asarray(state[k], np.float64) for k in ("pair_impulse", "link_impulse") if k in state},
            "awake": np.asarray(state["group_awake"], bool),
            "sleep_pose": [np.asarray(T, np.float64) if h else None
                           for T, h in zip(state["group_sleep_pose"], state["group_has_sleep_pose"])],
            "time": float(sc[0]), "step_count": int(sc[1]), "vmax": float(sc[2]), "last_dt_ctrl": float(sc[3]),
        }
        self.load_state_dict({"world": world,
                              "link_pose": {k: np.asarray(T, np.float64) for k, T in zip(names, state["link_pose"])},
                              "awake": {k: bool(a) for k, a in zip(self.pads, state["pad_awake"])}})
        for solver in self.solvers.values():
            solver.load_flat_state(state)

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` of a scene built the same way (bit-exact)."""
        self.world.load_state_dict(state["world"], env=self._state_env)
        self._link_pose = {k: v.copy() for k, v in state["link_pose"].items()}
        for solver in self.solvers.values():
            solver.awake.update({name: state["awake"][name] for name in solver.names})
            solver.load_state(state.get(solver.kind, {}))
        self._maps = {}
        self._posed = None
