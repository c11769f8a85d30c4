"""The packaged example capture: small, regenerated bit-for-bit (to float rounding), placed
under the hand by EXAMPLE_PLACEMENT."""
import warnings

import torch

from gausstac_maniskill.errors import AssetWarning
from gausstac_maniskill.splat import load_capture, load_ply
from gausstac_maniskill.splat.example_scene import (EXAMPLE_PLACEMENT, EXAMPLE_SCENE, TABLE_Z, build_example_scene,
                                                    write_example_scene)


def test_shipped_capture_is_small_plain_inria_and_regenerates(tmp_path):
    assert EXAMPLE_SCENE.is_file() and EXAMPLE_SCENE.stat().st_size < 1_000_000
    shipped = load_ply(EXAMPLE_SCENE)
    assert shipped.sh_degree == 1 and 5_000 < len(shipped) < 10_000
    assert not shipped.has_labels()  # a plain INRIA file, as other tools write them
    again = load_ply(write_example_scene(tmp_path / "again.ply"))
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert torch.allclose(getattr(again, name), getattr(shipped, name), atol=1e-5), name


def test_placed_capture_is_the_world_scene_with_the_table_under_the_hand():
    with warnings.catch_warnings():
        warnings.simplefilter("error", AssetWarning)  # a well-made capture loads silently
        placed = load_capture(EXAMPLE_SCENE, EXAMPLE_PLACEMENT)
    world = build_example_scene()
    assert torch.allclose(placed.means, world.means, atol=1e-5)
    assert torch.allclose(placed.covariances(), world.covariances(), atol=1e-9)
    assert torch.allclose(placed.sh, world.sh, atol=1e-4)  # the sheen's SH rotated back to the world
    sheen = placed.sh[:, 1:].abs().amax(dim=(1, 2)) > 1e-6  # the table's Gaussians, and only they
    assert sheen.sum() > 3000
    assert torch.allclose(placed.means[sheen, 2], torch.tensor(TABLE_Z), atol=1e-5)
