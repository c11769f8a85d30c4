"""The hand Gaussians folder's reader (``splat.asset``): what it returns for the shipped
Allegro asset, and the errors that name the file and the field."""
from __future__ import annotations

import json
import shutil

import pytest

from gausstac_maniskill.errors import AssetError
from gausstac_maniskill.splat.asset import load_hand_closed_links, load_hand_gaussians, load_hand_lod


def test_shipped_allegro_folder():
    """Fine and coarse levels with the same link names, and every link closed (the meshes'
    closedness itself is checked in test_build.py)."""
    from gausstac_maniskill.demo import ASSET_DIR

    hand, names = load_hand_gaussians(str(ASSET_DIR))
    fine, coarse, coarse_set = load_hand_lod(str(ASSET_DIR))
    assert len(names) == 21 and int(hand.link_id.max()) == 20 == int(coarse_set.link_id.max())
    assert fine < coarse and len(coarse_set) < len(hand)
    assert load_hand_closed_links(str(ASSET_DIR)) == tuple(names)


def test_bad_closed_links_name_the_file(tmp_path):
    from gausstac_maniskill.demo import ASSET_DIR

    for bad, match in (("link_3.0", "must be a list"), (["no_such_link"], "not in link_names")):
        folder = tmp_path / str(len(match))
        folder.mkdir()
        shutil.copy(ASSET_DIR / "gaussians.ply", folder / "gaussians.ply")
        info = json.loads((ASSET_DIR / "links.json").read_text())
        info["closed_links"] = bad
        (folder / "links.json").write_text(json.dumps(info))
        with pytest.raises(AssetError, match=rf"{folder / 'links.json'}.*{match}"):
            load_hand_closed_links(str(folder))
