"""Classroom exercises: self-checks for the notebooks and the student-copy generator.

One master notebook per topic (`notebooks/NN_*.ipynb`) holds the exercises *and* their
solutions, so the student copy can never drift from the master:

- an exercise is a code cell tagged `exercise` whose solution lines sit between
  `# BEGIN SOLUTION: <hint>` and `# END SOLUTION` (one block per cell);
- the next code cell is its self-check, a call `check(name, student_fn, reference_fn, inputs)`
  that compares the student's function with the library's on tiny inputs.

`python -m ncs_lite.exercises` (`make exercises`) writes
  exercises/student/NN_*.ipynb    each solution block replaced by
                                  `raise NotImplementedError("Exercise N: <hint>")`
  exercises/solutions/NN_*.ipynb  the master with the markers removed
both without outputs, byte-identical on a rerun. `--check` only compares and exits 1 when
`exercises/` is out of date: it compares cells (type, source, tags: `utils.notebook_content`),
not bytes, so a copy that was opened, run and saved in JupyterLab, with its outputs and the
kernel's metadata, is still current.
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np

from .utils import REPO_DIR, notebook_content, relative_to_repo

BEGIN, END, TAG = "# BEGIN SOLUTION", "# END SOLUTION", "exercise"
MASTERS = REPO_DIR / "notebooks"
OUT = REPO_DIR / "exercises"
FIRST = 1  # notebooks before 01 (the overview) have no exercises


# ----------------------------------------------------------------------------- self-checks
def _as_plain(x):
    """torch tensors -> numpy arrays, tuples -> lists, recursively (for comparing and printing)."""
    if hasattr(x, "detach") and hasattr(x, "cpu"):
        return x.detach().cpu().numpy()
    if isinstance(x, (tuple, list)):
        return [_as_plain(v) for v in x]
    return x


def _short(x, width: int = 160) -> str:
    x = _as_plain(x)
    if isinstance(x, np.ndarray):
        text = np.array2string(x, precision=4, threshold=12, max_line_width=width)
        text = f"array{tuple(x.shape)} {text}" if x.ndim else text
    else:
        text = repr(x)
    text = " ".join(text.split())
    return text if len(text) <= width else text[:width - 3] + "..."


def same(got, expected, rtol: float = 1e-5, atol: float = 1e-6) -> str | None:
    """None when `got` matches `expected` (numbers and arrays within tolerance, shapes equal),
    else a short reason."""
    got, expected = _as_plain(got), _as_plain(expected)
    if isinstance(expected, list):
        if not isinstance(got, list) or len(got) != len(expected):
            return f"expected {len(expected)} values, got {_short(got)}"
        for i, (g, e) in enumerate(zip(got, expected)):
            why = same(g, e, rtol, atol)
            if why:
                return f"item {i}: {why}"
        return None
    if expected is None or isinstance(expected, (str, bool)):
        return None if got == expected else "different value"
    try:
        g, e = np.asarray(got, dtype=float), np.asarray(expected, dtype=float)
    except (TypeError, ValueError):
        return None if got == expected else "different value"
    if g.shape != e.shape:
        return f"shape {g.shape}, expected {e.shape}"
    if not np.allclose(g, e, rtol=rtol, atol=atol, equal_nan=True):
        return "different value"
    return None


class WrongAnswer(AssertionError):
    """A self-check's verdict on a wrong answer. It is an AssertionError, so Run All stops at
    it and nbmake fails a broken master; in a notebook IPython shows it as its one verdict
    line (`_render_traceback_`), not as a traceback through this module."""

    def _render_traceback_(self) -> list[str]:
        return [str(self)]


def _one_line(error: BaseException, *lines: str) -> BaseException:
    """`error`, shown by IPython as `lines` plus its own `Type: message` line instead of a
    traceback (the class, and so what `except` and nbclient see, is unchanged)."""
    shown = [*lines, f"{type(error).__name__}: {error}"]
    error._render_traceback_ = lambda: shown
    return error


def check(name: str, student, reference, inputs, rtol: float = 1e-5, atol: float = 1e-6) -> None:
    """Compare `student(*args)` with `reference(*args)` (the library) for every `args` in
    `inputs` (a tuple of arguments, or a single argument). Prints "✓ name: correct ..." and
    returns None (so a check cell leaves no `Out[n]`), or raises WrongAnswer, whose one line
    says what was expected, so Run All stops there and a wrong master fails under nbmake. An
    unsolved stub's NotImplementedError passes through, shown as two lines: a note and its hint."""
    inputs = list(inputs)
    for args in inputs:
        args = args if isinstance(args, tuple) else (args,)
        expected = reference(*copy.deepcopy(args))
        try:
            got = student(*copy.deepcopy(args))
        except NotImplementedError as e:
            raise _one_line(e, f"… {name}: not solved yet; write the function in the cell above, "
                               "then rerun both cells") from None
        why = same(got, expected, rtol, atol)
        if why:
            raise WrongAnswer(f"✗ {name}: for input {', '.join(_short(a, 80) for a in args)} expected "
                              f"{_short(expected)}, got {_short(got)} ({why})")
    print(f"✓ {name}: correct on {len(inputs)} input(s), same as the library")


# ----------------------------------------------------------------------------- generator
def _source(cell) -> str:
    src = cell.get("source", "")
    return "".join(src) if isinstance(src, list) else src


def _set_source(cell, text: str) -> None:
    lines = text.splitlines(keepends=True)
    if lines and lines[-1].endswith("\n"):
        lines[-1] = lines[-1][:-1]
    cell["source"] = lines


def _is_exercise(cell) -> bool:
    return cell["cell_type"] == "code" and TAG in cell.get("metadata", {}).get("tags", [])


