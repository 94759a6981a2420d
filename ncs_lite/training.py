"""Training dSLATE on an experience buffer: `python -m ncs_lite train ...`.

    python -m ncs_lite train --env block-rearrange --preset reduced \
        --data .cache/buffers/block-rearrange-4 --out dslate.pt [--resume] [--steps N]

What the loop guarantees:
* Determinism and exact resume. The batch of step i is fixed by (seed, i) alone: the
  windows are read in a stream of seeded permutations of the dataset. A checkpoint holds
  the model, the Adam state, the step, torch's RNG state (gumbel noise, slot samples,
  dropout) and the config, so `--resume` continues bit-for-bit like an uninterrupted run.
* Phases as data. A run is a list of phases (`phases(cfg)`, each a `Phase`: its steps, its
  lr schedule, the parts it trains and its loss), derived from the config. `paper` is one
  phase, Table 2's: every part trains jointly, slot attention, decoder and dynamics at a
  linearly warmed-up lr, the dVAE at its constant lr. `reduced` trains the dVAE alone first
  (with `train.segmentation_start_steps`, then slot attention on the mixture loss alone from
  several starts, keeping the one with the lowest mixture error: `select_start`), and after the
  main phase polishes (dVAE frozen, another mixture loss), trains the dynamics
  alone (latent loss), fits the renderer alone (masks, then pixels) and refits the dynamics
  on states read with `slots.position_prior`. The gumbel tau follows the global step
  (cosine, `tau_schedule`). With `TrainConfig.color_augment` the mixture loss reads each
  video with its colour channels permuted (and, with "channels_gamma", each raised to a
  random power; data/augment.py), drawn from (seed, step) like the batch. Why each phase:
  docs/recipe.md.
* Gradient clipping: `clip_grad_norm_` with max norm `train.grad_clip` (1.0) of the
  *inf*-norm (largest absolute gradient entry), as SLATE's reference code does.
* Mixed precision: bf16 autocast where it is faster (AMX CPUs, recent GPUs); fp32 else.
* Safety: checkpoints are written atomically every `checkpoint_every` steps; a
  non-finite loss or gradient stops the run with FloatingPointError and leaves the last
  good checkpoint untouched. A loss CSV (`<out>.csv`) is written beside the checkpoint.
* Checkpoints contain only tensors, dicts, lists and primitives, so they load with
  `torch.load(path, weights_only=True)`; a checkpoint from other code or another config
  is refused with a ValueError naming the difference. Each holds a kind tag ("dslate") and
  a digest of its tensors, checked on load: another kind of file, a flipped byte or a
  non-finite weight is refused naming the path (files from before the tag still load).
* Nothing is lost: `--resume` refuses a checkpoint of another config, precision, env,
  buffer (manifest hash) or training code (`training_code_version`), naming what differs;
  a new run at an existing checkpoint needs `force` (which deletes the old run's checkpoint
  and loss log first, so the two never mix); a lock file (`<out>.lock`) makes two runs on
  one `out` refuse each other. `--extend` continues a *finished* run into a new file under a
  schedule that only adds later phases (`EXTENDABLE`: the fields of the dynamics, render and
  refit phases and the position prior; the renderer, which only the render phases train, may
  be new), recording the run it extends in `lineage`. Each checkpoint records the commit
  (`provenance`: writing into `ncs_lite/assets/` from a dirty tree is refused), the `--set`
  overrides, and the buffer's path (relative to the repo) and manifest hash.
"""
from __future__ import annotations

import contextlib
import csv
import fcntl
import itertools
import os
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .cache import load_or_train
from .config import DSlateConfig, from_dict, get_preset, saved_config_diff, to_dict
from .data import EpisodeDataset, cached_buffer, load_manifest, manifest_hash
from .data.augment import augment_colors
from .data.buffer import check_actions
from .envs import ENVIRONMENTS
from .inference import (CHECKPOINT_FORMAT, CHECKPOINT_KIND, DIGESTED, SHIPPED_MODELS, TRAIN_EPISODES, load_dslate,
                        read_checkpoint, resolve_device)
from .models.dslate import LOSSES, MODEL_VERSION, DSlate
from .models.dvae import cosine_anneal, tau_schedule
from .tensor_files import atomic_torch_save, tensor_digest
from .utils import (cache_dir, check_out_file, package_versions, progress, provenance, relative_to_repo,
                    seed_everything, sha256_file, source_hash)

__all__ = ["train", "obtain_dslate", "resolve_precision", "Phase", "phases", "lr_at", "train_step",
           "build_optimizer", "autocast",
           "training_code_version", "run_lock"]

# The sources whose changes can change a training run (model, loop, config, data, rendering).
TRAINING_CODE = ("models", "training.py", "config.py", "data", "envs")

CSV_FIELDS = ["step", *LOSSES, "tau", "lr", "grad_norm", "seconds"]


