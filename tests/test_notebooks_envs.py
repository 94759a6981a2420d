"""Notebooks 04-07 on robogym-rearrange: the library helpers they read the env
through, and each notebook run end to end with `env = "robogym-rearrange"` at `ci`.

nbmake runs every notebook at its default env (block-rearrange); papermill injects the
other one here, as `make reproduce` does."""
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
ENV_NOTEBOOKS = ("04_dslate_training", "05_graph_construction", "06_action_selection", "07_baselines")


def test_colour_names_use_each_envs_palette():
    from ncs_lite.envs import colour_names, palette

    names, rgb = palette("robogym-rearrange")
    assert colour_names("robogym-rearrange", rgb[[8, 12, 0]]) == ["black", "pink", "red"]
    names, rgb = palette("block-rearrange")
    assert colour_names("block-rearrange", rgb[[1, 7]] + 0.01) == ["green", "white"]
    # black is robogym-rearrange's own: block-rearrange's palette has no such colour
    assert colour_names("robogym-rearrange", np.full((1, 3), 0.1)) == ["black"]
    assert colour_names("block-rearrange", np.full((1, 3), 0.1)) != ["black"]
    with pytest.raises(ValueError, match="unknown environment 'stacking'"):
        palette("stacking")
    with pytest.raises(ValueError, match=r"colors must have shape \(k, 3\), got \(3,\)"):
        colour_names("block-rearrange", [0.1, 0.2, 0.3])


@pytest.mark.parametrize("env", ["block-rearrange", "robogym-rearrange"])
def test_obtain_dslate_loads_the_envs_shipped_checkpoint(env):
    """At `reduced` each env gets its own shipped checkpoint (robogym-rearrange once got
    block-rearrange's)."""
    from ncs_lite.inference import shipped_asset
    from ncs_lite.training import obtain_dslate

    try:
        path = shipped_asset(env, "ncs", "model")
    except FileNotFoundError:
        pytest.skip(f"the shipped {env} checkpoint is not present")
    model, got = obtain_dslate("reduced", env=env)
    assert got == path and model.checkpoint_info["env"] == env


@pytest.mark.parametrize("name", ENV_NOTEBOOKS)
def test_notebook_runs_on_robogym(name, tmp_path, monkeypatch):
    """The notebook at `ci` with `env = "robogym-rearrange"` (papermill, as `make reproduce`
    runs it): every cell runs, and every figure it draws goes to the env's own subfolder, so
    block-rearrange's figures are never overwritten."""
    papermill = pytest.importorskip("papermill")
    figures = tmp_path / "figures"
    monkeypatch.setenv("NCS_LITE_PRESET", "ci")
    monkeypatch.setenv("NCS_LITE_PROGRESS", "0")
    monkeypatch.setenv("NCS_LITE_FIGURES", str(figures))
    out = tmp_path / f"{name}_robogym.ipynb"
    papermill.execute_notebook(str(REPO / "notebooks" / f"{name}.ipynb"), str(out), cwd=str(REPO / "notebooks"),
                               parameters={"env": "robogym-rearrange", "preset": "ci"}, kernel_name="python3",
                               execution_timeout=600, progress_bar=False)
    written = sorted(p.relative_to(figures) for p in figures.rglob("*") if p.is_file())
    assert all(p.parts[:2] == (name, "robogym-rearrange") for p in written), written
    if name != "05_graph_construction":         # 05 draws only the mask graph, which robogym-rearrange skips
        assert any(p.suffix == ".png" for p in written), f"{name} drew no figure on robogym-rearrange"
