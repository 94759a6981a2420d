"""Classroom exercises: the student copies are current, every stub raises
NotImplementedError with its hint, the masters' solutions pass their self-checks, a wrong
answer fails its self-check, and a student copy runs until its first exercise and stops there.

The exercise sections need only their own imports cell, so most tests run them in-process
(seconds); one test executes each student copy's Exercises section in a kernel at `ci`."""
import builtins
import io
import json
import os
import re
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from ncs_lite import exercises
from ncs_lite.exercises import check, generate, make_copy

REPO = Path(__file__).resolve().parents[1]
MASTERS = exercises.masters(REPO / "notebooks")


def load(path):
    return json.loads(Path(path).read_text(encoding="utf-8"))


def src(cell):
    return "".join(cell["source"])


def exercises_start(nb):
    """The index of the cell of the Exercises heading."""
    return next(i for i, c in enumerate(nb["cells"]) if src(c).startswith("## Exercises"))


def exercise_section(nb):
    """The code cells from the Exercises heading on: imports, then (exercise, check) pairs."""
    return [c for c in nb["cells"][exercises_start(nb):] if c["cell_type"] == "code"]


def code_before_exercises(nb):
    """The sources of the code cells before the Exercises heading."""
    return [src(c) for c in nb["cells"][:exercises_start(nb)] if c["cell_type"] == "code"]


def run_cells(cells, namespace=None):
    namespace = {"__name__": "__exercise__", "__builtins__": builtins} if namespace is None else namespace
    out = io.StringIO()
    with redirect_stdout(out):
        for cell in cells:
            exec(compile(src(cell), "<cell>", "exec"), namespace)
    return namespace, out.getvalue()


def test_every_notebook_from_01_has_two_exercises_with_checks():
    assert [p.name[:2] for p in MASTERS] == ["01", "02", "03", "04", "05", "06", "07", "08", "09", "10"]
    for path in MASTERS:
        nb = load(path)
        cells = nb["cells"]
        found = exercises.exercises_of(nb, path.name)
        assert len(found) >= 2, path.name
        for i, cell in enumerate(cells):
            if "exercise" in cell["metadata"].get("tags", []):
                nxt = cells[i + 1]
                assert nxt["cell_type"] == "code" and "check(" in src(nxt), \
                    f"{path.name}: exercise cell {i} is not followed by a self-check cell"


def test_generated_copies_are_current(tmp_path):
    files = generate(tmp_path, REPO / "notebooks")
    for path, text in files.items():
        committed = REPO / "exercises" / path.relative_to(tmp_path)
        assert committed.exists(), f"{committed} missing: run `make exercises`"
        assert committed.read_text(encoding="utf-8") == text, f"{committed} is stale: run `make exercises`"
    generated = {p.relative_to(tmp_path) for p in files}
    committed = {p.relative_to(REPO / "exercises") for p in (REPO / "exercises").glob("*/*.ipynb")}
    assert committed == generated, f"extra files in exercises/: {sorted(committed - generated)}"
    assert generate(tmp_path, REPO / "notebooks") == files     # deterministic


def test_student_copies_hold_no_solution_and_no_outputs():
    for path in MASTERS:
        for kind in ("student", "solutions"):
            nb = load(REPO / "exercises" / kind / path.name)
            assert nb["metadata"]["kernelspec"]["name"] == "python3"
            for cell in nb["cells"]:
                assert exercises.BEGIN not in src(cell) and exercises.END not in src(cell)
                if cell["cell_type"] == "code":
                    assert not cell["outputs"] and cell["execution_count"] is None
        master = exercises.exercises_of(load(path), path.name)
        student = "\n".join(src(c) for c in load(REPO / "exercises" / "student" / path.name)["cells"])
        for ex in master:
            assert f'raise NotImplementedError("Exercise {ex["number"]}: {ex["hint"]}")' in student
            body = [line for line in ex["solution"].split("\n") if line.strip() and "return" in line]
            assert not any(line in student for line in body), f"{path.name}: a solution line leaked"


