"""The hand Gaussians folder's reader (``splat.asset``): what it returns for the shipped
Allegro asset, and the errors that name the file and the field."""
from __future__ import annotations

import json
import shutil

import pytest

from gausstac_maniskill.errors import AssetError
from gausstac_maniskill.splat.asset import load_hand_closed_links, load_hand_gaussians, load_hand_lod


def test_shipped_allegro_folder():
    """Fine, 2.5 mm and 3 mm levels with the same link names, and every link closed (the
    meshes' closedness itself is checked in test_build.py)."""
    from gausstac_maniskill.demo import ASSET_DIR

    hand, names = load_hand_gaussians(str(ASSET_DIR))
    fine, levels = load_hand_lod(str(ASSET_DIR))
    assert len(names) == 21 and int(hand.link_id.max()) == 20
    assert fine == 0.002 and [s for s, _ in levels] == [0.0025, 0.003]
    assert all(int(g.link_id.max()) == 20 for _, g in levels)
    assert len(hand) > len(levels[0][1]) > len(levels[1][1])
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


def test_levels_of_detail_read_and_refused(tmp_path):
    """``levels`` must grow in spacing and name files that exist (errors name links.json and the
    field, or the missing file); an older folder's single ``coarse`` entry reads as one level."""
    from gausstac_maniskill.demo import ASSET_DIR

    info = json.loads((ASSET_DIR / "links.json").read_text())
    three = info["levels"][1]
    cases = {"shrinking": ({"levels": [three, info["levels"][0]]}, "must grow from level to level"),
             "missing": ({"levels": [dict(three, file="nowhere.ply")]}, "nowhere.ply: hand Gaussians file"),
             "unsized": ({"levels": [{"file": three["file"]}]}, "needs 'file' and 'spacing'"),
             "empty": ({"levels": []}, "non-empty list"),
             "legacy": ({"coarse": three}, None)}
    for name, (entry, match) in cases.items():
        folder = tmp_path / name
        folder.mkdir()
        for f in ("gaussians.ply", three["file"]):
            shutil.copy(ASSET_DIR / f, folder / f)
        meta = {k: v for k, v in info.items() if k != "levels"}
        (folder / "links.json").write_text(json.dumps(dict(meta, **entry)))
        if match is None:
            fine, levels = load_hand_lod(str(folder))
            assert fine == 0.002 and len(levels) == 1 and levels[0][0] == 0.003
        else:
            with pytest.raises(AssetError, match=match):
                load_hand_lod(str(folder))