def _blocks(text: str, where: str):
    """Split an exercise cell into (before, indent, hint, solution lines, after)."""
    lines = text.split("\n")
    starts = [i for i, line in enumerate(lines) if line.strip().startswith(BEGIN)]
    ends = [i for i, line in enumerate(lines) if line.strip().startswith(END)]
    if len(starts) != 1 or len(ends) != 1 or ends[0] < starts[0]:
        raise ValueError(f"{where}: an `exercise` cell needs exactly one '{BEGIN}: <hint>' ... "
                         f"'{END}' block, got {len(starts)} begin and {len(ends)} end markers")
    b, e = starts[0], ends[0]
    marker = lines[b].strip()
    hint = marker[len(BEGIN):].lstrip(":").strip()
    if not hint:
        raise ValueError(f"{where}: write a hint after the marker: '{BEGIN}: <hint>'")
    indent = lines[b][:len(lines[b]) - len(lines[b].lstrip())]
    return lines[:b], indent, hint, lines[b + 1:e], lines[e + 1:]


def _clean(nb) -> dict:
    nb = copy.deepcopy(nb)
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            cell["outputs"], cell["execution_count"] = [], None
    return nb


def _banner(name: str, kind: str) -> dict:
    text = {"student": (f"**Student copy** of `notebooks/{name}`, generated by `make exercises`. "
                        "Run it top to bottom: it stops at the first exercise you have not solved "
                        "yet, with a `NotImplementedError` that says which one and gives a hint. "
                        "Replace the `raise NotImplementedError(...)` line with your code, then run "
                        "the check cell below it."),
            "solutions": (f"**Solutions** to the exercises of `notebooks/{name}`, generated by "
                          "`make exercises`. Keep this copy away from students until they are "
                          "done.")}[kind]
    return {"cell_type": "markdown", "metadata": {}, "source": [text]}


def exercises_of(nb, where: str = "notebook") -> list[dict]:
    """[{number, hint, solution}] of a master notebook, in order."""
    out = []
    for cell in nb["cells"]:
        if _is_exercise(cell):
            _, _, hint, solution, _ = _blocks(_source(cell), where)
            out.append({"number": len(out) + 1, "hint": hint, "solution": "\n".join(solution)})
        elif BEGIN in _source(cell):
            raise ValueError(f"{where}: a '{BEGIN}' marker outside a cell tagged `{TAG}`")
    return out


def make_copy(nb, name: str, kind: str) -> dict:
    """The student (`kind="student"`) or solutions copy of master notebook `nb`."""
    if kind not in ("student", "solutions"):
        raise ValueError(f"kind must be 'student' or 'solutions', got {kind!r}")
    nb = _clean(nb)
    number = 0
    for cell in nb["cells"]:
        if not _is_exercise(cell):
            continue
        number += 1
        before, indent, hint, solution, after = _blocks(_source(cell), name)
        if kind == "student":
            middle = [f"{indent}raise NotImplementedError({json.dumps(f'Exercise {number}: {hint}', ensure_ascii=False)})"]
        else:
            middle = solution
        _set_source(cell, "\n".join(before + middle + after))
    banner = _banner(name, kind)
    if nb.get("nbformat_minor", 0) >= 5:          # nbformat 4.5 gives every cell an id
        banner["id"] = f"{kind}-banner"
    nb["cells"].insert(0, banner)
    return nb


def dumps(nb) -> str:
    """The byte layout of the kit's notebooks (1-space JSON, keys sorted, trailing newline)."""
    return json.dumps(nb, indent=1, sort_keys=True, ensure_ascii=False) + "\n"


def masters(folder: Path = MASTERS) -> list[Path]:
    return [p for p in sorted(folder.glob("[0-9][0-9]_*.ipynb")) if int(p.name[:2]) >= FIRST]


def generate(out: Path = OUT, folder: Path = MASTERS) -> dict[Path, str]:
    """{path: text} of every student and solutions copy (nothing written)."""
    files = {}
    for path in masters(folder):
        nb = json.loads(path.read_text(encoding="utf-8"))
        if not exercises_of(nb, path.name):
            raise ValueError(f"{path.name} has no exercise cells (tag a code cell `{TAG}`)")
        for kind in ("student", "solutions"):
            files[out / kind / path.name] = dumps(make_copy(nb, path.name, kind))
    return files


def first_difference(current: str, generated: str) -> str:
    """Where a copy's cells first differ from the generated ones, for a one-line message."""
    have, want = notebook_content(current), notebook_content(generated)
    if have is None:
        return "not a readable notebook"
    for i, (a, b) in enumerate(zip(have, want)):
        if a != b:
            return f"cell {i} ({b[0]}) is not the one `make exercises` writes"
    return f"{len(have)} cells, `make exercises` writes {len(want)}" if len(have) != len(want) else "same cells"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ncs_lite.exercises", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=OUT, help="output folder (default: exercises/)")
    parser.add_argument("--check", action="store_true",
                        help="compare cells only (not outputs or metadata); exit 1 if out of date")
    args = parser.parse_args(argv)
    files = generate(args.out)
    if args.check:
        stale = {}
        for p, text in files.items():
            current = p.read_text(encoding="utf-8") if p.exists() else None
            if current is None:
                stale[p] = "missing (`make exercises` writes it)"
            elif notebook_content(current) != notebook_content(text):
                stale[p] = first_difference(current, text)
        for p, why in stale.items():
            print(f"out of date: {relative_to_repo(p)}: {why}")
        return 1 if stale else 0
    stale = [p for p, text in files.items() if not p.exists() or p.read_text(encoding="utf-8") != text]
    for p in stale:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(files[p], encoding="utf-8")
    print(f"{len(files)} notebooks in {relative_to_repo(args.out)} ({len(stale)} rewritten)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