# ---------------------------------------------------------------------- devices and precision
def cpu_has_fast_bf16() -> bool:
    """True on CPUs with AMX or AVX512-BF16 (oneDNN runs bf16 matmuls natively there)."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return "amx_bf16" in flags or "avx512_bf16" in flags


def resolve_precision(precision: str, device: torch.device) -> str:
    """'auto' -> 'bf16' on bf16-capable GPUs and AMX/AVX512-BF16 CPUs, else 'fp32'."""
    if precision in ("bf16", "fp32"):
        return precision
    if precision != "auto":
        raise ValueError(f"precision must be 'auto', 'bf16' or 'fp32', got {precision!r}")
    if device.type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    return "bf16" if cpu_has_fast_bf16() else "fp32"


def autocast(device: torch.device, precision: str):
    """bf16 autocast context (a no-op context for fp32)."""
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16")


# ---------------------------------------------------------------------- phases and data order
# The parts of DSlate (its attributes that hold parameters) that the SLATE loss trains; the
# renderer, the one other part, trains alone in the render phases.
SLATE_PARTS = ("dvae", "token_emb", "pos_emb", "mask_emb", "pixel_encoder", "sa_in", "slot_attn", "decoder",
               "dynamics", "mixture", "state_masks")
# ... and those the mixture loss alone trains (`train.main_loss`, `train.polish_loss` "mixture")
MIXTURE_PARTS = ("pixel_encoder", "sa_in", "slot_attn", "mixture", "state_masks")


@dataclass(frozen=True)
class Phase:
    """A stretch of training with one loss, one lr schedule and the parts it trains: a run
    is a list of them (`phases`), so that each stage of the recipe reads as one row."""
    name: str
    steps: int
    loss: str                   # what it minimises (`train_step`): "dvae" the dVAE's reconstruction
    #                             alone, "slate" DSlate.forward's sum, "mixture" DSlate.mixture_loss
    #                             (segmentation alone), "dynamics" the latent loss
    #                             (DSlate.dynamics_loss), "render_masks" / "render" DSlate.render_loss
    #                             on slot attention's masks / on the frames
    trains: tuple[str, ...]     # the parts (SLATE_PARTS, "renderer") whose weights move; the rest is frozen
    lr: float = 0.0             # lr of every part but the dVAE: the peak after `warmup`
    warmup: int = 0             # steps of linear warm-up at the phase's start
    decay: str = "none"         # after the warm-up: "none" (constant) or "cosine" to 0.1 lr at the end
    dvae_lr: float = 0.0        # the dVAE's lr, constant (Table 2: no warm-up); 0 = frozen
    foreground_weight: float | None = None  # the mixture loss's (None: mixture.foreground_weight)
    mixture_error: str | None = None        # the mixture loss's (None: mixture.error)
    augment: str = "none"       # the colour augmentation of the mixture loss's videos (data/augment.py)
    position_prior: float = 0.0  # DSlate.position_prior while it trains
    starts: int = 1             # initialisations of `trains` tried in turn, `steps // starts` steps
    #                             each on the same batches; the best is kept (`select_start`)
    start: int = 0              # the run's step at which it begins

    @property
    def end(self) -> int:
        """The run's step at which the next phase begins."""
        return self.start + self.steps

    @property
    def start_steps(self) -> int:
        """Steps of each of the phase's starts (all of them when it has one)."""
        return self.steps // self.starts

    def data_step(self, step: int) -> int:
        """The run's step whose batch (and colour augmentation) the run's `step` reads: each
        start of a phase with several reads the batches of its first."""
        return self.start + (step - self.start) % self.start_steps

    def lr_at(self, i: int) -> float:
        """lr of every part but the dVAE at step `i` of this phase: linear warm-up to `lr`,
        then constant or a cosine decay to 10% of it at the phase's last step (each of
        several starts follows the schedule from its own first step)."""
        if self.starts > 1:
            i %= self.start_steps
        warm = min(1.0, (i + 1) / self.warmup) if self.warmup > 0 else 1.0
        if self.decay == "cosine" and i >= self.warmup:
            return cosine_anneal(i - self.warmup, self.lr, 0.1 * self.lr, max(1, self.start_steps - self.warmup))
        return self.lr * warm


def phases(cfg: DSlateConfig) -> list[Phase]:
    """The run's phases in order, derived from `cfg`; those of 0 steps are left out, so
    `paper` is one phase ("main", Table 2) and `reduced` seven (why each: docs/recipe.md);
    `train.segmentation_start_steps` adds "starts" before the main schedule."""
    return [p for p in _all_phases(cfg) if p.steps > 0]


