"""Small shared helpers: seeding, progress bars, atomic writes, paths, versions.

Every long job in the kit writes through `atomic_path` (`atomic_write_text`, `atomic_write_json`,
`tensor_files.atomic_torch_save`) so an interrupted run never leaves a half-written file
behind, and every long loop goes through `progress` so CI can silence all bars with one
setting (NCS_LITE_PROGRESS=0). Nothing here needs torch: every command imports this module.
"""
from __future__ import annotations

import ast
import contextlib
import glob
import hashlib
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm
from tqdm.std import tqdm as text_tqdm

PACKAGE_DIR = Path(__file__).resolve().parent
REPO_DIR = PACKAGE_DIR.parent


def seed_everything(seed: int) -> np.random.Generator:
    """Seed Python, NumPy and torch (if imported); return a fresh NumPy Generator.

    Environments take their own seed through `env.reset(seed=...)`.
    """
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    random.seed(int(seed))
    np.random.seed(int(seed) % 2**32)
    torch = sys.modules.get("torch")         # seeded when imported; importing it here would cost seconds
    if torch is not None:
        torch.manual_seed(int(seed))
    return np.random.default_rng(int(seed))


def task_seed_of(agent_seed: int, task_seed: int) -> int:
    """The seed an agent seeded `agent_seed` draws with on the task whose env was reset with
    `task_seed` (agents reseed in `reset`): a task's moves then depend on that task alone, not
    on the tasks run before it, so a task set split over workers or run in another order gives
    the same rows."""
    return int(np.random.SeedSequence([int(agent_seed), int(task_seed), 0xA6E7]).generate_state(1)[0])


def progress_enabled() -> bool:
    """Bars are on unless NCS_LITE_PROGRESS=0 (set by CI and `make test`)."""
    return os.environ.get("NCS_LITE_PROGRESS", "1") not in ("0", "false", "no")


def in_jupyter_kernel() -> bool:
    """True inside a Jupyter kernel (JupyterLab, papermill, nbmake), False in a terminal."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None and hasattr(ipython, "get_ipython") else None
    return type(shell).__name__ == "ZMQInteractiveShell"


def progress(iterable=None, **kwargs):
    """A tqdm bar that honours NCS_LITE_PROGRESS (off under CI and `make test`).

    In a terminal it is tqdm's usual bar. In a Jupyter kernel it is tqdm's *text* bar on
    stdout, not a widget: a widget saved in a notebook reads "Error displaying widget: model
    not found" once the notebook is reopened, while the text bar's last line (desc, count,
    time) stays readable. In a kernel every bar is kept (`leave=True`) so each long loop
    leaves that one-line record."""
    kwargs.setdefault("disable", not progress_enabled())
    if in_jupyter_kernel():
        kwargs.update(leave=True)
        kwargs.setdefault("file", sys.stdout)
        kwargs.setdefault("ncols", 100)
        kwargs.setdefault("mininterval", 1.0)
        return text_tqdm(iterable, **kwargs)
    kwargs.setdefault("dynamic_ncols", True)
    return tqdm(iterable, **kwargs)


STALE_TMP_SECONDS = 3600     # a temporary file this old was left by a killed write


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _writer_gone(tmp: Path, name: str) -> bool:
    """Whether the process that made the temporary file `tmp` of `name` has ended (False when
    its name holds no pid: files from before the pid was written)."""
    pid = tmp.name[len(name) + 2:].split(".", 1)[0]
    if not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)           # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return True
    except (PermissionError, OverflowError):
        pass                           # alive under another user; not a pid
    return False


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path in the target's folder; rename it over `path` on success.

    os.replace is atomic on POSIX, so readers see either the old file or the new one. The
    file gets the mode a plain `open` would give (0666 less the umask; mkstemp's is 0600,
    which a shared class folder could not read). Temporary files of `path` that a killed
    write left behind are removed: those whose writer (its pid is in the name) has ended, and
    any older than STALE_TMP_SECONDS (a reused pid, another host).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for old in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        try:
            if _writer_gone(old, path.name) or time.time() - old.stat().st_mtime > STALE_TMP_SECONDS:
                old.unlink()
        except OSError:
            pass                       # another process removed or renamed it
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def one_line(e: BaseException) -> str:
    """`Type: first line of the message` of an exception, for a one-line error about a file."""
    first = (str(e).splitlines() or [""])[0][:200]
    return f"{type(e).__name__}: {first}" if first else type(e).__name__


def recorded_env(info: dict) -> str | None:
    """The env a graph or NF graph was made on: `info["env"]`, or for a file made before it
    was recorded, the env that names the buffer it was built from (`info["data"]`,
    ".cache/buffers/<env>-k4-..."); None when neither says."""
    if info.get("env"):
        return str(info["env"])
    name = Path(str(info.get("data") or "")).name
    for env in ("block-rearrange", "robogym-rearrange", "block-stacking"):
        if name.startswith(env + "-"):
            return env
    return None


def check_file_env(flag: str, path, made_on: str | None, expected: str | None) -> None:
    """ValueError naming the file and both envs when a file made on one env would be used on
    another; a file (or a use) that names no env passes."""
    if made_on is not None and expected is not None and made_on != expected:
        raise ValueError(f"{flag} {path} was made on {made_on!r}, not {expected!r}; pass a file made on "
                         f"{expected} (or use it with {made_on})")


def check_out_file(path: str | os.PathLike, what: str) -> Path:
    """ValueError naming `path` unless a `what` file can be written there: not a directory,
    not below a file. Checked before the work, which would otherwise fail at its first save."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"--out {path} is a directory; expected the path of a {what} file")
    _check_parents(path)
    return path


