"""Training: ``train(config, data, out)`` reads top to bottom, one process or many (torchrun).

Resumption is exact: the batch order of epoch ``e`` is a permutation seeded by
``(seed, e)``, augmentation derives from ``(seed, e, index)``, and a checkpoint records the
step, epoch and batch within the epoch; ``resume=True`` skips the batches already done, so a
killed run that resumes ends with the same weights as one that never stopped (tested).
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader
from tqdm import tqdm

from esim_lite.core.atomic import write_text
from esim_lite.core.dataconf import to_yaml
from model import checkpoint
from model.archs import e2sri_arch
from model.archs.e2sri_arch import E2SRI, count_parameters
from model.config import OptimConfig, TrainConfig
from model.losses.similarity import SimilarityLoss
from model.metrics.image import mse, psnr, ssim
from model.training.curves import ValHistory
from model.training.setup import Distributed, TrainData, build_data, epoch_batches, init_distributed
from model.training.warm_start import warm_start

log = logging.getLogger(__name__)


def lr_lambda(optim: OptimConfig, steps_per_epoch: int):
    """Multiplier of the initial rate at a given step, per ``optim.schedule``."""
    e = optim.epochs
    if optim.schedule == "released":
        milestones = [0.5 * e, 0.75 * e]
    elif optim.schedule == "paper":  # x0.1 at every half of the remaining epochs
        milestones, start = [], 0.0
        while e - start > 1:
            start += (e - start) / 2
            milestones.append(start)
    else:
        milestones = []
    bounds = [m * steps_per_epoch for m in milestones]
    return lambda step: 0.1 ** sum(step >= b for b in bounds)


def central_input(batch: dict, config: TrainConfig, first_pass: E2SRI | None) -> torch.Tensor:
    """What the network's central input is for this experiment (see NetConfig.central)."""
    return e2sri_arch.central_input(config.model, batch["stacks"], batch["flows"],
                                    batch["lr"], first_pass)


def run_batch(model, batch: dict, config: TrainConfig, first_pass: E2SRI | None
              ) -> torch.Tensor:
    """The network's output for every sample of ``batch``, ``(B, 1, sH, sW)``."""
    return model(batch["stacks"], central_input(batch, config, first_pass), batch["flows"])


@torch.inference_mode()
def validate(net: E2SRI, loader: DataLoader, config: TrainConfig, device: torch.device,
             first_pass: E2SRI | None, lpips_net, max_batches: int | None = None
             ) -> tuple[dict[str, float], list[tuple[np.ndarray, ...]]]:
    """Mean PSNR/SSIM/MSE/LPIPS over the held-out split, and a few (stack, lr, out, hr)."""
    net.eval()
    sums, count, examples = {"psnr": 0.0, "ssim": 0.0, "mse": 0.0, "lpips": 0.0}, 0, []
    for b, batch in enumerate(loader):
        if max_batches is not None and b >= max_batches:
            break
        batch = {k: v.to(device) for k, v in batch.items()}
        out = run_batch(net, batch, config, first_pass).float().clamp(0, 1)
        hr = batch["hr"]
        values = {"psnr": psnr(out, hr), "ssim": ssim(out, hr), "mse": mse(out, hr)}
        if lpips_net is not None:
            values["lpips"] = lpips_net(out, hr)
        for k, v in values.items():
            sums[k] += float(v.sum())
        count += len(hr)
        if len(examples) < 4:
            mid = config.model.n_stacks // 2
            examples.append((batch["stacks"][0, mid].cpu().numpy(),
                             batch["lr"][0, 0].cpu().numpy(), out[0, 0].cpu().numpy(),
                             hr[0, 0].cpu().numpy()))
    net.train()
    if lpips_net is None:
        sums.pop("lpips")
    return {k: v / max(count, 1) for k, v in sums.items()}, examples


def save_examples(path: Path, examples, title: str) -> Path:
    from esim_lite.core.figures import contact_sheet, gray_to_rgb, write_png

    rows = []
    for stack, lr, out, hr in examples:
        events = ((stack.mean(axis=0) + 1) / 2).clip(0, 1)
        rows.append([(gray_to_rgb(events), "central stack"), (gray_to_rgb(lr), "LR frame"),
                     (gray_to_rgb(out), "output"), (gray_to_rgb(hr), "HR target")])
    return write_png(path, contact_sheet(rows, title, height=min(256, examples[0][3].shape[0])))