def _all_phases(cfg: DSlateConfig) -> list[Phase]:
    """Every phase the trainer knows, in order, each with its start: one of 0 steps starts
    where a longer one would (what `--extend` checks a finished run against)."""
    t, prior = cfg.train, cfg.slots.position_prior
    joint = t.main_loss == "slate"      # the main schedule trains every part (Table 2)
    plan = [
        Phase("dvae_warmup", t.dvae_warmup_steps, "dvae", ("dvae",), dvae_lr=cfg.dvae.lr),
        Phase("starts", t.segmentation_starts * t.segmentation_start_steps, "mixture", MIXTURE_PARTS, lr=t.lr,
              warmup=t.warmup_steps, augment=t.color_augment, starts=t.segmentation_starts),
        Phase("main", t.main_steps() - t.dvae_warmup_steps, t.main_loss,
              SLATE_PARTS if joint else MIXTURE_PARTS, lr=t.lr, warmup=t.warmup_steps,
              decay=t.lr_decay, dvae_lr=cfg.dvae.lr if joint else 0.0, augment=t.color_augment),
        Phase("polish", t.polish_steps, t.polish_loss,
              SLATE_PARTS[1:] if t.polish_loss == "slate" else MIXTURE_PARTS, lr=t.polish_lr,
              foreground_weight=t.polish_foreground_weight, mixture_error=t.polish_mixture_error,
              augment=t.color_augment),
        Phase("dynamics", t.dynamics_steps, "dynamics", ("dynamics",), lr=t.dynamics_lr,
              position_prior=prior if t.dynamics_prior else 0.0),
        Phase("render_masks", t.render_mask_steps, "render_masks", ("renderer",), lr=t.render_lr,
              position_prior=prior),
        Phase("render", t.render_steps - t.render_mask_steps, "render", ("renderer",), lr=t.render_lr,
              position_prior=prior),
        Phase("refit", t.refit_steps, "dynamics", ("dynamics",), lr=t.dynamics_lr, position_prior=prior),
    ]
    starts = itertools.accumulate((p.steps for p in plan), initial=0)
    return [replace(p, start=start) for p, start in zip(plan, starts)]


def lr_at(step: int, cfg: DSlateConfig) -> float:
    """lr of every part but the dVAE at the run's `step`: its phase's (`Phase.lr_at`); past
    the last phase, the last phase's schedule continued."""
    run = phases(cfg)
    phase = next((p for p in run if step < p.end), run[-1])
    return phase.lr_at(step - phase.start)


class BatchOrder:
    """Indices of the windows used at each step: a stream of permutations of the dataset,
    permutation j drawn from `default_rng([seed, j])`. Step i reads stream[i*B:(i+1)*B]."""

    def __init__(self, n: int, batch: int, seed: int):
        self.n, self.batch, self.seed, self._cache = n, batch, seed, {}

    def _perm(self, j: int) -> np.ndarray:
        if j not in self._cache:
            self._cache = {j: np.random.default_rng([self.seed, j]).permutation(self.n)}
        return self._cache[j]

    def __call__(self, step: int) -> np.ndarray:
        start = step * self.batch
        out = []
        while len(out) < self.batch:
            j, r = divmod(start + len(out), self.n)
            out.extend(self._perm(j)[r:r + self.batch - len(out)].tolist())
        return np.asarray(out)


def build_optimizer(model: DSlate, cfg: DSlateConfig) -> torch.optim.Adam:
    """Adam with groups: the dVAE (its phase's `dvae_lr`), everything else but the renderer,
    and the renderer (both at its phase's `lr_at`), last, so that a run extended by it keeps
    the others' state."""
    dvae = list(model.dvae.parameters())
    renderer = list(model.renderer.parameters()) if model.renderer is not None else []
    ids = {id(p) for p in dvae + renderer}
    rest = [p for p in model.parameters() if id(p) not in ids]
    groups = [{"params": dvae, "lr": cfg.dvae.lr, "name": "dvae"},
              {"params": rest, "lr": lr_at(0, cfg), "name": "slate"}]
    if renderer:
        groups.append({"params": renderer, "lr": lr_at(0, cfg), "name": "renderer"})
    return torch.optim.Adam(groups)


