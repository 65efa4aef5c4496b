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
import os
import time
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader
from tqdm import tqdm

from esim_lite.atomic import write_text
from esim_lite.dataconf import to_yaml
from model import checkpoint, e2sri_arch
from model.config import OptimConfig, TrainConfig
from model.curves import ValHistory
from model.dataset import ShardSamples, find_shards, index_samples
from model.e2sri_arch import E2SRI, count_parameters
from model.input_cache import CacheSpec, InputCache
from model.losses import SimilarityLoss
from model.metrics import mse, psnr, ssim

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Distributed:
    rank: int = 0
    world: int = 1
    device: torch.device = torch.device("cpu")

    @property
    def main(self) -> bool:
        return self.rank == 0


def init_distributed() -> Distributed:
    """One process, or the one torchrun started us as (``WORLD_SIZE`` > 1)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    cuda = torch.cuda.is_available()
    if world == 1:
        return Distributed(device=torch.device("cuda" if cuda else "cpu"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if cuda:
        torch.cuda.set_device(local)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    return Distributed(dist.get_rank(), world,
                       torch.device(f"cuda:{local}" if cuda else "cpu"))


def epoch_batches(n: int, batch: int, seed: int, epoch: int, rank: int = 0, world: int = 1
                  ) -> list[list[int]]:
    """This rank's batches of epoch ``epoch``: a permutation seeded by (seed, epoch), cut to
    whole batches for every rank (all ranks must take the same number of steps, or DDP
    waits forever), dealt round-robin to ranks."""
    g = torch.Generator().manual_seed(seed * 1_000_003 + epoch)
    usable = n // (batch * world) * batch * world
    order = torch.randperm(n, generator=g)[:usable][rank::world].tolist()
    return [order[i:i + batch] for i in range(0, len(order), batch)]


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


@torch.inference_mode()
def evaluate(net: E2SRI, loader: DataLoader, config: TrainConfig, device: torch.device,
             first_pass: E2SRI | None, lpips_net, max_batches: int | None = None
             ) -> tuple[dict[str, float], list[tuple[np.ndarray, ...]]]:
    """Mean PSNR/SSIM/MSE/LPIPS over the held-out split, and a few (stack, lr, out, hr)."""
    net.eval()
    sums, count, examples = {"psnr": 0.0, "ssim": 0.0, "mse": 0.0, "lpips": 0.0}, 0, []
    for b, batch in enumerate(loader):
        if max_batches is not None and b >= max_batches:
            break
        batch = {k: v.to(device) for k, v in batch.items()}
        out = net(batch["stacks"], central_input(batch, config, first_pass),
                  batch["flows"]).float().clamp(0, 1)
        hr = batch["hr"]
        values = {"psnr": psnr(out, hr), "ssim": ssim(out, hr), "mse": mse(out, hr)}
        if lpips_net is not None:
            values["lpips"] = lpips_net(out, hr)
        for k, v in values.items():
            sums[k] += float(v.sum())
        count += len(hr)
        if len(examples) < 4:
            mid = config.model.n_stacks // 2
            examples.append((batch["stacks"][0, mid].cpu().numpy(), batch["lr"][0, 0].cpu().numpy(),
                             out[0, 0].cpu().numpy(), hr[0, 0].cpu().numpy()))
    net.train()
    if lpips_net is None:
        sums.pop("lpips")
    return {k: v / max(count, 1) for k, v in sums.items()}, examples


def save_examples(path: Path, examples, title: str) -> Path:
    from datagen.preview import contact_sheet, gray_to_rgb, write_png

    rows = []
    for stack, lr, out, hr in examples:
        events = ((stack.mean(axis=0) + 1) / 2).clip(0, 1)
        rows.append([(gray_to_rgb(events), "central stack"), (gray_to_rgb(lr), "LR frame"),
                     (gray_to_rgb(out), "output"), (gray_to_rgb(hr), "HR target")])
    return write_png(path, contact_sheet(rows, title, height=min(256, examples[0][3].shape[0])))


def train(config: TrainConfig, data: str | Path, out: str | Path, resume: bool = False,
          show_progress: bool = True) -> dict:
    """Train per ``config`` on the shards in ``data``; write checkpoints/logs to ``out``.

    Returns the final validation metrics and run facts (on every rank).
    """
    env = init_distributed()
    out = Path(out)
    cfg, run = config, config.run
    torch.manual_seed(run.seed)

    if run.threads:
        torch.set_num_threads(run.threads)
    shards = find_shards(data)
    train_refs, val_refs = index_samples(shards, cfg.data, cfg.model.n_stacks, cfg.model.scale)
    sensor_hw = sensor_of(shards[0])
    if run.val_batches is not None:  # a fixed sample spread over every held-out sequence
        val_refs = spread(val_refs, run.val_batches * cfg.optim.batch_size)
    cache = None
    if cfg.data.cache:
        spec = CacheSpec(cfg.data.stacks, cfg.data.flow, cfg.model.n_stacks, cfg.model.scale)
        cache = InputCache.build(shards, train_refs + val_refs, spec,
                                 workers=max(1, os.cpu_count() or 1) if env.main else 1)
    train_set = ShardSamples(train_refs, cfg.data, cfg.model.n_stacks, cfg.model.scale, True,
                             run.seed, cache)
    val_set = ShardSamples(val_refs, cfg.data, cfg.model.n_stacks, cfg.model.scale, False,
                           cache=cache)
    steps_per_epoch = len(epoch_batches(len(train_set), cfg.optim.batch_size, run.seed, 0,
                                        env.rank, env.world))
    if steps_per_epoch == 0:
        raise ValueError(f"{data}: {len(train_set)} training samples, fewer than the batch "
                         f"size {cfg.optim.batch_size} x {env.world} process(es)")

    net = E2SRI(cfg.model).to(env.device)
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
    criterion = SimilarityLoss(cfg.loss.lpips_weight).to(env.device)
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.optim.lr, betas=cfg.optim.betas,
                                 weight_decay=cfg.optim.weight_decay)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer,
                                                  lr_lambda(cfg.optim, steps_per_epoch))
    amp_dtype = (torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16) \
        if cuda and run.amp else (torch.bfloat16 if not cuda and run.cpu_amp else None)
    scaler = torch.amp.GradScaler("cuda") if amp_dtype == torch.float16 else None

    step, epoch, offset, seconds_before = 0, 0, 0, 0.0
    last = out / "last.pt"
    if resume and last.is_file():
        state = checkpoint.load(last)
        check_resumable(cfg, state, last)
        net.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        step, epoch, offset = state["step"], state["epoch"], state["batch_in_epoch"]
        seconds_before = float(state.get("train_seconds", 0.0))
        checkpoint.set_rng_state(state["rng"])
        log.info("resumed from %s at step %d", last, step)
    config_yaml = to_yaml(cfg)

    def save(path: Path, **extra) -> None:
        if env.main:
            checkpoint.save(path, model=net.state_dict(), optimizer=optimizer.state_dict(),
                            scheduler=scheduler.state_dict(), step=step, epoch=epoch,
                            batch_in_epoch=offset, rng=checkpoint.rng_state(), config=config_yaml,
                            net=checkpoint.net_args(net), sensor_hw=sensor_hw,
                            train_seconds=seconds_before + time.perf_counter() - start,
                            **extra)

    def validate() -> tuple[dict[str, float], list]:
        metrics, examples = evaluate(net, val_loader, cfg, env.device, first_pass,
                                     criterion.lpips, run.val_batches)
        for k, v in metrics.items():
            writer.add_scalar(f"val/{k}", v, step)
        history.add(step, (seconds_before + time.perf_counter() - start) / 3600, metrics)
        history.save()
        history.plot(out / "val_curve.png", f"validation: {len(val_set)} held-out frames, "
                     f"whole {sensor_hw[1]}x{sensor_hw[0]} -> x{cfg.model.scale}, outputs "
                     f"clipped to [0, 1], no intensity fit")
        return metrics, examples

    writer = None
    if env.main:
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "config.yaml", config_yaml)
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(str(out / "tb"))
        history = ValHistory(out / "val_history.csv")
    total = cfg.optim.epochs * steps_per_epoch
    if run.max_steps is not None:
        total = min(total, run.max_steps)
    loader_args = {"num_workers": run.workers, "pin_memory": cuda}
    val_loader = DataLoader(val_set, batch_size=cfg.optim.batch_size, **loader_args)
    # with a time budget the number of steps is unknown: no total, so no made-up ETA
    bar = tqdm(total=None if run.max_minutes else total, initial=step, unit="step",
               disable=not (show_progress and env.main),
               desc=f"train (stops after {run.max_minutes:g} min)" if run.max_minutes else "train")
    start, stop = time.perf_counter(), step >= total
    if env.main:
        log.info("%d parameters, %d train / %d val samples, %d steps per epoch",
                 count_parameters(net), len(train_set), len(val_set), steps_per_epoch)
    while not stop and epoch < cfg.optim.epochs:
        train_set.set_epoch(epoch)
        batches = epoch_batches(len(train_set), cfg.optim.batch_size, run.seed, epoch,
                                env.rank, env.world)
        loader = DataLoader(train_set, batch_sampler=batches[offset:], **loader_args)
        for batch in loader:
            batch = {k: v.to(env.device, non_blocking=True) for k, v in batch.items()}
            with torch.autocast(env.device.type, dtype=amp_dtype) if amp_dtype \
                    else nullcontext():
                output = model(batch["stacks"], central_input(batch, cfg, first_pass),
                               batch["flows"])
            loss, parts = criterion(output.float(), batch["hr"])
            if not torch.isfinite(loss):
                save(out / f"nan_step{step}.pt")
                raise FloatingPointError(f"loss is {loss.item()} at step {step}; the state "
                                         f"before this step is in {out / f'nan_step{step}.pt'}")
            optimizer.zero_grad(set_to_none=True)
            (scaler.scale(loss) if scaler else loss).backward()
            if scaler:
                scaler.unscale_(optimizer)
            if cfg.optim.grad_clip:
                torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.optim.grad_clip)
            if scaler:
                scaler.step(optimizer)
                scaler.update()
            else:
                optimizer.step()
            scheduler.step()
            step, offset = step + 1, offset + 1
            if offset == len(batches):
                epoch, offset = epoch + 1, 0
            bar.update(1)
            if env.main and (step % run.log_every == 0 or step == 1):
                bar.set_postfix(loss=f"{loss.item():.4f}", lr=f"{scheduler.get_last_lr()[0]:.1e}")
                writer.add_scalar("train/loss", loss.item(), step)
                for k, v in parts.items():
                    writer.add_scalar(f"train/{k}", v, step)
            minutes = (time.perf_counter() - start) / 60
            stop = step >= total or (run.max_minutes is not None and minutes >= run.max_minutes)
            if env.world > 1:  # ranks time themselves; stop together or deadlock
                flag = torch.tensor(int(stop), device=env.device)
                dist.all_reduce(flag, op=dist.ReduceOp.MAX)
                stop = bool(flag)
            if run.checkpoint_every and step % run.checkpoint_every == 0 and not stop:
                save(last)
            if env.main and run.val_every and step % run.val_every == 0 and not stop and val_set:
                validate()
            if stop:
                break
    bar.close()
    save(last)
    result = {"step": step, "epoch": epoch, "parameters": count_parameters(net),
              "weights_sha256": weights_digest(net),
              "train_samples": len(train_set), "val_samples": len(val_set),
              "seconds": time.perf_counter() - start,
              "train_hours": (seconds_before + time.perf_counter() - start) / 3600}
    if env.main and len(val_set):
        metrics, examples = validate()
        result["val"] = metrics
        result["curve_png"] = str(out / "val_curve.png")
        title = (f"step {step}: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
        result["png"] = str(save_examples(out / "val_examples.png", examples, title))
    if env.main:
        writer.close()
        write_text(out / "result.json", json.dumps(result, indent=2, default=float))
    if env.world > 1:
        dist.barrier()
    return result


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
    from esim_lite.dataconf import load_yaml_text, to_mapping

    stored = _flat(to_mapping(load_yaml_text(TrainConfig, state["config"], source=str(path))))
    now = _flat(to_mapping(config))
    differ = sorted(k for k in set(stored) | set(now)
                    if stored.get(k) != now.get(k) and k not in RESUMABLE_CHANGES)
    if differ:
        shown = ", ".join(f"{k} ({stored.get(k)!r} -> {now.get(k)!r})" for k in differ[:6])
        raise ValueError(f"{path}: cannot resume with a different {shown}"
                         f"{' ...' if len(differ) > 6 else ''}; use the checkpoint's config "
                         f"({path.parent / 'config.yaml'}) or a new --out")


def spread(items: list, n: int) -> list:
    """``n`` items evenly spaced over ``items`` (all of them if there are no more than n)."""
    if len(items) <= n:
        return items
    return [items[int(i * len(items) / n)] for i in range(n)]


def sensor_of(shard: Path) -> tuple[int, int]:
    """(H, W) of the event sensor the training data was simulated with."""
    from datagen.shard import ShardReader

    with ShardReader(shard) as reader:
        h, w = reader.group(reader.sequences()[0]).attrs["sensor_resolution"]
    return int(h), int(w)


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