@dataclass
class TrainState:
    """Everything a step changes or reads, and the position in the batch plan."""

    net: E2SRI
    model: torch.nn.Module  # ``net``, or its DistributedDataParallel wrapper
    first_pass: E2SRI | None
    criterion: SimilarityLoss
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LambdaLR
    amp_dtype: torch.dtype | None
    scaler: torch.amp.GradScaler | None
    step: int = 0
    epoch: int = 0
    offset: int = 0  # batches of ``epoch`` already done
    seconds_before: float = 0.0  # training time of the runs this one resumes
    start: float = field(default_factory=time.perf_counter)

    def train_seconds(self) -> float:
        return self.seconds_before + time.perf_counter() - self.start


def build_state(cfg: TrainConfig, env: Distributed, steps_per_epoch: int,
                warm: bool = True) -> TrainState:
    """The network (with its first pass and flow initialisation), loss and optimiser.
    ``warm``: apply ``run.init_from`` (not when the run resumes: its weights come from its
    own checkpoint, and the warm start's source need not exist any more)."""
    run = cfg.run
    net = E2SRI(cfg.model)
    if run.init_from and warm:
        warm_start(net, run.init_from)
    net = net.to(env.device)
    cuda = env.device.type == "cuda"
    if run.channels_last:
        net = net.to(memory_format=torch.channels_last)
    model = torch.nn.parallel.DistributedDataParallel(net) if env.world > 1 else net
    first_pass = None
    if cfg.model.central == "first_pass":
        if not run.first_pass:
            raise ValueError("model.central = first_pass needs run.first_pass (a checkpoint)")
        first_pass = checkpoint.load_model(run.first_pass, env.device)
        if first_pass.config.central != "stack" or first_pass.config.scale != cfg.model.scale:
            raise ValueError(f"{run.first_pass}: the first pass must be a main (stack) model "
                             f"of scale {cfg.model.scale}")
    if run.flow_init:
        if net.flow_net is None:
            raise ValueError("run.flow_init needs model.flow = learned")
        net.flow_net.load_state_dict(checkpoint.load_any(run.flow_init)["flow_net"])
    criterion = SimilarityLoss(cfg.loss.lpips_weight, unfired_tv=cfg.loss.unfired_tv,
                               unfired_dilate=cfg.loss.unfired_dilate).to(env.device)
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.optim.lr, betas=cfg.optim.betas,
                                 weight_decay=cfg.optim.weight_decay)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer,
                                                  lr_lambda(cfg.optim, steps_per_epoch))
    amp_dtype = (torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16) \
        if cuda and run.amp else (torch.bfloat16 if not cuda and run.cpu_amp else None)
    scaler = torch.amp.GradScaler("cuda") if amp_dtype == torch.float16 else None
    return TrainState(net, model, first_pass, criterion, optimizer, scheduler, amp_dtype,
                      scaler)


def resume_from(state: TrainState, cfg: TrainConfig, last: Path) -> None:
    """Continue exactly where ``last`` stopped (weights, optimiser, schedule, batch, RNG)."""
    saved = checkpoint.load(last)
    check_resumable(cfg, saved, last)
    state.net.load_state_dict(saved["model"])
    state.optimizer.load_state_dict(saved["optimizer"])
    state.scheduler.load_state_dict(saved["scheduler"])
    state.step, state.epoch, state.offset = (saved["step"], saved["epoch"],
                                             saved["batch_in_epoch"])
    state.seconds_before = float(saved.get("train_seconds", 0.0))
    checkpoint.set_rng_state(saved["rng"])
    log.info("resumed from %s at step %d", last, state.step)


