"""A classroom session leaves the kit clean: a notebook opened, run and saved in JupyterLab
(outputs, execution counts, the kernel's metadata) is not a change to the code, while an
edited cell is; progress bars and cache lines say plainly what happened.

The browser check that drives a real JupyterLab is `scripts/check_classroom.py`
(`make classroom-check`); these are its pure parts, on tiny inputs."""
import copy
import json
import subprocess

import pytest

from ncs_lite import utils
from ncs_lite.exercises import dumps
from ncs_lite.utils import notebook_content, same_notebook

NOTEBOOK = {
    "cells": [
        {"cell_type": "markdown", "metadata": {}, "source": ["# Title\n", "text"]},
        {"cell_type": "code", "execution_count": None, "metadata": {"tags": ["parameters"]}, "outputs": [],
         "source": ["preset = \"reduced\"\n", "seed = 0"]},
        {"cell_type": "code", "execution_count": None, "metadata": {}, "outputs": [], "source": ["print(seed)"]},
    ],
    "metadata": {"kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
                 "language_info": {"name": "python"}},
    "nbformat": 4, "nbformat_minor": 4,
}


def run_and_saved(nb):
    """`nb` as JupyterLab saves it after Run All: outputs, counts, ids, the kernel's metadata."""
    nb = copy.deepcopy(nb)
    nb["metadata"]["language_info"] = {"name": "python", "version": "3.11.7", "mimetype": "text/x-python",
                                       "codemirror_mode": {"name": "ipython", "version": 3},
                                       "pygments_lexer": "ipython3", "nbconvert_exporter": "python",
                                       "file_extension": ".py"}
    nb["nbformat_minor"] = 5
    for i, cell in enumerate(nb["cells"]):
        cell["id"] = f"cell-{i}"
        if cell["cell_type"] == "code":
            cell["execution_count"] = i
            cell["outputs"] = [{"name": "stdout", "output_type": "stream", "text": ["0\n"]}]
            cell["metadata"]["scrolled"] = True
    return json.dumps(nb, indent=2)                       # another layout too


def test_a_run_and_saved_notebook_has_the_same_content():
    text = dumps(NOTEBOOK)
    assert notebook_content(text) == [("markdown", "# Title\ntext", ()),
                                      ("code", 'preset = "reduced"\nseed = 0', ("parameters",)),
                                      ("code", "print(seed)", ())]
    assert same_notebook(text, run_and_saved(NOTEBOOK))


@pytest.mark.parametrize("change", ["source", "type", "tag", "order", "added"])
def test_an_edited_cell_is_a_change(change):
    nb = copy.deepcopy(NOTEBOOK)
    cells = nb["cells"]
    if change == "source":
        cells[2]["source"] = ["print(seed + 1)"]
    elif change == "type":
        cells[0]["cell_type"] = "raw"
    elif change == "tag":                                 # the parameters cell is no longer one
        cells[1]["metadata"]["tags"] = []
    elif change == "order":
        cells[1], cells[2] = cells[2], cells[1]
    else:
        cells.append({"cell_type": "code", "metadata": {}, "outputs": [], "source": []})
    assert not same_notebook(dumps(NOTEBOOK), run_and_saved(nb))


def test_text_that_is_not_a_notebook_is_compared_byte_for_byte():
    assert notebook_content("{not json") is None and notebook_content('{"cells": 3}') is None
    assert same_notebook("{not json", "{not json") and not same_notebook("{not json", dumps(NOTEBOOK))


def git(repo, *args):
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout


@pytest.fixture
def repo(tmp_path, monkeypatch):
    """A git repository with one notebook and one module, committed; the kit's REPO_DIR."""
    git(tmp_path, "init", "-q")
    git(tmp_path, "config", "user.email", "t@example.com")
    git(tmp_path, "config", "user.name", "t")
    (tmp_path / "notebooks").mkdir()
    (tmp_path / "notebooks" / "01_x.ipynb").write_text(dumps(NOTEBOOK), encoding="utf-8")
    (tmp_path / "code.py").write_text("x = 1\n")
    git(tmp_path, "add", ".")
    git(tmp_path, "commit", "-q", "-m", "start")
    monkeypatch.setattr(utils, "REPO_DIR", tmp_path)
    return tmp_path


