"""A student's session in JupyterLab, driven in headless Chromium: does it leave the kit clean?

    .venv/bin/python scripts/check_classroom.py [--notebook 01_environments] [--keep]
    (make classroom-check)

On a scratch copy of this checkout (its tracked files as they are now, committed in a fresh
git repository, so the checkout itself is never touched), with NCS_LITE_PRESET=ci as
docs/teaching.md advises for a first pass, it starts JupyterLab and, through JupyterLab's
own commands (`--expose-app-in-browser`: the commands a student's clicks run):

1. opens exercises/student/<notebook>: the kernel starts and the notebook is not modified;
2. runs all: Run All stops at exercise 1's check, which shows two lines (the note and the
   stub's hint), no traceback; saves. `git status` names that notebook alone (its outputs),
   yet the kit sees no change: `dirty_files()` is empty and `python -m ncs_lite.exercises
   --check` passes;
3. writes a wrong answer into exercise 1 and runs all: the check cell shows the one-line
   verdict `✗ ...` and Run All stops there (for the notebooks in WRONG, 01_environments);
4. writes the right answer, runs all: "✓ ..." with no `Out[n]`, Run All stops at exercise
   2; no printed absolute path, no "0 episodes" bar; saves, closes, reopens: the answer and
   its verdict are there and the notebook is not modified;
5. `git status` still names that notebook alone; now its cells changed, so `dirty_files()`
   and `--check` name it (and only it, at the solved cell).

Prints a line a step and a verdict; exits 1 when a step fails, 2 when selenium or Chromium
is missing (`scripts/browser.py`). --keep leaves the scratch copy and the server's log.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from browser import chrome, console_errors, free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
WRONG = {"01_environments": "def horizon(multiplier: float, min_steps: int) -> int:\n"
                            "    return max(1, int(multiplier * min_steps))     # rounds down: wrong\n"}

JS_OPEN = """
const [path, done] = [arguments[0], arguments[arguments.length - 1]];
(async () => {
  const app = window.jupyterapp;
  const panel = await app.commands.execute('docmanager:open', {path, factory: 'Notebook'});
  await panel.context.ready;
  await panel.sessionContext.ready;
  app.shell.activateById(panel.id);
  window.ncsPanel = panel;
  return 'ok';
})().then(done, e => done('ERROR ' + e));
"""
JS_IDLE = """
const done = arguments[arguments.length - 1];
(async () => {
  const panel = window.ncsPanel;
  for (let i = 0; i < 1200; i++) {                     // up to 10 minutes
    const kernel = panel.sessionContext.session && panel.sessionContext.session.kernel;
    const busy = panel.content.widgets.some(c => c.model.type === 'code' && (c.model.executionState === 'running'
      || (c.node.querySelector('.jp-InputPrompt') || {}).textContent?.includes('*')));
    if (kernel && kernel.status === 'idle' && !busy) return {dirty: panel.context.model.dirty, status: kernel.status};
    await new Promise(r => setTimeout(r, 500));
  }
  return 'ERROR kernel still busy';
})().then(done, e => done('ERROR ' + e));
"""
JS_RUN_ALL = """
const done = arguments[arguments.length - 1];
(async () => {
  const app = window.jupyterapp;
  app.shell.activateById(window.ncsPanel.id);
  await app.commands.execute('notebook:run-all-cells');
  return 'ok';
})().then(done, e => done('ERROR ' + e));
"""
JS_SET_SOURCE = """
const [marker, text, done] = [arguments[0], arguments[1], arguments[arguments.length - 1]];
const cells = window.ncsPanel.content.widgets.filter(c => c.model.sharedModel.getSource().includes(marker));
if (cells.length !== 1) { done('ERROR ' + cells.length + ' cells hold ' + marker); }
else { cells[0].model.sharedModel.setSource(text); done('ok'); }
"""
JS_SAVE_CLOSE = """
const [close, done] = [arguments[0], arguments[arguments.length - 1]];
(async () => {
  const panel = window.ncsPanel;
  await panel.context.save();
  const dirty = panel.context.model.dirty;
  if (close) { panel.close(); await new Promise(r => setTimeout(r, 500)); }
  return {dirty, closed: close};
})().then(done, e => done('ERROR ' + e));
"""
JS_RENDERED = """
return window.ncsPanel.content.widgets.map(c => [c.model.type, c.model.sharedModel.getSource(),
  c.model.type === 'code' ? JSON.stringify(c.model.outputs.toJSON()) : '']);