def check_out_dir(path: str | os.PathLike, what: str, flag: str = "--out") -> Path:
    """ValueError naming `path` unless it is (or can be made) a `what` directory."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{flag} {path} is a file; expected a {what} directory")
    _check_parents(path, flag)
    return path


def _check_parents(path: Path, flag: str = "--out") -> None:
    for parent in path.parents:
        if parent.exists():                       # the nearest folder that exists decides
            if not parent.is_dir():
                raise ValueError(f"{flag} {path} lies below {parent}, which is a file, not a directory")
            return


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def atomic_write_json(path: str | os.PathLike, obj) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def package_versions() -> dict[str, str]:
    """Versions of the packages whose behaviour shapes data and results."""
    out = {"python": sys.version.split()[0]}
    for name in ("ncs-lite", "numpy", "torch", "pybullet", "mujoco", "gymnasium", "scipy"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=REPO_DIR, capture_output=True, text=True, timeout=5,
                          check=True).stdout


def dirty_files() -> list[str]:
    """Tracked files with uncommitted changes ([] outside git), the generated text aside:
    figures/, README.md and docs/ are outputs (`python -m ncs_lite.docs` rewrites the README's
    result blocks and docs/results.md whenever a table or a notebook time is written, while
    `make reproduce` runs), and none of them changes what the code does. A notebook whose
    cells are those of the commit (`notebook_content`) is not changed either: opening, running
    and saving it in JupyterLab rewrites its outputs and metadata, not what it runs."""
    try:
        out = _git("status", "--porcelain", "-z", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return []
    changed = []
    entries = iter(out.split("\0"))
    for entry in entries:
        if not entry:
            continue
        status, path = entry[:2], entry[3:]
        if "R" in status or "C" in status:
            next(entries, None)              # -z gives a rename's old path as the next entry
        if path.startswith(GENERATED_TEXT):
            continue
        if status.strip() == "M" and path.endswith(".ipynb") and _same_cells_as_head(path):
            continue
        changed.append(path)
    return changed


GENERATED_TEXT = ("figures/", "README.md", "docs/")     # outputs, not code (dirty_files)


def notebook_content(text: str) -> list[tuple[str, str, tuple[str, ...]]] | None:
    """What a notebook is to the kit, from its JSON text: (type, source, tags) of each cell,
    in order (the tags mark the `parameters` cell and the exercises); None when `text` is not
    a notebook. Outputs, execution counts, cell ids and the metadata a kernel or JupyterLab
    writes (language_info, widths, collapsed cells) are left out: they change on every run."""
    try:
        nb = json.loads(text)
        cells = nb["cells"]
        out = []
        for cell in cells:
            source = cell.get("source", "")
            tags = (cell.get("metadata") or {}).get("tags") or []
            out.append((str(cell["cell_type"]), "".join(source) if isinstance(source, list) else str(source),
                        tuple(sorted(map(str, tags)))))
        return out
    except (ValueError, TypeError, KeyError, AttributeError):
        return None


def same_notebook(a: str, b: str) -> bool:
    """Whether two notebook texts run the same cells (`notebook_content`); two texts that are
    not notebooks are the same only byte for byte."""
    ca, cb = notebook_content(a), notebook_content(b)
    return a == b if ca is None or cb is None else ca == cb


def _same_cells_as_head(path: str) -> bool:
    try:
        committed = subprocess.run(["git", "show", f"HEAD:{path}"], cwd=REPO_DIR, capture_output=True,
                                   encoding="utf-8", timeout=5, check=True).stdout
        current = (REPO_DIR / path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError, subprocess.SubprocessError):
        return False
    return same_notebook(committed, current)


def git_commit() -> str:
    """The kit's commit (with '+dirty' for uncommitted changes), or 'unknown' outside git."""
    try:
        sha = _git("rev-parse", "--short", "HEAD").strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return sha + ("+dirty" if dirty_files() else "")


# Where committed results live: writing there from a dirty tree would give them a provenance
# that names no commit.
def committed_result_dirs() -> tuple[Path, ...]:
    return (REPO_DIR / "figures", PACKAGE_DIR / "assets")


def allow_dirty_from_env() -> bool:
    """NCS_LITE_ALLOW_DIRTY=1 lets results be written into figures/ or assets/ from a dirty tree."""
    return os.environ.get("NCS_LITE_ALLOW_DIRTY", "0") not in ("0", "", "false", "no")