def test_dirty_files_ignores_a_run_and_saved_notebook_only(repo):
    assert utils.dirty_files() == []
    (repo / "notebooks" / "01_x.ipynb").write_text(run_and_saved(NOTEBOOK), encoding="utf-8")
    assert git(repo, "status", "--porcelain").strip() == "M notebooks/01_x.ipynb"   # git sees bytes
    assert utils.dirty_files() == [] and not utils.git_commit().endswith("+dirty")
    edited = copy.deepcopy(NOTEBOOK)
    edited["cells"][2]["source"] = ["print(seed * 2)"]
    (repo / "notebooks" / "01_x.ipynb").write_text(run_and_saved(edited), encoding="utf-8")
    assert utils.dirty_files() == ["notebooks/01_x.ipynb"]
    (repo / "code.py").write_text("x = 2\n")
    assert sorted(utils.dirty_files()) == ["code.py", "notebooks/01_x.ipynb"]


def test_a_deleted_notebook_is_a_change(repo):
    (repo / "notebooks" / "01_x.ipynb").unlink()
    assert utils.dirty_files() == ["notebooks/01_x.ipynb"]


def test_exercises_check_passes_a_run_and_saved_copy_and_names_an_edited_one(tmp_path, monkeypatch, capsys):
    from ncs_lite import exercises

    master = copy.deepcopy(NOTEBOOK)
    master["cells"].append({"cell_type": "code", "metadata": {"tags": ["exercise"]}, "outputs": [],
                            "execution_count": None,
                            "source": ["def f(x):\n", "    # BEGIN SOLUTION: double it\n", "    return 2 * x\n",
                                       "    # END SOLUTION"]})
    (tmp_path / "notebooks").mkdir()
    (tmp_path / "notebooks" / "01_x.ipynb").write_text(dumps(master), encoding="utf-8")
    generate = exercises.generate
    monkeypatch.setattr(exercises, "generate", lambda out: generate(out, tmp_path / "notebooks"))
    out = tmp_path / "exercises"
    assert exercises.main(["--out", str(out)]) == 0
    assert exercises.main(["--out", str(out), "--check"]) == 0
    student = out / "student" / "01_x.ipynb"
    nb = json.loads(student.read_text(encoding="utf-8"))
    student.write_text(run_and_saved(nb), encoding="utf-8")             # opened, run, saved
    assert exercises.main(["--out", str(out), "--check"]) == 0
    nb["cells"][-1]["source"] = ["def f(x):\n", "    return x + x"]      # solved
    student.write_text(run_and_saved(nb), encoding="utf-8")
    capsys.readouterr()
    assert exercises.main(["--out", str(out), "--check"]) == 1
    printed = capsys.readouterr().out
    assert printed.count("out of date") == 1
    assert "student/01_x.ipynb: cell 4 (code) is not the one `make exercises` writes" in printed


def test_no_progress_bar_when_the_jobs_hold_nothing(monkeypatch, capsys):
    from ncs_lite.workers import map_jobs

    monkeypatch.setenv("NCS_LITE_PROGRESS", "1")
    assert map_jobs(lambda shared, shards: len(shards), [([],)], workers=1, desc="collect x: 0 episodes") == [0]
    shown = capsys.readouterr()
    assert "collect x" not in shown.out + shown.err
    assert map_jobs(lambda shared, shards: len(shards), [([1, 2],)], workers=1, desc="collect x: 2 episodes") == [2]
    shown = capsys.readouterr()
    assert "collect x: 2 episodes" in shown.out + shown.err                    # a bar when there is work


def test_cache_lines_say_what_happened_without_paths(tmp_path, monkeypatch, capsys):
    from ncs_lite.cache import cached

    monkeypatch.setenv("NCS_LITE_CACHE", str(tmp_path))
    cached("evaluation", lambda: [1, 2], k=1)
    first = capsys.readouterr().out
    assert first.startswith("computed evaluation in ") and first.endswith(" s, saved to cache\n")
    cached("evaluation", lambda: [1, 2], k=1)
    assert capsys.readouterr().out == "loaded evaluation from cache\n"
    assert str(tmp_path) not in first
