"""The helpers notebook figures rely on to say what they show: slot ownership, lost objects,
slot titles, the camera projection of arena points."""
import numpy as np
import pytest

from ncs_lite.figures import arena_to_pixel, slot_titles
from ncs_lite.metrics import lost_in_reconstruction, slot_assignment


def two_objects():
    true = np.zeros((1, 2, 8, 8), bool)
    true[0, 0, :2, :2] = True          # object 0 top-left
    true[0, 1, 6:, 6:] = True          # object 1 bottom-right
    return true


def test_slot_assignment_owner_and_floor():
    true = two_objects()
    pred = np.zeros((1, 3, 8, 8))
    pred[0, 2] = 1.0                   # slot 2: the floor ...
    pred[0, 0, :2, :2] = 2.0           # slot 0 wins object 0
    pred[0, 2, 6:, 6:] = 3.0           # ... and also object 1 (absorbed)
    owner, background = slot_assignment(pred, true)
    assert owner.tolist() == [[0, 2]] and background.tolist() == [2]
    assert slot_titles(owner[0], background[0], 3, ["red", "green"]) == ["red", "-", "floor+green"]
    with pytest.raises(ValueError, match="masks must have shapes"):
        slot_assignment(pred[0], true)


def test_lost_in_reconstruction():
    true = two_objects()
    image = np.full((1, 8, 8, 3), 0.3)
    image[0, :2, :2] = (1.0, 0.0, 0.0)
    image[0, 6:, 6:] = (0.0, 1.0, 0.0)
    recon = image.copy()
    recon[0, 6:, 6:] = 0.32            # object 1 painted as floor
    assert lost_in_reconstruction(recon, image, true).tolist() == [[False, True]]
    assert not lost_in_reconstruction(image, image, true).any()


def test_arena_to_pixel_lands_on_the_cube():
    from ncs_lite.envs import make

    env = make("block-rearrange", num_objects=4)
    try:
        _, info = env.reset(seed=3)
        pix = arena_to_pixel(env, info["positions"][:, :2])           # (k, 2) = (column, row)
        for o, (col, row) in enumerate(pix):
            rows, cols = np.nonzero(info["masks"][o])
            assert abs(cols.mean() - col) < 1.5 and abs(rows.mean() - row) < 1.5
    finally:
        env.close()


def test_a_figure_record_names_no_absolute_path_of_the_repo(tmp_path, monkeypatch):
    import json

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ncs_lite import figures
    from ncs_lite.utils import REPO_DIR

    monkeypatch.setenv("NCS_LITE_FIGURES", str(tmp_path))
    fig = plt.figure()
    png = figures.save_fig(fig, "nb", "f", {"checkpoint": str(REPO_DIR / "ncs_lite" / "assets" / "x.pt"),
                                            "runs": [REPO_DIR / ".cache" / "r"], "outside": "/elsewhere/y"})
    plt.close(fig)
    params = json.loads(png.with_suffix(".json").read_text())["params"]
    assert params == {"checkpoint": "ncs_lite/assets/x.pt", "runs": [".cache/r"], "outside": "/elsewhere/y"}
