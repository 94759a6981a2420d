"""Training dSLATE on an experience buffer: `python -m ncs_lite train ...`.

    python -m ncs_lite train --env block-rearrange --preset reduced \
        --data .cache/buffers/block-rearrange-4 --out dslate.pt [--resume] [--steps N]

What the loop guarantees:
* Determinism and exact resume. The batch of step i is fixed by (seed, i) alone: the
  windows are read in a stream of seeded permutations of the dataset. A checkpoint holds
  the model, the Adam state, the step, torch's RNG state (gumbel noise, slot samples,
  dropout) and the config, so `--resume` continues bit-for-bit like an uninterrupted run.
* Schedules are functions of the step: gumbel tau (cosine, `tau_schedule`), the lr of
  slot attention / decoder / dynamics (linear warm-up, then constant or cosine), and the
  dVAE's constant lr (no warm-up), as in Table 2. Optional polish steps follow the schedule
  (`TrainConfig.polish_steps`: constant lr, dVAE frozen, another foreground weight), then
  optional dynamics steps (`TrainConfig.dynamics_steps`: the dynamics alone, latent loss),
  then optional render steps (`TrainConfig.render_steps`: the renderer alone, mask then
  pixel loss), then optional refit steps (`TrainConfig.refit_steps`: the dynamics alone
  again, on states read with `slots.position_prior`, which acts from the render phase on).
  With `TrainConfig.color_augment` the mixture loss reads each video with its colour
  channels permuted (and, with "channels_gamma", each raised to a random power;
  data/augment.py), drawn from (seed, step) like the batch. Why each phase: docs/recipe.md.
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
  schedule that only adds later phases (`EXTENDABLE`: the dynamics, render and refit phases
  and the position prior; the renderer, which only the render phase trains, may be new),
  recording the run it extends in `lineage`. Each checkpoint records the commit
  (`provenance`: writing into `ncs_lite/assets/` from a dirty tree is refused), the `--set`
  overrides, and the buffer's path (relative to the repo) and manifest hash.
"""
from __future__ import annotations

import contextlib
import csv
import fcntl
import os
import shutil
import time
from pathlib import Path

import numpy as np
import torch

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

