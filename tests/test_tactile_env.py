"""The mechanism shared by the tasks: copies of observations, the state dict's task part and its
round trip, the pads' contacts per link and object, and the implicit reaction's bookkeeping
(fakes in place of the co-simulator, drives and springs: no env is built)."""
import numpy as np
import torch

from gausstac_maniskill.tactile_env import (batch_state, copied, fold_pad_reaction, load_flat_states, pad_contacts,
                                            split_task_state, stacked_flat_states, task_state_leaves)


def test_copied_shares_no_memory_and_keeps_other_leaves():
    tree = {"a": torch.zeros(2), "b": {"c": np.zeros(3)}, "d": 1}
    out = copied(tree)
    out["a"] += 1
    out["b"]["c"] += 1
    assert tree["a"].sum() == 0 and tree["b"]["c"].sum() == 0 and out["d"] == 1


def test_batch_state_adds_the_env_axis_to_a_one_env_state_only():
    one = {"articulations": {"hand": torch.zeros(5)}, "task": {"t": torch.zeros(1)}}
    out = batch_state(one)
    assert out["articulations"]["hand"].shape == (1, 5) and out["task"]["t"].shape == (1, 1)
    batched = {"articulations": {"hand": torch.zeros(2, 5)}}
    assert batch_state(batched) is batched


def test_task_state_round_trip_keeps_shapes_and_rows():
    task = {"target": torch.tensor([1.0, 2.0]), "goal": torch.ones(2, 3)}
    wrench = {"cube": np.arange(12.0).reshape(2, 6)}
    contacts = np.arange(2 * 1 * 2 * 7, dtype=np.float64).reshape(2, 1, 2, 7)
    leaves = task_state_leaves(task, wrench, contacts, 2)
    assert leaves["target"].shape == (2, 1) and leaves["wrench_cube"].dtype == torch.float64
    assert leaves["pad_contacts"].shape == (2, 14)
    assert task_state_leaves({}, {}, np.zeros((0, 0, 1, 7)), 2) == {}
    rows = torch.tensor([1])
    back, w, c = split_task_state(leaves, rows, 2, lambda: task)
    assert back["target"].tolist() == [2.0] and back["goal"].shape == (1, 3)
    assert w["cube"].tolist() == [wrench["cube"][1].tolist()]
    np.testing.assert_array_equal(c.numpy(), contacts[1:].reshape(1, -1))


class _Sim:
    def __init__(self, contacts=None, flat=None):
        self.contacts, self.flat, self.loaded = contacts or {}, flat, None

    def link_contacts(self, link):
        return self.contacts.get(link, {})

    def flat_state(self):
        return self.flat

    def load_flat_state(self, flat):
        self.loaded = flat


def test_pad_contacts_sorts_rows_by_object_with_soft_objects_last():
    row = np.arange(7.0)
    sim = _Sim({"tip": {"cube": row, "sponge": 2 * row, "jelly": row}})
    out = pad_contacts(sim, ["base", "tip"], ["cube"])
    assert out.shape == (2, 2, 7) and not out[0].any()
    np.testing.assert_array_equal(out[1, 0], row)
    np.testing.assert_array_equal(out[1, 1], 3 * row)  # every soft object in the last column


def test_flat_states_stack_and_load_back_per_row():
    sims = [_Sim(flat={"x": np.full(3, float(b))}) for b in range(3)]
    flat = stacked_flat_states(sims)
    assert flat["x"].shape == (3, 3)
    load_flat_states(sims, flat, torch.tensor([2]), 3)
    assert sims[2].loaded["x"].tolist() == [2.0] * 3 and sims[0].loaded is None
    load_flat_states(sims, {"x": flat["x"][[1]]}, torch.tensor([0]), 3)  # one row per env set
    assert sims[0].loaded["x"].tolist() == [1.0] * 3


def test_fold_pad_reaction_folds_every_env_and_takes_the_springs_share():
    folded = []

    class Hand:
        links = ["L0"]

        def fold(self, contacts, friction):
            folded.append(contacts.shape)

    class Spring:
        def take(self, rows, mu):
            assert len(rows) == 1 and rows[0][1] == "L0" and mu == 0.5
            return np.ones(6)

    contacts = np.zeros((2, 1, 3, 7))
    obj_w = {"cube": np.zeros((2, 6)), "ball": np.zeros((2, 6))}
    fold_pad_reaction(contacts, np.array([0.5, 0.3, 0.1]), [Hand(), Hand()], [[Spring(), None], [None, None]],
                      ["cube", "ball"], obj_w)
    assert folded == [(1, 3, 7), (1, 3, 7)]
    assert obj_w["cube"][0].tolist() == [-1.0] * 6 and not obj_w["cube"][1].any() and not obj_w["ball"].any()
