"""Committed notebooks carry no outputs, use the python3 kernel and the house skeleton, and
close every env they make in the cell that makes it."""
import ast
import json
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("[0-9][0-9]_*.ipynb"))


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 2


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_clean(path):
    nb = json.loads(path.read_text())
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    assert all(not c.get("outputs") and c.get("execution_count") is None for c in code), \
        f"{path.name} holds outputs: strip them with nbstripout"
    assert nb["metadata"]["kernelspec"]["name"] == "python3"
    tagged = [c for c in code if "parameters" in c.get("metadata", {}).get("tags", [])]
    assert len(tagged) == 1, "exactly one cell tagged `parameters`"
    text = "\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "markdown")
    for heading in ("## Setup", "## Summary", "## Exercises", "## References"):
        assert heading in text, f"{path.name} lacks the '{heading}' section"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_carries_the_kernels_metadata(path):
    """The metadata the python3 kernel writes is committed, so opening a notebook in JupyterLab
    does not mark it modified (only the Python version may differ on another machine: the
    kit compares notebooks by their cells, `ncs_lite.utils.notebook_content`)."""
    kernel = pytest.importorskip("ipykernel.ipkernel").IPythonKernel
    expected = {k: v for k, v in kernel.language_info.items() if k != "version"}
    info = json.loads(path.read_text())["metadata"]["language_info"]
    assert {k: v for k, v in info.items() if k != "version"} == expected and isinstance(info.get("version"), str), \
        f"{path.name}: language_info is not what the python3 kernel writes: {info}"


ENV_MAKERS = ("make", "make_env")    # ncs_lite.envs.make, TaskSet.make_env


def _opened_and_closed(tree):
    """Names a cell assigns an env to (`env = make(...)`), and names it calls `.close()` on."""
    opened, closed = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            f = node.value.func
            if getattr(f, "id", None) in ENV_MAKERS or getattr(f, "attr", None) in ENV_MAKERS:
                opened |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        if isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "close":
            if isinstance(node.func.value, ast.Name):
                closed.add(node.func.value.id)
    return opened, closed


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_every_env_is_closed_in_the_cell_that_makes_it(path):
    """A PyBullet or MuJoCo env left open holds its simulator until the kernel dies (and a
    rerun cell opens another): `with make(...) as env:` or `env.close()` in the same cell."""
    code = [c for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]
    for i, cell in enumerate(code):
        opened, closed = _opened_and_closed(ast.parse("".join(cell["source"])))
        assert opened <= closed, f"{path.name}, code cell {i}: {sorted(opened - closed)} never closed in that cell"