@pytest.mark.parametrize("path", MASTERS, ids=lambda p: p.name)
def test_masters_pass_stubs_raise_and_wrong_answers_fail(path):
    master = load(path)
    cells = exercise_section(master)
    pairs = [(cells[i], cells[i + 1]) for i in range(1, len(cells), 2)]   # cells[0]: imports
    ns, out = run_cells(cells)                                  # the master's solutions pass
    assert out.count("✓") == len(pairs) and "✗" not in out, out

    student = exercise_section(make_copy(master, path.name, "student"))
    for number, (stub, chk) in enumerate(pairs, 1):
        stub_ns = dict(ns)
        run_cells([student[2 * number - 1]], stub_ns)             # replaces the solution by the stub
        with pytest.raises(NotImplementedError, match=f"Exercise {number}: "):
            run_cells([chk], stub_ns)

        # a deliberately wrong answer: the master's function with its result perturbed
        name = re.search(r"^def (\w+)\(", src(stub), re.M).group(1)
        wrong_ns = dict(ns)
        right = ns[name]

        def wrong(*args, _right=right):
            result = _right(*args)
            if isinstance(result, tuple):
                return (result[0] * 0 + 0.123,) + tuple(result[1:])
            return result * 0 + 7
        wrong_ns[name] = wrong
        with pytest.raises(AssertionError):
            run_cells([chk], wrong_ns)


def test_check_prints_a_plain_verdict():
    out = io.StringIO()
    with redirect_stdout(out):
        assert check("double", lambda x: 2 * x, lambda x: x + x, [1, 2.5]) is None   # no `Out[n]: True`
        with pytest.raises(AssertionError, match="expected 4, got 5") as wrong:
            check("double", lambda x: 2 * x + (x == 2), lambda x: x + x, [1, 2])
    assert out.getvalue() == "✓ double: correct on 2 input(s), same as the library\n"
    # IPython shows an exception by its _render_traceback_ when it has one: the verdict, one line
    assert isinstance(wrong.value, exercises.WrongAnswer)
    assert wrong.value._render_traceback_() == ["✗ double: for input 2 expected 4, got 5 (different value)"]


def test_an_unsolved_stub_shows_two_lines_and_stays_a_not_implemented_error():
    def stub(x):
        raise NotImplementedError("Exercise 1: add x to itself")

    with pytest.raises(NotImplementedError, match="Exercise 1: add x to itself") as err:
        check("double", stub, lambda x: x + x, [1])
    assert err.value._render_traceback_() == [
        "… double: not solved yet; write the function in the cell above, then rerun both cells",
        "NotImplementedError: Exercise 1: add x to itself"]


def test_a_verdict_in_ipython_is_its_line_not_a_traceback(capsys, tmp_path, monkeypatch):
    """What a student sees: IPython's shell renders the failing check as the verdict line."""
    shell_module = pytest.importorskip("IPython.core.interactiveshell")
    from traitlets.config import Config

    monkeypatch.setenv("IPYTHONDIR", str(tmp_path))          # no profile or history in $HOME
    config = Config()
    config.HistoryManager.enabled = False
    shell = shell_module.InteractiveShell.instance(config=config)
    try:
        shell.run_cell("from ncs_lite.exercises import check\n"
                       "check('double', lambda x: 3 * x, lambda x: x + x, [2])")
        shown = capsys.readouterr()
        text = shown.out + shown.err
        assert "✗ double: for input 2 expected 4, got 6 (different value)" in text
        assert "Traceback" not in text and "exercises.py" not in text
        result = shell.run_cell("check('double', lambda x: 2 * x, lambda x: x + x, [2])")
        assert result.result is None and result.success      # nothing for `Out[n]`
    finally:
        shell_module.InteractiveShell.clear_instance()