"""


class Failed(Exception):
    pass


def scratch_repo(where: Path) -> Path:
    """The checkout's tracked files as they are now, committed in a fresh repository."""
    repo = where / "repo"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
    for name in filter(None, files.decode().split("\0")):
        src, dst = REPO / name, repo / name
        if src.is_file():
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
    for args in (["init", "-q"], ["add", "-A"], ["-c", "user.name=check", "-c", "user.email=check@localhost",
                                                   "commit", "-q", "-m", "scratch copy for check_classroom"]):
        subprocess.run(["git", *args], cwd=repo, check=True, capture_output=True)
    return repo


def kit(repo: Path, code: str) -> str:
    """Run `code` in the scratch copy's kit (its ncs_lite, its git) and return what it printed."""
    out = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(repo)})
    return (out.stdout + out.stderr).strip() + f"\n(exit {out.returncode})"


def porcelain(repo: Path) -> list[str]:
    return subprocess.run(["git", "status", "--porcelain"], cwd=repo, capture_output=True, text=True,
                          check=True).stdout.splitlines()


def start_lab(repo: Path, where: Path, env: dict) -> tuple[subprocess.Popen, str]:
    port, token = free_port(), "classroom-check"
    args = [sys.executable, "-m", "jupyter", "lab", "--no-browser", f"--port={port}", "--ip=127.0.0.1",
            f"--ServerApp.token={token}", f"--ServerApp.root_dir={repo}", "--expose-app-in-browser",
            "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate"]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        args.append("--allow-root")
    log = open(where / "jupyterlab.log", "w")
    lab = subprocess.Popen(args, cwd=repo, env=env, stdout=log, stderr=subprocess.STDOUT)
    for _ in range(120):
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status?token={token}", timeout=2)
            return lab, f"http://127.0.0.1:{port}/lab?token={token}"
        except OSError:
            if lab.poll() is not None:
                raise Failed(f"JupyterLab exited ({lab.returncode}); see {where / 'jupyterlab.log'}")
            time.sleep(0.5)
    raise Failed("JupyterLab did not answer in 60 s")


def call(driver, script: str, *args):
    result = driver.execute_async_script(script, *args)
    if isinstance(result, str) and result.startswith("ERROR"):
        raise Failed(result)
    return result


def check_cells(nb: dict) -> list[dict]:
    """The code cells that call `check(` (the self-checks), in order."""
    return [c for c in nb["cells"] if c["cell_type"] == "code" and "check(" in "".join(c["source"])]


def errors_of(cell: dict) -> list[dict]:
    return [o for o in cell.get("outputs", []) if o.get("output_type") == "error"]


def text_of(cell: dict) -> str:
    return "".join("".join(o.get("text", "")) for o in cell.get("outputs", []) if o.get("output_type") == "stream")


def expect(ok: bool, what: str, detail: str = "") -> None:
    print(("ok    " if ok else "FAIL  ") + what + (f": {detail}" if detail and not ok else ""))
    if not ok:
        raise Failed(what)