class RunLog:
    """Where a run reports: checkpoints, TensorBoard, the validation curve, the progress bar
    (only the main process writes)."""

    def __init__(self, cfg: TrainConfig, data: TrainData, out: Path, env: Distributed,
                 state: TrainState, total: int, show_progress: bool) -> None:
        self.cfg, self.data, self.out, self.env = cfg, data, out, env
        self.config_yaml = to_yaml(cfg)
        self.writer = self.history = None
        if env.main:
            out.mkdir(parents=True, exist_ok=True)
            write_text(out / "config.yaml", self.config_yaml)
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(out / "tb"))
            self.history = ValHistory(out / "val_history.csv")
        run = cfg.run
        self.val_loader = DataLoader(data.val_set, batch_size=cfg.optim.batch_size,
                                     num_workers=run.workers,
                                     pin_memory=env.device.type == "cuda")
        # with a time budget the number of steps is unknown: no total, so no made-up ETA
        self.bar = tqdm(total=None if run.max_minutes else total, initial=state.step,
                        unit="step", disable=not (show_progress and env.main),
                        desc=f"train (stops after {run.max_minutes:g} min)" if run.max_minutes
                        else "train")

    def save(self, state: TrainState, path: Path, **extra) -> None:
        if self.env.main:
            checkpoint.save(path, model=state.net.state_dict(),
                            optimizer=state.optimizer.state_dict(),
                            scheduler=state.scheduler.state_dict(), step=state.step,
                            epoch=state.epoch, batch_in_epoch=state.offset,
                            rng=checkpoint.rng_state(), config=self.config_yaml,
                            net=checkpoint.net_args(state.net), sensor_hw=self.data.sensor_hw,
                            train_seconds=state.train_seconds(), **extra)

    def step(self, state: TrainState, loss: torch.Tensor, parts: dict) -> None:
        self.bar.update(1)
        if self.env.main and (state.step % self.cfg.run.log_every == 0 or state.step == 1):
            self.bar.set_postfix(loss=f"{loss.item():.4f}",
                                 lr=f"{state.scheduler.get_last_lr()[0]:.1e}")
            self.writer.add_scalar("train/loss", loss.item(), state.step)
            for k, v in parts.items():
                self.writer.add_scalar(f"train/{k}", v, state.step)

    def validate(self, state: TrainState) -> tuple[dict[str, float], list]:
        cfg, hw = self.cfg, self.data.sensor_hw
        metrics, examples = validate(state.net, self.val_loader, cfg, self.env.device,
                                     state.first_pass, state.criterion.lpips,
                                     cfg.run.val_batches)
        for k, v in metrics.items():
            self.writer.add_scalar(f"val/{k}", v, state.step)
        self.history.add(state.step, state.train_seconds() / 3600, metrics)
        self.history.save()
        frames = len(self.data.val_set)
        self.history.plot(self.out / "val_curve.png", f"validation: {frames} "
                          f"held-out frames, whole {hw[1]}x{hw[0]} -> x{cfg.model.scale}, "
                          f"outputs clipped to [0, 1], no intensity fit")
        return metrics, examples


def train_one_epoch(state: TrainState, data: TrainData, cfg: TrainConfig, env: Distributed,
                    total: int, report: RunLog) -> bool:
    """Run the rest of epoch ``state.epoch`` (from batch ``state.offset``); checkpoint and
    validate on their schedules. Returns whether the run is to stop."""
    run, out = cfg.run, report.out
    data.train_set.set_epoch(state.epoch)
    batches = epoch_batches(len(data.train_set), cfg.optim.batch_size, run.seed, state.epoch,
                            env.rank, env.world)
    loader = DataLoader(data.train_set, batch_sampler=batches[state.offset:],
                        num_workers=run.workers, pin_memory=env.device.type == "cuda")
    for batch in loader:
        batch = {k: v.to(env.device, non_blocking=True) for k, v in batch.items()}
        with torch.autocast(env.device.type, dtype=state.amp_dtype) if state.amp_dtype \
                else nullcontext():
            output = run_batch(state.model, batch, cfg, state.first_pass)
        loss, parts = state.criterion(output.float(), batch["hr"], batch["stacks"])
        if not torch.isfinite(loss):
            report.save(state, out / f"nan_step{state.step}.pt")
            raise FloatingPointError(f"loss is {loss.item()} at step {state.step}; the state "
                                     f"before this step is in {out / f'nan_step{state.step}.pt'}")
        _optimise(state, loss, cfg.optim.grad_clip)
        state.step, state.offset = state.step + 1, state.offset + 1
        if state.offset == len(batches):
            state.epoch, state.offset = state.epoch + 1, 0
        report.step(state, loss, parts)
        minutes = (time.perf_counter() - state.start) / 60
        stop = state.step >= total or (run.max_minutes is not None and
                                       minutes >= run.max_minutes)
        if env.world > 1:  # ranks time themselves; stop together or deadlock
            flag = torch.tensor(int(stop), device=env.device)
            dist.all_reduce(flag, op=dist.ReduceOp.MAX)
            stop = bool(flag)
        if run.checkpoint_every and state.step % run.checkpoint_every == 0 and not stop:
            report.save(state, out / "last.pt")
        if env.main and run.val_every and state.step % run.val_every == 0 and not stop \
                and data.val_set:
            report.validate(state)
        if stop:
            return True
    return False


def _optimise(state: TrainState, loss: torch.Tensor, grad_clip: float | None) -> None:
    scaler = state.scaler
    state.optimizer.zero_grad(set_to_none=True)
    (scaler.scale(loss) if scaler else loss).backward()
    if scaler:
        scaler.unscale_(state.optimizer)
    if grad_clip:
        torch.nn.utils.clip_grad_norm_(state.net.parameters(), grad_clip)
    if scaler:
        scaler.step(state.optimizer)
        scaler.update()
    else:
        state.optimizer.step()
    state.scheduler.step()