@pytest.mark.parametrize("path", sorted((REPO / "exercises" / "student").glob("[0-9][0-9]_*.ipynb")),
                         ids=lambda p: p.stem)
def test_student_copy_runs_to_its_first_exercise_and_stops_there(path, tmp_path):
    """Execute a student copy at `ci` in a kernel, as nbmake would: the only error is the
    NotImplementedError of its first exercise's stub, shown in two lines. The code before
    the Exercises heading is the master's, cell for cell, and nbmake runs the master, so the
    kernel runs the banner and the Exercises section (which needs only its own imports)."""
    nbclient, nbformat = pytest.importorskip("nbclient"), pytest.importorskip("nbformat")
    nb = nbformat.read(path, as_version=4)
    assert code_before_exercises(nb) == code_before_exercises(load(REPO / "notebooks" / path.name))
    nb.cells = nb.cells[:1] + nb.cells[exercises_start(nb):]   # the banner, then the exercises
    env = {"NCS_LITE_PRESET": "ci", "NCS_LITE_PROGRESS": "0",
           "NCS_LITE_FIGURES": os.environ.get("NCS_LITE_FIGURES", str(tmp_path / "figures"))}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                         resources={"metadata": {"path": str(path.parent)}})
        with pytest.raises(nbclient.exceptions.CellExecutionError) as err:
            client.execute()
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    assert err.value.ename == "NotImplementedError", err.value
    assert "Exercise 1: " in str(err.value)
    failed = [c for c in nb.cells if c.cell_type == "code"
              and any(o.get("output_type") == "error" for o in c.get("outputs", []))]
    assert len(failed) == 1 and "check(" in failed[0].source
    shown = next(o for o in failed[0].outputs if o.get("output_type") == "error").traceback
    assert len(shown) == 2 and "not solved yet" in shown[0], shown     # two lines, not a traceback


def test_measured_time_reads_the_reproduce_record(tmp_path, monkeypatch):
    import ncs_lite.figures as figures

    monkeypatch.setattr(figures, "REPO_DIR", tmp_path)
    assert figures.measured_time("01_environments").endswith("not measured yet")
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "notebook_times.json").write_text(json.dumps(
        {"seconds": {"01_environments": 185.0, "02_dvae": 12.4}, "commit": "abc1234def", "dirty": False}))
    assert figures.measured_time("01_environments") == \
        "time of 01_environments: about 3 min at `reduced` (measured by `make reproduce` at commit abc1234)"
    assert "about 12 s" in figures.measured_time("02_dvae")
    assert figures.measured_time("06_action_selection").endswith("not measured yet")
    # notebooks 04-07 on the other envs: make reproduce's <name>_robogym and <name>_stacking
    (tmp_path / "figures" / "notebook_times.json").write_text(json.dumps(
        {"seconds": {"06_action_selection": 30.0, "06_action_selection_stacking": 400.0}}))
    assert "about 7 min" in figures.measured_time("06_action_selection", "block-stacking")
    assert figures.measured_time("06_action_selection", "block-stacking").startswith(
        "time of 06_action_selection_stacking:")
    assert "about 30 s" in figures.measured_time("06_action_selection", "block-rearrange")
    assert figures.measured_time("06_action_selection", "robogym-rearrange").endswith("not measured yet")


def test_figures_of_other_presets_leave_figures_alone(monkeypatch):
    import ncs_lite.figures as figures

    monkeypatch.delenv("NCS_LITE_FIGURES", raising=False)
    monkeypatch.delenv("NCS_LITE_PRESET", raising=False)
    monkeypatch.setattr(figures, "_PRESET", None)
    figures.resolve_preset("ci")
    assert figures.figure_folder("01_environments") == REPO / "build" / "figures" / "ci" / "01_environments"
    monkeypatch.setenv("NCS_LITE_FIGURES", "/tmp/elsewhere")
    assert figures.figure_folder("01_environments") == Path("/tmp/elsewhere/01_environments")
    monkeypatch.setattr(figures, "_PRESET", None)