# ---------------------------------------------------------------------- checkpoints
def _rng_state(device: torch.device) -> dict:
    state = {"torch": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def _set_rng_state(state: dict, device: torch.device) -> None:
    torch.set_rng_state(state["torch"].cpu())
    if device.type == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"].cpu(), device)


def training_code_version() -> str:
    """Hash of the sources that shape a training run (`TRAINING_CODE`): `--resume` and the
    checkpoint cache of `obtain_dslate` are keyed by it."""
    return source_hash(*TRAINING_CODE)


def code_version(out_path, allow_dirty: bool = False) -> dict:
    """Commit (refusing a dirty tree for `ncs_lite/assets/`), training-code hash and package
    versions, stored in every checkpoint."""
    return {**provenance(out_path, allow_dirty), "training_code": training_code_version(),
            **package_versions()}


@contextlib.contextmanager
def run_lock(out_path: Path):
    """Hold `<out>.lock` for a run: a second run on the same `out` fails at once, naming it."""
    lock = Path(str(out_path) + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            other = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            raise ValueError(f"another training run (pid {other}) is writing {out_path}; wait for it "
                             "or choose another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
        with contextlib.suppress(OSError):
            lock.unlink()
    finally:
        os.close(fd)


def _resume_differences(ckpt: dict, cfg, precision: str, env: str, data_meta: dict) -> list[str]:
    """What makes a checkpoint unfit to resume bit-for-bit: ['precision: fp32 != bf16', ...]."""
    diff = saved_config_diff(ckpt["config"], cfg)
    old_data = ckpt.get("data") or {}
    pairs = [("precision", ckpt.get("precision"), precision), ("env", ckpt.get("env"), env),
             ("buffer manifest", old_data.get("manifest_sha256"), data_meta["manifest_sha256"]),
             ("training code", (ckpt.get("code_version") or {}).get("training_code"),
              training_code_version())]
    return diff + [f"{name}: {a!r} != {b!r}" for name, a, b in pairs if a != b]


def _check_continuable(ckpt: dict, what: str) -> None:
    """ValueError (`what`: ...) unless the checkpoint holds the state a run continues from."""
    missing = [k for k in ("optimizer", "rng", "step", "seconds") if k not in ckpt]
    if missing:
        raise ValueError(f"{what}: it lacks {missing}, which every checkpoint `train` writes holds; "
                         "use --force to start afresh")


# Fields that act only from a phase after the polish on, each with that phase (`_all_phases`):
# a finished run may be extended by them (`--extend`) without retraining what came before.
EXTENDABLE = {"train.dynamics_steps": "dynamics", "train.dynamics_lr": "dynamics",
              "train.render_steps": "render_masks", "train.render_lr": "render_masks",
              "train.render_mask_steps": "render_masks",
              "mixture.render_hidden": "render_masks", "slots.position_prior": "render_masks",
              "train.refit_steps": "refit", "train.dynamics_prior": "dynamics"}
# what an extension may add to the model: the renderer (mixture.render_hidden), new at its phase
ADDED_BY_EXTENDING = ("renderer.",)


def _extend_problems(ckpt: dict, cfg, precision: str, env: str, data_meta: dict) -> list[str]:
    """Why a finished checkpoint cannot be extended into this run: everything `--resume`
    checks, except the EXTENDABLE fields and the training code (recorded in `lineage`)."""
    allowed = tuple(f"{f}:" for f in EXTENDABLE) + ("training code:",)
    differences = _resume_differences(ckpt, cfg, precision, env, data_meta)
    problems = [d for d in differences if not d.startswith(allowed)]
    step, done = int(ckpt["step"]), from_dict(ckpt["config"]).train.total_steps()
    if step < done:
        problems.append(f"it stopped at step {step} of its {done}: --resume it first")
    changed = [f for f in EXTENDABLE if any(d.startswith(f"{f}:") for d in differences)]
    start = {p.name: p.start for p in _all_phases(cfg)}
    acts_from = dict(EXTENDABLE, **({"slots.position_prior": "dynamics"} if cfg.train.dynamics_prior else {}))
    starts = {f: start[acts_from[f]] for f in changed}
    late = [f"{f} (from step {starts[f]})" for f in changed if step > starts[f]]
    if late:
        problems.append(f"it is at step {step}, past where the changed fields act: {', '.join(late)}; "
                        "they would act on steps it has already taken")
    elif cfg.train.total_steps() <= step:
        problems.append(f"this run ends at step {cfg.train.total_steps()} and adds nothing to its {step}")
    return problems


@dataclass
class _Run:
    """What a run records beside its weights (its config, where it writes, the buffer, the
    code it comes from), held in one place so that the loop and `_save` take it whole."""
    cfg: DSlateConfig
    out_path: Path
    device: torch.device
    precision: str
    env: str
    data_meta: dict
    version: dict
    overrides: list
    lineage: list = field(default_factory=list)   # the finished runs it extends (`--extend`), oldest first

    @property
    def csv_path(self) -> Path:
        return self.out_path.with_suffix(".csv")


def _save(run: _Run, model, opt, step: int, seconds: float, last: dict, starts: dict) -> None:
    ckpt = {
        "kind": CHECKPOINT_KIND,
        "format": CHECKPOINT_FORMAT,
        "model_version": MODEL_VERSION,
        "code_version": run.version,
        "overrides": list(run.overrides),
        "config": to_dict(run.cfg),
        "env": run.env,
        "data": run.data_meta,
        "step": step,
        "precision": run.precision,
        "seconds": seconds,
        "last": last,
        "model": model.state_dict(),
        "optimizer": opt.state_dict(),
        "rng": _rng_state(run.device),
        "lineage": list(run.lineage),
        "starts": starts,
    }
    atomic_torch_save({**ckpt, "content_digest": tensor_digest(ckpt, DIGESTED)}, run.out_path)


# ---------------------------------------------------------------------- the loop
def train(cfg: DSlateConfig, data_dir: str | Path, out_path: str | Path, resume: bool = False,
          device=None, max_steps: int | None = None, env: str = "block-rearrange",
          precision: str | None = None, compile: bool = False, force: bool = False,
          overrides: list[str] | tuple = (), allow_dirty: bool = False,
          extend: str | Path | None = None) -> Path:
    """Train dSLATE on the buffer in `data_dir`; write checkpoints to `out_path`.

    Runs the config's `phases` to `cfg.train.total_steps()` or, if given, to global step
    `max_steps` (schedules still follow the full run, so a run stopped with `max_steps` and
    resumed matches an uninterrupted one). Returns `out_path`.
    `precision` overrides `cfg.train.precision` ('auto', 'bf16', 'fp32').
    `compile` runs the forward through `torch.compile` (inductor: fuses the elementwise work
    around the matmuls; what it gains: docs/benchmarks.md, `bench train`). The first steps
    pay the compilation; checkpoints are unchanged.
    `force` starts afresh over an existing run at `out_path`; `overrides` (the `--set`
    strings that made `cfg`) are recorded in the checkpoint.
    `extend`: a finished checkpoint (another path) to continue into `out_path` under a schedule
    that only adds steps after its last one (the EXTENDABLE fields, e.g. a dynamics phase);
    its loss log is copied first, and the new checkpoint's `lineage` records the extended
    file's step, hash, code version and the fields' old values.
    """
    cfg.validate()
    out_path = check_out_file(out_path, "checkpoint")
    device = resolve_device(device)
    precision = resolve_precision(precision or cfg.train.precision, device)
    total = cfg.train.total_steps()
    stop = total if max_steps is None else int(max_steps)
    if not 1 <= stop <= total:
        raise ValueError(f"max_steps must be in 1..{total} (the last step of the config's phases), got {max_steps}")
    run = _Run(cfg, out_path, device, precision, env, _buffer_meta(cfg, data_dir, env),
               code_version(out_path, allow_dirty), list(overrides))
    with run_lock(out_path):
        ckpt = _previous_run(run, resume, extend, force)
        dataset = EpisodeDataset(data_dir, window=cfg.train.window)
        check_actions(data_dir, dataset.actions.numpy())
        order = BatchOrder(len(dataset), cfg.train.batch_size, cfg.train.seed)
        return _loop(run, dataset, order, stop, ckpt, compile, extending=extend is not None)



def _buffer_meta(cfg: DSlateConfig, data_dir, env: str) -> dict:
    """The buffer's path (relative to the repo), size, seed and manifest hash, recorded in
    every checkpoint; ValueError when it was collected on another env or image size."""
    if env not in ENVIRONMENTS:
        raise ValueError(f"unknown environment {env!r}; expected one of {', '.join(ENVIRONMENTS)}")
    manifest = load_manifest(data_dir)
    collected_on = (manifest.get("env") or {}).get("env", env)
    if collected_on != env:
        raise ValueError(f"the buffer {data_dir} was collected on {collected_on!r}, not --env {env!r}")
    size = manifest["env"].get("image_size", cfg.image_size)
    if size != cfg.image_size:
        raise ValueError(f"the buffer {data_dir} holds {size}x{size} images, but the config's image_size is "
                         f"{cfg.image_size}; train with --set image_size={size} or on another buffer")
    return {"dir": relative_to_repo(data_dir), "episodes": int(manifest["episodes"]),
            "seed": int(manifest["seed"]), "manifest_sha256": manifest_hash(data_dir)}


def _previous_run(run: _Run, resume: bool, extend, force: bool) -> dict | None:
    """The checkpoint the run continues (`resume`: its own; `extend`: a finished run's, whose
    loss log it copies), or None to start afresh (`force` deletes an old run first); sets
    `run.lineage`. ValueError naming why when that checkpoint does not fit the run."""
    out_path, csv_path, ckpt = run.out_path, run.csv_path, None
    if extend is not None:
        if resume:
            raise ValueError("--extend starts a new run from a finished one; it cannot --resume as well")
        extend = Path(extend)
        if extend.resolve() == out_path.resolve():
            raise ValueError(f"--extend {extend} and --out are the same file; write the extended run "
                             "to another --out (the finished run is kept)")
        ckpt = read_checkpoint(extend, map_location=run.device)
        _check_continuable(ckpt, f"cannot extend {extend}")
        problems = _extend_problems(ckpt, run.cfg, run.precision, run.env, run.data_meta)
        if problems:
            raise ValueError(f"cannot extend {extend}: {'; '.join(problems)}")
        run.lineage = list(ckpt.get("lineage") or []) + [{
            "path": relative_to_repo(extend), "sha256": sha256_file(extend), "step": int(ckpt["step"]),
            "code_version": ckpt.get("code_version"),
            "fields": {f: ckpt["config"].get(f.split(".")[0], {}).get(f.split(".")[1]) for f in EXTENDABLE}}]
    if resume:
        if not out_path.exists():
            raise FileNotFoundError(f"--resume given but there is no checkpoint at {out_path}")
        ckpt = read_checkpoint(out_path, map_location=run.device)
        _check_continuable(ckpt, f"cannot resume {out_path}")
        run.lineage = list(ckpt.get("lineage") or [])
        diff = _resume_differences(ckpt, run.cfg, run.precision, run.env, run.data_meta)
        if diff:
            raise ValueError(f"cannot resume {out_path}: it differs from this run (checkpoint vs "
                             f"requested): {'; '.join(diff)}. Use the same settings, another --out, "
                             "or --force to start afresh")
        return ckpt
    if out_path.exists() or csv_path.exists():
        if not force:
            what = out_path if out_path.exists() else csv_path
            raise ValueError(f"{what} already exists: pass --resume to continue that run or "
                             "--force to delete it and start afresh")
        for p in (out_path, csv_path):
            p.unlink(missing_ok=True)
    if extend is not None:          # the finished run's log, continued (cut at its step by _loop)
        out_path.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(extend.with_suffix(".csv"), csv_path)
    return ckpt


def _loop(run: _Run, dataset, order: BatchOrder, stop: int, ckpt: dict | None, compile: bool,
          extending: bool) -> Path:
    """Train from `ckpt` (None: from the seeded initialisation) to step `stop`, phase by
    phase: a row of the loss log every step, a checkpoint every `checkpoint_every` and at `stop`."""
    cfg = run.cfg
    seed_everything(cfg.train.seed)
    model = DSlate(cfg).to(run.device)
    forward = torch.compile(model) if compile else model          # same parameters
    opt = build_optimizer(model, cfg)
    first, seconds, last_saved, starts = 0, 0.0, None, {}
    chooser = next((p for p in phases(cfg) if p.starts > 1), None)     # the phase whose starts compete
    ends = {chooser.start + c * chooser.start_steps for c in range(1, chooser.starts + 1)} if chooser else set()
    if ckpt is not None:
        starts = ckpt.get("starts") or {}
        _restore(model, opt, ckpt, run.out_path, extending)
        _set_rng_state(ckpt["rng"], run.device)
        first, seconds = int(ckpt["step"]), float(ckpt["seconds"])
        last_saved = first
        _truncate_csv(run.csv_path, first)
    else:
        run.out_path.parent.mkdir(parents=True, exist_ok=True)
        with open(run.csv_path, "w", newline="") as f:
            csv.writer(f).writerow(CSV_FIELDS)
    model.train()
    bar = progress(total=stop, initial=min(first, stop), desc=f"train dSLATE ({cfg.name}, {run.precision})",
                   unit="step")
    try:
        with open(run.csv_path, "a", newline="") as csv_file:
            log = csv.writer(csv_file)
            for phase in phases(cfg):
                for step in range(max(first, phase.start), min(stop, phase.end)):
                    if step in ends:                                  # a segmentation start has ended
                        csv_file.flush()
                        starts = select_start(model, opt, chooser, step, starts, run.csv_path)
                    t0 = time.perf_counter()
                    frames, actions, augmented = _batch(dataset, order, step, phase, run)
                    tau, lr = tau_schedule(step, cfg.dvae), phase.lr_at(step - phase.start)
                    try:
                        out, grad_norm = train_step(model, opt, phase, step - phase.start, frames, actions, tau,
                                                    run.precision, augmented, forward)
                    except FloatingPointError as e:
                        kept = (f"the last good checkpoint {run.out_path} (step {last_saved}) was kept"
                                if last_saved is not None else "no checkpoint had been written yet")
                        raise FloatingPointError(f"{e} at step {step + 1}; training stopped and {kept}. Lower "
                                                 "the learning rate or use precision fp32.") from None
                    seconds += time.perf_counter() - t0
                    done, vals = step + 1, {k: float(v.detach()) for k, v in out.items()}
                    log.writerow([done, *(f"{vals[k]:.4f}" for k in LOSSES), f"{tau:.4f}", f"{lr:.3e}",
                                  f"{float(grad_norm):.4g}", f"{seconds:.1f}"])
                    bar.update(1)
                    if done % 10 == 0 or done == stop:
                        csv_file.flush()
                        bar.set_postfix(loss=f"{vals['loss']:.1f}", mse=f"{vals['mse']:.1f}",
                                        ce=f"{vals['ce']:.1f}", tau=f"{tau:.2f}")
                    if done % cfg.train.checkpoint_every == 0 or done == stop:
                        csv_file.flush()
                        _save(run, model, opt, done, seconds, {k: round(v, 4) for k, v in vals.items()}, starts)
                        last_saved = done
    finally:
        bar.close()
    return run.out_path


def select_start(model: DSlate, opt: torch.optim.Adam, phase: Phase, step: int, record: dict,
                 csv_path: Path) -> dict:
    """The run's `step` ends start c - 1 of `phase` (c = (step - phase.start) / its start_steps):
    score that start by its mean mixture error (the log's "mix") over its last quarter of
    steps, read from the loss log, and keep its weights of `phase.trains` when it is the best
    so far; then begin start c from those parts' initialisation for (train.seed, c) or, after
    the last start, restore the best one's weights. Adam's state of the parts starts afresh
    either way. `record` (the scores so far, the best start and its weights) is saved in
    every checkpoint, so a resumed run chooses as an uninterrupted one; returns the new one.
    The score reads images only (no success, no ground truth)."""
    c = (step - phase.start) // phase.start_steps
    window = max(1, phase.start_steps // 4)
    with open(csv_path, newline="") as f:
        mix = [float(r["mix"]) for r in csv.DictReader(f) if step - window < int(r["step"]) <= step]
    if len(mix) != window:
        raise ValueError(f"the loss log {csv_path} lacks steps {step - window + 1}..{step} of segmentation "
                         f"start {c - 1}; resume from a checkpoint whose log is complete")
    scores = list(record.get("scores", [])) + [sum(mix) / window]
    best = int(np.argmin(scores))
    if best == c - 1:
        kept = {k: v.detach().clone() for k, v in _of_parts(model.state_dict(), phase.trains).items()}
    else:
        kept = record["weights"]
    last = c == phase.starts
    model.load_state_dict(kept if last else _initial_weights(model.cfg, phase.trains, c), strict=False)
    for p in _of_parts(dict(model.named_parameters()), phase.trains).values():
        opt.state.pop(p, None)
    print(f"segmentation start {c - 1} of {phase.starts}: mixture error {scores[-1]:.2f}"
          + (f"; keeping start {best} ({scores[best]:.2f})" if last else ""), flush=True)
    return {"scores": scores, "best": best, "weights": {} if last else kept}


def _initial_weights(cfg: DSlateConfig, parts: tuple[str, ...], start: int) -> dict:
    """The weights of `parts` that a model initialised for (train.seed, `start`) begins with;
    the global RNG streams are left as they were."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(np.random.default_rng([cfg.train.seed, start]).integers(2 ** 31)))
        fresh = DSlate(cfg)
    return _of_parts(fresh.state_dict(), parts)


def _of_parts(tensors: dict, parts: tuple[str, ...]) -> dict:
    """The entries of a {name: tensor} dict of DSlate (state_dict, named_parameters) that
    belong to `parts` (its attributes, e.g. MIXTURE_PARTS)."""
    return {k: v for k, v in tensors.items() if k.split(".")[0] in parts}


def _batch(dataset, order: BatchOrder, step: int, phase: Phase, run: _Run):
    """Step `step`'s videos (B, T, H, W, 3) uint8 and actions (B, T-1, A) on the run's device,
    and the mixture loss's colour-augmented copy of the videos when the phase augments (else
    None), drawn from (seed, step) alone like the batch, so a resumed run sees the same."""
    step = phase.data_step(step)
    items = [dataset[int(i)] for i in order(step)]
    frames = torch.stack([it["frames"] for it in items]).to(run.device, non_blocking=True)
    actions = torch.stack([it["actions"] for it in items]).to(run.device, non_blocking=True)
    if phase.augment == "none":
        return frames, actions, None
    rng = np.random.default_rng([run.cfg.train.seed, step, 1])
    return frames, actions, augment_colors(phase.augment, frames, rng)


def train_step(model: DSlate, opt: torch.optim.Adam, phase: Phase, i: int, frames: torch.Tensor,
               actions: torch.Tensor, tau: float, precision: str = "fp32",
               mixture_videos: torch.Tensor | None = None, forward=None) -> tuple[dict, torch.Tensor]:
    """One optimizer step at step `i` of `phase`: its lrs (`build_optimizer`'s groups) and
    position prior, its loss under `precision`'s autocast, backward, gradient clipping
    (`train.grad_clip` of the `train.grad_clip_norm` norm) and Adam. `forward`: the model's
    forward to call (default the model; `torch.compile`d in `train --compile`).

    frames (B, T, H, W, 3) uint8, actions (B, T-1, A) -> (the LOSSES, the gradient norm
    before clipping). FloatingPointError, before the update, on a non-finite loss or
    gradient. `bench train` times this step.
    """
    for g in opt.param_groups:
        g["lr"] = phase.dvae_lr if g.get("name") == "dvae" else phase.lr_at(i)
    model.position_prior = phase.position_prior
    with autocast(frames.device, precision):
        if phase.loss == "dynamics":
            out = model.dynamics_loss(frames, actions)
        elif phase.loss in ("render_masks", "render"):
            out = model.render_loss(frames, masks=phase.loss == "render_masks")
        elif phase.loss == "mixture":
            out = model.mixture_loss(frames, phase.foreground_weight, mixture_videos, phase.mixture_error)
        else:
            out = (model if forward is None else forward)(
                frames, actions, tau, dvae_only=phase.loss == "dvae", foreground_weight=phase.foreground_weight,
                mixture_videos=mixture_videos, mixture_error=phase.mixture_error)
    loss = out["loss"]
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite loss ({float(loss.detach())})")
    opt.zero_grad(set_to_none=True)
    loss.backward()
    t = model.cfg.train
    grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), t.grad_clip, norm_type=float(t.grad_clip_norm))
    if not torch.isfinite(grad_norm):
        raise FloatingPointError(f"non-finite gradient norm ({float(grad_norm.detach())})")
    opt.step()
    return out, grad_norm


def _restore(model, opt, ckpt, out_path, extending: bool) -> None:
    """Load a checkpoint's model and optimizer; an extended run may lack the parts that its
    extension adds (ADDED_BY_EXTENDING), which then start from their initialisation."""
    try:
        result = model.load_state_dict(ckpt["model"], strict=not extending)
    except RuntimeError as e:
        raise ValueError(f"checkpoint {out_path} does not match this code's model: {e}") from e
    foreign = list(result.unexpected_keys) + [k for k in result.missing_keys
                                              if not k.startswith(ADDED_BY_EXTENDING)]
    if foreign:
        raise ValueError(f"checkpoint {out_path} does not match this code's model: {foreign[:4]}")
    added = []
    if result.missing_keys and len(ckpt["optimizer"]["param_groups"]) < len(opt.param_groups):
        added = [opt.param_groups.pop()]                 # the new renderer's group, last
    opt.load_state_dict(ckpt["optimizer"])
    for group in added:
        opt.add_param_group(group)


def _truncate_csv(csv_path: Path, step: int) -> None:
    """Drop rows after `step` (written after the checkpoint an interrupted run resumes from)."""
    if not csv_path.exists():
        with open(csv_path, "w", newline="") as f:
            csv.writer(f).writerow(CSV_FIELDS)
        return
    with open(csv_path, newline="") as f:
        rows = list(csv.reader(f))
    keep = [CSV_FIELDS] + [r for r in rows[1:] if r and int(r[0]) <= step]
    with open(csv_path, "w", newline="") as f:
        csv.writer(f).writerows(keep)


# ---------------------------------------------------------------------- load or train
def obtain_dslate(preset: str = "reduced", train_from_scratch: bool = False, seed: int = 0,
                  env: str = "block-rearrange", device=None) -> tuple[DSlate, Path]:
    """The notebooks' "load the checkpoint if present, else train": returns (model, path).

    * `reduced` without `train_from_scratch`: `env`'s shipped checkpoint, when present.
    * otherwise: train at `preset` (train.seed = `seed`) on the cached buffer of
      `train.num_objects` objects (`data.cached_buffer(TRAIN_EPISODES[preset], seed=seed)`),
      writing `<cache>/checkpoints/dslate-<env>-<preset>-s<seed>.pt`. A finished checkpoint there is
      reused (unless `train_from_scratch`), an interrupted one is resumed, and one made with
      another config, env, buffer or training code is retrained; each decision is printed.
    With preset="reduced", seed=0 this is the command that made the shipped checkpoint.
    """
    shipped = SHIPPED_MODELS.get(env)
    if preset == "reduced" and not train_from_scratch and shipped is not None and shipped.exists():
        return load_dslate(shipped, device), shipped
    cfg = get_preset(preset, env)
    cfg.train.seed = int(seed)
    path = cache_dir() / "checkpoints" / f"dslate-{env}-{preset}-s{seed}.pt"
    data = cached_buffer(TRAIN_EPISODES[preset], env=env, num_objects=cfg.train.num_objects, seed=int(seed))

    def unfinished(ckpt: Path) -> str | None:
        step, total = int(read_checkpoint(ckpt)["step"]), cfg.train.total_steps()
        return None if step >= total else f"at step {step} of {total}"

    model = load_or_train(path, unfit=lambda ckpt: _unfit(ckpt, cfg, env, data), unfinished=unfinished,
                          train=lambda resume, force: train(cfg, data, path, resume=resume, force=force,
                                                            device=device, env=env),
                          load=lambda ckpt: load_dslate(ckpt, device), who="obtain_dslate",
                          from_scratch=train_from_scratch)
    return model, path


def _unfit(path: Path, cfg, env: str, data: Path) -> str | None:
    """Why the cached checkpoint at `path` cannot be reused or resumed, or None."""
    try:
        ckpt = read_checkpoint(path)
    except ValueError as e:
        return f"it cannot be read ({e})"
    diff = saved_config_diff(ckpt["config"], cfg)
    if diff:
        return f"it was trained with another config ({'; '.join(diff[:3])})"
    if ckpt.get("env") != env:
        return f"it was trained on {ckpt.get('env')!r}, not {env!r}"
    if (ckpt.get("data") or {}).get("manifest_sha256") != manifest_hash(data):
        return "it was trained on another buffer (manifest hash differs)"
    if (ckpt.get("code_version") or {}).get("training_code") != training_code_version():
        return "the training code changed since it was trained"
    return None