def finish(state: TrainState, data: TrainData, report: RunLog) -> dict:
    """The last checkpoint, a final validation with example outputs, ``result.json``."""
    out, env = report.out, report.env
    report.bar.close()
    report.save(state, out / "last.pt")
    result = {"step": state.step, "epoch": state.epoch,
              "parameters": count_parameters(state.net),
              "weights_sha256": weights_digest(state.net),
              "train_samples": len(data.train_set), "val_samples": len(data.val_set),
              "seconds": time.perf_counter() - state.start,
              "train_hours": state.train_seconds() / 3600}
    if env.main and len(data.val_set):
        metrics, examples = report.validate(state)
        result["val"] = metrics
        result["curve_png"] = str(out / "val_curve.png")
        title = (f"step {state.step}: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
        result["png"] = str(save_examples(out / "val_examples.png", examples, title))
    if env.main:
        report.writer.close()
        write_text(out / "result.json", json.dumps(result, indent=2, default=float))
    if env.world > 1:
        dist.barrier()
    return result


def train(config: TrainConfig, data: str | Path, out: str | Path, resume: bool = False,
          show_progress: bool = True) -> dict:
    """Train per ``config`` on the shards in ``data``; write checkpoints/logs to ``out``.

    Returns the final validation metrics and run facts (on every rank).
    """
    env = init_distributed()
    out, cfg = Path(out), config
    torch.manual_seed(cfg.run.seed)
    if cfg.run.threads:
        torch.set_num_threads(cfg.run.threads)
    shards = build_data(cfg, data, env)
    resuming = resume and (out / "last.pt").is_file()
    state = build_state(cfg, env, shards.steps_per_epoch, warm=not resuming)
    if resuming:
        resume_from(state, cfg, out / "last.pt")
    total = cfg.optim.epochs * shards.steps_per_epoch
    if cfg.run.max_steps is not None:
        total = min(total, cfg.run.max_steps)
    report = RunLog(cfg, shards, out, env, state, total, show_progress)
    state.start = time.perf_counter()
    if env.main:
        log.info("%d parameters, %d train / %d val samples, %d steps per epoch",
                 count_parameters(state.net), len(shards.train_set), len(shards.val_set),
                 shards.steps_per_epoch)
    stop = state.step >= total
    while not stop and state.epoch < cfg.optim.epochs:
        stop = train_one_epoch(state, shards, cfg, env, total, report)
    return finish(state, shards, report)


#: Settings a resumed run may change: how it runs, not what it learns or in which order.
RESUMABLE_CHANGES = ("run.workers", "run.max_steps", "run.max_minutes", "run.log_every",
                     "run.val_every", "run.checkpoint_every", "run.val_batches", "run.amp",
                     "run.cpu_amp", "run.channels_last", "run.threads")


def _flat(mapping, prefix: str = "") -> dict:
    out = {}
    for k, v in mapping.items():
        key = f"{prefix}{k}"
        out.update(_flat(v, key + ".") if isinstance(v, dict) else {key: v})
    return out


def check_resumable(config: TrainConfig, state: dict, path: Path) -> None:
    """Refuse to resume ``path`` under a config that changes what is learnt or the batch
    plan (network, data, loss, optimiser, seed): the message names the differing keys."""
    from esim_lite.core.dataconf import to_mapping

    stored = _flat(to_mapping(checkpoint.config_of(state, str(path))))
    now = _flat(to_mapping(config))
    differ = sorted(k for k in set(stored) | set(now)
                    if stored.get(k) != now.get(k) and k not in RESUMABLE_CHANGES)
    if differ:
        shown = ", ".join(f"{k} ({stored.get(k)!r} -> {now.get(k)!r})" for k in differ[:6])
        raise ValueError(f"{path}: cannot resume with a different {shown}"
                         f"{' ...' if len(differ) > 6 else ''}; use the checkpoint's config "
                         f"({path.parent / 'config.yaml'}) or a new --out")


def weights_digest(net: torch.nn.Module) -> str:
    """SHA-256 of the parameters and buffers (bit-for-bit identity of two models)."""
    h = hashlib.sha256()
    for name, tensor in sorted(net.state_dict().items()):
        h.update(name.encode())
        h.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def psnr_summary(result: dict) -> str:
    v = result.get("val", {})
    parts = [f"{k.upper()} {v[k]:.4f}" for k in ("psnr", "ssim", "mse", "lpips") if k in v]
    return ", ".join(parts) if parts else "no validation split"