def session(driver, url: str, repo: Path, name: str) -> None:
    rel = f"exercises/student/{name}.ipynb"
    path = repo / rel
    solutions = json.loads((repo / "exercises" / "solutions" / f"{name}.ipynb").read_text(encoding="utf-8"))
    answer = next("".join(c["source"]) for c in solutions["cells"] if "exercise" in c["metadata"].get("tags", []))
    stub_marker = 'raise NotImplementedError("Exercise 1: '

    driver.get(url)
    for _ in range(240):
        if driver.execute_script("return !!(window.jupyterapp && window.jupyterapp.shell)"):
            break
        time.sleep(0.5)
    call(driver, "const d = arguments[arguments.length - 1]; window.jupyterapp.restored.then(() => d('ok'));")

    # 1. open: the kernel fills in its metadata; the notebook must not turn modified
    call(driver, JS_OPEN, rel)
    state = call(driver, JS_IDLE)
    time.sleep(3)                                         # kernel_info's metadata arrives after `ready`
    state = call(driver, JS_IDLE)
    expect(not state["dirty"], f"1. opened {rel}: the kernel is idle and the notebook is not modified",
           f"modified on open ({state})")

    # 2. run all, save: the kit sees no change
    call(driver, JS_RUN_ALL)
    call(driver, JS_IDLE)
    call(driver, JS_SAVE_CLOSE, False)
    nb = json.loads(path.read_text(encoding="utf-8"))
    first = check_cells(nb)[0]
    shown = [line for e in errors_of(first) for line in e["traceback"]]
    expect(len(shown) == 2 and "not solved yet" in shown[0] and "Exercise 1: " in shown[1],
           "2. Run All stops at exercise 1's check with two lines", repr(shown))
    expect(not any(errors_of(c) for c in check_cells(nb)[1:]), "   ... and runs nothing after it")
    status = porcelain(repo)
    expect(status == [f" M {rel}"], "   git status names that notebook alone (its outputs)", repr(status))
    dirty = kit(repo, "from ncs_lite.utils import dirty_files; print(dirty_files())")
    expect(dirty.startswith("[]"), "   the kit sees no change: dirty_files() == []", dirty)
    checked = kit(repo, "import sys; from ncs_lite.exercises import main; sys.exit(main(['--check']))")
    expect(checked.endswith("(exit 0)"), "   python -m ncs_lite.exercises --check passes", checked)

    # 3. a wrong answer: one verdict line, Run All stops there
    if name in WRONG:
        call(driver, JS_SET_SOURCE, stub_marker, WRONG[name])
        call(driver, JS_RUN_ALL)
        call(driver, JS_IDLE)
        call(driver, JS_SAVE_CLOSE, False)
        first = check_cells(json.loads(path.read_text(encoding="utf-8")))[0]
        shown = [line for e in errors_of(first) for line in e["traceback"]]
        expect(len(shown) == 1 and shown[0].startswith("✗ "), "3. a wrong answer shows its one-line verdict",
               repr(shown))
        print(f"      {shown[0]}")
        stub_marker = "rounds down: wrong"

    # 4. the right answer: "✓", no Out[n]; save, close, reopen
    call(driver, JS_SET_SOURCE, stub_marker, answer)
    call(driver, JS_RUN_ALL)
    call(driver, JS_IDLE)
    saved = call(driver, JS_SAVE_CLOSE, True)
    expect(not saved["dirty"], "4. saved and closed")
    nb = json.loads(path.read_text(encoding="utf-8"))
    first, second = check_cells(nb)[:2]
    expect(text_of(first).startswith("✓ ") and not errors_of(first), "   exercise 1's check prints ✓",
           repr(first.get("outputs")))
    print(f"      {text_of(first).strip()}")
    results = [o for c in check_cells(nb) for o in c.get("outputs", []) if o.get("output_type") == "execute_result"]
    expect(not results, "   no check cell leaves an Out[n]", repr(results))
    expect(len(errors_of(second)) == 1 and errors_of(second)[0]["ename"] == "NotImplementedError",
           "   Run All now stops at exercise 2", repr(second.get("outputs")))
    outputs = json.dumps([c.get("outputs", []) for c in nb["cells"] if c["cell_type"] == "code"], ensure_ascii=False)
    expect(str(repo) not in outputs and str(REPO) not in outputs, "   no output names the checkout's absolute path")
    expect(" 0 episodes" not in outputs, "   no empty progress bar (\"0 episodes\")")
    call(driver, JS_OPEN, rel)
    call(driver, JS_IDLE)
    time.sleep(3)
    state = call(driver, JS_IDLE)
    cells = driver.execute_script(JS_RENDERED)
    solved = [c for c in cells if c[1] == answer]
    verdict = [c for c in cells if c[0] == "code" and "✓ " in c[2]]
    expect(len(solved) == 1 and len(verdict) == 1 and not state["dirty"],
           "   reopened: the answer and its ✓ are there, and the notebook is not modified", repr(state))

    # 5. the kit sees the student's edit, and only it
    status = porcelain(repo)
    expect(status == [f" M {rel}"], "5. git status names that notebook alone", repr(status))
    dirty = kit(repo, "from ncs_lite.utils import dirty_files; print(dirty_files())")
    expect(dirty.startswith(f"['{rel}']"), "   dirty_files() names it: its cells changed", dirty)
    checked = kit(repo, "import sys; from ncs_lite.exercises import main; sys.exit(main(['--check']))")
    expect(checked.count("out of date") == 1 and rel in checked and checked.endswith("(exit 1)"),
           "   --check names it alone, at the solved cell", checked)
    print(f"      {checked.splitlines()[0]}")
    committed = json.loads(subprocess.run(["git", "show", f"HEAD:{rel}"], cwd=repo, capture_output=True,
                                          text=True, check=True).stdout)
    changed = sorted(k for k in set(nb) | set(committed) if k != "cells" and nb.get(k) != committed.get(k))
    meta = sorted(k for k in set(nb["metadata"]) | set(committed["metadata"])
                  if nb["metadata"].get(k) != committed["metadata"].get(k))
    print(f"      what JupyterLab changed beside cells: top-level {changed or 'nothing'}, metadata {meta or 'nothing'}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--notebook", default="01_environments", help="the student copy to work on")
    parser.add_argument("--keep", action="store_true", help="keep the scratch copy and JupyterLab's log")
    args = parser.parse_args(argv)
    where = Path(tempfile.mkdtemp(prefix="ncs-classroom-"))
    driver = lab = None
    try:
        repo = scratch_repo(where)
        expect(porcelain(repo) == [], f"0. a scratch copy of the checkout, committed ({len(list(repo.rglob('*')))} paths)")
        env = {**os.environ, "PYTHONPATH": str(repo), "NCS_LITE_PRESET": "ci",
               "JUPYTER_CONFIG_DIR": str(where / "jupyter-config"), "JUPYTER_RUNTIME_DIR": str(where / "runtime"),
               "JUPYTERLAB_SETTINGS_DIR": str(where / "lab-settings"),
               "JUPYTERLAB_WORKSPACES_DIR": str(where / "lab-workspaces")}
        for name in ("NCS_LITE_FIGURES", "NCS_LITE_CACHE"):     # the scratch copy's own figures/ and .cache/
            env.pop(name, None)
        lab, url = start_lab(repo, where, env)
        driver = chrome()
        driver.set_script_timeout(900)
        session(driver, url, repo, args.notebook)
        errors = [e for e in console_errors(driver) if "favicon" not in e]
        print(f"      browser console: {len(errors)} errors" + (f" (first: {errors[0][:160]})" if errors else ""))
        print("classroom-check: a student's session leaves the kit clean")
        return 0
    except Failed as e:
        print(f"classroom-check: FAILED at: {e}")
        return 1
    finally:
        if driver is not None:
            driver.quit()
        if lab is not None:
            lab.terminate()
            try:
                lab.wait(20)
            except subprocess.TimeoutExpired:
                lab.kill()
        if args.keep:
            print(f"kept {where}")
        else:
            shutil.rmtree(where, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
