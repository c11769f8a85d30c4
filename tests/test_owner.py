"""owner.Owner: a part reads its owner back without keeping it alive (no reference cycle)."""
import gc
import weakref

import pytest

from gausstac_maniskill.errors import GaussTacError
from gausstac_maniskill.owner import Owner


class Part:
    scene = Owner()

    def __init__(self, scene):
        self.scene = scene


class Scene:
    def __init__(self):
        self.part = Part(self)


def test_the_part_reads_its_owner_and_the_owner_is_freed_without_the_cyclic_collector():
    gc.disable()
    try:
        scene = Scene()
        part, alive = scene.part, weakref.ref(scene)
        assert part.scene is scene
        del scene
        assert alive() is None  # freed by reference counting alone: no cycle
        with pytest.raises(GaussTacError, match="Part.scene: the object that owned it was deleted"):
            part.scene
    finally:
        gc.enable()


def test_an_owner_without_weak_references_is_held_strongly():
    part = Part((1, 2))  # a tuple allows no weak reference
    assert part.scene == (1, 2)
    assert isinstance(Part.__dict__["scene"], Owner) and Part.scene is Part.__dict__["scene"]