def provenance(target: str | os.PathLike, allow_dirty: bool = False) -> dict:
    """The commit a result written to `target` comes from: {"commit", "dirty"}.

    Refuses (ValueError naming the changed files) to write into the repo's `figures/` or
    `ncs_lite/assets/` from a tree with uncommitted changes, unless `allow_dirty` (or
    NCS_LITE_ALLOW_DIRTY=1); a result written anyway records `"dirty": true`.
    """
    target = Path(target).resolve()
    changed = dirty_files()
    guarded = any(target == d or d in target.parents for d in committed_result_dirs())
    if changed and guarded and not (allow_dirty or allow_dirty_from_env()):
        shown = ", ".join(changed[:5]) + (f" and {len(changed) - 5} more" if len(changed) > 5 else "")
        raise ValueError(f"refusing to write {relative_to_repo(target)} from a tree with uncommitted "
                         f"changes ({shown}): commit first so the result names its commit, or pass "
                         "--allow-dirty (NCS_LITE_ALLOW_DIRTY=1 for notebooks)")
    return {"commit": git_commit(), "dirty": bool(changed)}


def relative_to_repo(path: str | os.PathLike) -> str:
    """`path` relative to the repo when inside it (so provenance does not name this machine),
    as written or with its links followed: `.cache/...` also where `.cache` is a link to
    another checkout's cache (a git worktree sharing it)."""
    for p in (Path(os.path.abspath(path)), Path(path).resolve()):
        try:
            return str(p.relative_to(REPO_DIR))
        except ValueError:
            pass
    return str(path)


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def source_hash(*parts: str) -> str:
    """sha256 over the code of the kit's Python sources under `parts` (files or folders of
    ncs_lite/): the code version that caches and `--resume` are keyed by. It reads each file's
    syntax tree without docstrings (`code_of`), so prose, comments and layout change no key."""
    h = hashlib.sha256()
    for part in sorted(parts):
        root = PACKAGE_DIR / part
        files = sorted(root.rglob("*.py")) if root.is_dir() else [root]
        for f in files:
            h.update(str(f.relative_to(PACKAGE_DIR)).encode())
            h.update(code_of(f.read_text()).encode())
    return h.hexdigest()[:16]


def code_of(source: str) -> str:
    """What Python runs of `source`: its syntax tree, dumped without positions, comments or
    docstrings (a module's, class's or function's first statement when it is a string)."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree)


def _repo_path(variable: str, default: Path) -> Path:
    """$variable, a relative value read from the repo's root (notebooks run in notebooks/,
    papermill in the caller's folder: the working directory must not decide), else default."""
    value = os.environ.get(variable)
    if not value:
        return default
    path = Path(value).expanduser()
    return path if path.is_absolute() else REPO_DIR / path


# notebooks 04-07 run once more on each other env (`make reproduce`, `env` parameter): that run's
# executed copy (build/notebooks/<run>.ipynb) and time (figures/notebook_times.json) are named
# <notebook><suffix>; its figures go to figures/<notebook>/<env>/
# each env's short name in the file names of its notebook runs and tables (block-rearrange's
# files carry none: `notebook_run`, `reproduce.table_name`)
ENV_SHORT_NAMES = {"block-rearrange": "", "robogym-rearrange": "robogym", "block-stacking": "stacking"}
NOTEBOOK_ENV_SUFFIX = {env: f"_{short}" if short else "" for env, short in ENV_SHORT_NAMES.items()}


def notebook_run(notebook: str, env: str = "block-rearrange") -> str:
    """The name of `notebook`'s run on `env`: "04_dslate_training_stacking" for
    ("04_dslate_training", "block-stacking"); the notebook's own name on block-rearrange."""
    if env not in NOTEBOOK_ENV_SUFFIX:
        raise ValueError(f"env must be one of {', '.join(NOTEBOOK_ENV_SUFFIX)}, got {env!r}")
    return notebook + NOTEBOOK_ENV_SUFFIX[env]


def split_notebook_run(run: str) -> tuple[str, str]:
    """(notebook, env) of a run's name, `notebook_run`'s inverse: "05_graph_construction_robogym"
    -> ("05_graph_construction", "robogym-rearrange"); a name without an env's suffix is
    block-rearrange's."""
    for env, suffix in NOTEBOOK_ENV_SUFFIX.items():
        if suffix and run.endswith(suffix):
            return run[:-len(suffix)], env
    return run, "block-rearrange"


def figures_dir() -> Path:
    """Where notebooks write figures: $NCS_LITE_FIGURES or <repo>/figures."""
    return _repo_path("NCS_LITE_FIGURES", REPO_DIR / "figures")


def cache_dir() -> Path:
    """Where generated data and checkpoints are cached: $NCS_LITE_CACHE or <repo>/.cache."""
    return _repo_path("NCS_LITE_CACHE", REPO_DIR / ".cache")