__all__ = ["train", "obtain_dslate", "resolve_precision", "lr_at", "build_optimizer", "autocast",
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


# ---------------------------------------------------------------------- schedules and data order
def lr_at(step: int, cfg: DSlateConfig) -> float:
    """lr of slot attention, decoder and dynamics at `step`: linear warm-up to the peak,
    then constant ('none') or a cosine decay to 10% of the peak at the schedule's last step
    ('cosine'); then `polish_lr` for the polish steps, `dynamics_lr` and `render_lr` for the
    dynamics and render phases, `dynamics_lr` again for the refit phase."""
    t = cfg.train
    if t.refit_steps and step >= t.render_end():
        return t.dynamics_lr
    if t.render_steps and step >= t.dynamics_end():
        return t.render_lr
    if t.dynamics_steps and step >= t.polish_end():
        return t.dynamics_lr
    if step >= t.main_steps():
        return t.polish_lr
    step = step - t.dvae_warmup_steps          # this schedule starts after the dVAE warm-up
    if step < 0:
        return 0.0
    warm = min(1.0, (step + 1) / t.warmup_steps) if t.warmup_steps > 0 else 1.0
    if t.lr_decay == "cosine" and step >= t.warmup_steps:
        total = t.main_steps() - t.dvae_warmup_steps
        return cosine_anneal(step - t.warmup_steps, t.lr, 0.1 * t.lr, max(1, total - t.warmup_steps))
    return t.lr * warm


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
    """Adam with groups: the dVAE (constant lr), everything else (warm-up lr) but the renderer,
    and the renderer (same lr), last, so that a run extended by it keeps the others' state."""
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


# Fields that act only on the phases after the polish, each with the phase it acts from: a
# finished run may be extended by them (`--extend`) without retraining what came before.
EXTENDABLE = {"train.dynamics_steps": "polish_end", "train.dynamics_lr": "polish_end",
              "train.render_steps": "dynamics_end", "train.render_lr": "dynamics_end",
              "train.render_mask_steps": "dynamics_end",
              "mixture.render_hidden": "dynamics_end", "slots.position_prior": "dynamics_end",
              "train.refit_steps": "render_end"}
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
    starts = {f: getattr(cfg.train, EXTENDABLE[f])() for f in changed}
    late = [f"{f} (from step {starts[f]})" for f in changed if step > starts[f]]
    if late:
        problems.append(f"it is at step {step}, past where the changed fields act: {', '.join(late)}; "
                        "they would act on steps it has already taken")
    elif cfg.train.total_steps() <= step:
        problems.append(f"this run ends at step {cfg.train.total_steps()} and adds nothing to its {step}")
    return problems


def _save(path, model, opt, cfg, step, device, precision, env, data_meta, seconds, last,
          version, overrides, lineage=()) -> None:
    ckpt = {
        "kind": CHECKPOINT_KIND,
        "format": CHECKPOINT_FORMAT,
        "model_version": MODEL_VERSION,
        "code_version": version,
        "overrides": list(overrides),
        "config": to_dict(cfg),
        "env": env,
        "data": data_meta,
        "step": step,
        "precision": precision,
        "seconds": seconds,
        "last": last,
        "model": model.state_dict(),
        "optimizer": opt.state_dict(),
        "rng": _rng_state(device),
        "lineage": list(lineage),    # the finished runs this one extends (`--extend`), oldest first
    }
    atomic_torch_save({**ckpt, "content_digest": tensor_digest(ckpt, DIGESTED)}, path)


# ---------------------------------------------------------------------- the loop
def train(cfg: DSlateConfig, data_dir: str | Path, out_path: str | Path, resume: bool = False,
          device=None, max_steps: int | None = None, env: str = "block-rearrange",
          precision: str | None = None, compile: bool = False, force: bool = False,
          overrides: list[str] | tuple = (), allow_dirty: bool = False,
          extend: str | Path | None = None) -> Path:
    """Train dSLATE on the buffer in `data_dir`; write checkpoints to `out_path`.

    Runs until `cfg.train.total_steps()` (the schedule's epochs x episodes per epoch / batch,
    then `polish_steps`, `dynamics_steps`, `render_steps` and `refit_steps`) or, if given,
    until global step `max_steps` (schedules still follow the full run, so a run stopped with
    `max_steps` and resumed matches an uninterrupted one).
    Returns `out_path`.
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
    if stop < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")

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
    data_meta = {"dir": relative_to_repo(data_dir), "episodes": int(manifest["episodes"]),
                 "seed": int(manifest["seed"]), "manifest_sha256": manifest_hash(data_dir)}
    csv_path = out_path.with_suffix(".csv")
    version = code_version(out_path, allow_dirty)
    lineage = []
    with run_lock(out_path):
        if extend is not None:
            if resume:
                raise ValueError("--extend starts a new run from a finished one; it cannot --resume as well")
            extend = Path(extend)
            if extend.resolve() == out_path.resolve():
                raise ValueError(f"--extend {extend} and --out are the same file; write the extended run "
                                 "to another --out (the finished run is kept)")
            ckpt = read_checkpoint(extend, map_location=device)
            _check_continuable(ckpt, f"cannot extend {extend}")
            problems = _extend_problems(ckpt, cfg, precision, env, data_meta)
            if problems:
                raise ValueError(f"cannot extend {extend}: {'; '.join(problems)}")
            lineage = list(ckpt.get("lineage") or []) + [{
                "path": relative_to_repo(extend), "sha256": sha256_file(extend), "step": int(ckpt["step"]),
                "code_version": ckpt.get("code_version"),
                "fields": {f: ckpt["config"].get(f.split(".")[0], {}).get(f.split(".")[1]) for f in EXTENDABLE}}]
        if resume:
            if not out_path.exists():
                raise FileNotFoundError(f"--resume given but there is no checkpoint at {out_path}")
            ckpt = read_checkpoint(out_path, map_location=device)
            _check_continuable(ckpt, f"cannot resume {out_path}")
            lineage = list(ckpt.get("lineage") or [])
            diff = _resume_differences(ckpt, cfg, precision, env, data_meta)
            if diff:
                raise ValueError(f"cannot resume {out_path}: it differs from this run (checkpoint vs "
                                 f"requested): {'; '.join(diff)}. Use the same settings, another --out, "
                                 "or --force to start afresh")
        elif out_path.exists() or csv_path.exists():
            if not force:
                what = out_path if out_path.exists() else csv_path
                raise ValueError(f"{what} already exists: pass --resume to continue that run or "
                                 "--force to delete it and start afresh")
            for p in (out_path, csv_path):
                p.unlink(missing_ok=True)
        if extend is not None:          # the finished run's log, continued (cut at its step by _loop)
            out_path.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(extend.with_suffix(".csv"), csv_path)
        dataset = EpisodeDataset(data_dir, window=cfg.train.window)
        check_actions(data_dir, dataset.actions.numpy())
        order = BatchOrder(len(dataset), cfg.train.batch_size, cfg.train.seed)
        return _loop(cfg, dataset, order, out_path, csv_path, device, precision, compile, env,
                     data_meta, version, overrides, stop, ckpt if (resume or extend is not None) else None,
                     lineage, extending=extend is not None)


def _loop(cfg, dataset, order, out_path, csv_path, device, precision, compile, env, data_meta,
          version, overrides, stop, ckpt, lineage=(), extending=False) -> Path:
    seed_everything(cfg.train.seed)
    model = DSlate(cfg).to(device)
    forward = torch.compile(model) if compile else model          # same parameters
    opt = build_optimizer(model, cfg)
    step, seconds = 0, 0.0
    resume = ckpt is not None
    if resume:
        _restore(model, opt, ckpt, out_path, extending)
        _set_rng_state(ckpt["rng"], device)
        step, seconds = int(ckpt["step"]), float(ckpt["seconds"])
        _truncate_csv(csv_path, step)
    else:
        out_path.parent.mkdir(parents=True, exist_ok=True)
        with open(csv_path, "w", newline="") as f:
            csv.writer(f).writerow(CSV_FIELDS)

    model.train()
    params = list(model.parameters())
    last_saved = step if resume else None
    bar = progress(total=stop, initial=min(step, stop), desc=f"train dSLATE ({cfg.name}, {precision})",
                   unit="step")
    csv_file = open(csv_path, "a", newline="")
    writer = csv.writer(csv_file)
    try:
        while step < stop:
            t0 = time.perf_counter()
            idx = order(step)
            items = [dataset[int(i)] for i in idx]
            frames = torch.stack([it["frames"] for it in items]).to(device, non_blocking=True)
            actions = torch.stack([it["actions"] for it in items]).to(device, non_blocking=True)
            tau, lr = tau_schedule(step, cfg.dvae), lr_at(step, cfg)
            polishing = step >= cfg.train.main_steps()
            for g in opt.param_groups:
                g["lr"] = (0.0 if polishing else cfg.dvae.lr) if g.get("name") == "dvae" else lr

            dvae_only = step < cfg.train.dvae_warmup_steps
            augmented = None
            if cfg.train.color_augment != "none" and not dvae_only and step < cfg.train.polish_end():
                # drawn from (seed, step) alone, like the batch, so a resumed run sees the same
                augmented = augment_colors(cfg.train.color_augment, frames,
                                           np.random.default_rng([cfg.train.seed, step, 1]))
            model.position_prior = cfg.slots.position_prior if step >= cfg.train.dynamics_end() else 0.0
            with autocast(device, precision):
                if cfg.train.dynamics_end() <= step < cfg.train.render_end():   # the renderer alone
                    masks = step < cfg.train.dynamics_end() + cfg.train.render_mask_steps
                    out = model.render_loss(frames, masks=masks)
                elif step >= cfg.train.polish_end():     # the dynamics and refit phases: it alone
                    out = model.dynamics_loss(frames, actions)
                else:
                    out = forward(frames, actions, tau, dvae_only=dvae_only,
                                  foreground_weight=cfg.train.polish_foreground_weight if polishing else None,
                                  mixture_videos=augmented,
                                  mixture_error=cfg.train.polish_mixture_error if polishing else None)
            loss = out["loss"]
            if not torch.isfinite(loss):
                _non_finite("loss", loss, step, out_path, last_saved)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(params, cfg.train.grad_clip,
                                                       norm_type=float(cfg.train.grad_clip_norm))
            if not torch.isfinite(grad_norm):
                _non_finite("gradient norm", grad_norm, step, out_path, last_saved)
            opt.step()
            step += 1
            seconds += time.perf_counter() - t0

            vals = {k: float(v.detach()) for k, v in out.items()}
            writer.writerow([step, *(f"{vals[k]:.4f}" for k in LOSSES),
                             f"{tau:.4f}", f"{lr:.3e}", f"{float(grad_norm):.4g}", f"{seconds:.1f}"])
            bar.update(1)
            if step % 10 == 0 or step == stop:
                csv_file.flush()
                bar.set_postfix(loss=f"{vals['loss']:.1f}", mse=f"{vals['mse']:.1f}",
                                ce=f"{vals['ce']:.1f}", tau=f"{tau:.2f}")
            if step % cfg.train.checkpoint_every == 0 or step == stop:
                csv_file.flush()
                _save(out_path, model, opt, cfg, step, device, precision, env, data_meta, seconds,
                      {k: round(v, 4) for k, v in vals.items()}, version, overrides, lineage)
                last_saved = step
    finally:
        csv_file.close()
        bar.close()
    return out_path


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


def _non_finite(what, value, step, out_path, last_saved):
    kept = (f"the last good checkpoint {out_path} (step {last_saved}) was kept"
            if last_saved is not None else "no checkpoint had been written yet")
    raise FloatingPointError(f"non-finite {what} ({float(value.detach())}) at step {step + 1}; training "
                             f"stopped and {kept}. Lower the learning rate or use precision fp32.")


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
    * otherwise: train at `preset` (train.seed = `seed`) on the cached 4-object buffer
      `data.cached_buffer(TRAIN_EPISODES[preset], seed=seed)`, writing
      `<cache>/checkpoints/dslate-<env>-<preset>-s<seed>.pt`. A finished checkpoint there is
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
    data = cached_buffer(TRAIN_EPISODES[preset], env=env, num_objects=4, seed=int(seed))
    resume = force = False
    if path.exists() and not train_from_scratch:
        why = _unfit(path, cfg, env, data)
        if why is None:
            step = int(read_checkpoint(path)["step"])
            if step >= cfg.train.total_steps():
                return load_dslate(path, device), path
            resume = True
            print(f"obtain_dslate: resuming {path} at step {step} of {cfg.train.total_steps()}")
        else:
            force = True
            print(f"obtain_dslate: retraining {path} from scratch: {why}")
    elif path.exists():
        force = True
        print(f"obtain_dslate: retraining {path} from scratch (train_from_scratch=True)")
    train(cfg, data, path, resume=resume, force=force, device=device, env=env)
    return load_dslate(path, device), path


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
