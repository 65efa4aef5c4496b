"""Which inputs a trained network's loss still pulls on: per-batch gradients of EFR's first
convolutions, per input column.

For each input column of ``efr0`` (central input, then the event history) and ``efr`` (side
stack, central input, history, flow) it prints the mean |gradient| over the batches and the
sign consistency, ``|mean over batches| / mean |g|`` averaged over the column's weights: about
``1 / sqrt(batches)`` for pure noise, 1 for a gradient that always points the same way. Used
on run H (docs/models.md) to ask whether its history columns stayed near zero for lack of a
consistent pull. Training samples of ``--data`` under the checkpoint's own config (its input
cache is reused when present), fixed order, no update.

    .venv/bin/python bench/input_gradients.py runs/x2_history/last.pt \
        --data shards/real_mix_small --batches 24
"""

from __future__ import annotations

import argparse
import sys

import torch


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--data", required=True, help="training shards (folder)")
    parser.add_argument("--batches", type=int, default=24)
    parser.add_argument("--batch-size", type=int, default=8)
    args = parser.parse_args(argv)

    from model import checkpoint
    from model.losses.similarity import SimilarityLoss
    from model.training.setup import build_data
    from model.training.train import central_input

    try:
        cfg = checkpoint.config_of(checkpoint.load(args.checkpoint), args.checkpoint)
        net = checkpoint.load_model(args.checkpoint, torch.device("cpu")).float().train()
        data = build_data(cfg, args.data)
    except (OSError, ValueError) as exc:
        print(f"input_gradients: {exc}", file=sys.stderr)
        return 2
    loss_cfg = cfg.loss
    criterion = SimilarityLoss(loss_cfg.lpips_weight, unfired_tv=loss_cfg.unfired_tv,
                               unfired_dilate=loss_cfg.unfired_dilate,
                               fill_unseen=loss_cfg.fill_unseen,
                               fill_dilate=loss_cfg.fill_dilate)
    samples = data.train_set
    samples.set_epoch(0)
    order = torch.randperm(len(samples), generator=torch.Generator().manual_seed(0))
    names = ("efr0.0.0.weight", "efr.0.0.weight")
    grads: dict[str, list[torch.Tensor]] = {n: [] for n in names}
    params = dict(net.named_parameters())
    bs = args.batch_size
    for b in range(min(args.batches, len(samples) // bs)):
        items = [samples[int(i)] for i in order[b * bs:(b + 1) * bs]]
        batch = {k: torch.stack([it[k] for it in items]) for k in items[0]}
        net.zero_grad()
        out = net(batch["stacks"], central_input(batch, cfg, None), batch["flows"])
        loss, _ = criterion(out.float(), batch["hr"], batch["stacks"])
        loss.backward()
        for n in names:
            grads[n].append(params[n].grad.detach().clone())
    print(f"# .venv/bin/python bench/input_gradients.py {args.checkpoint} --data {args.data} "
          f"--batches {len(grads[names[0]])} --batch-size {bs}\n")
    print("| tensor | input column | mean abs weight | mean abs gradient | sign consistency |")
    print("|---|---|---|---|---|")
    for n in names:
        g = torch.stack(grads[n])  # (batches, out, in, kh, kw)
        consistency = (g.mean(0).abs() / g.abs().mean(0).clamp_min(1e-12)).mean((0, 2, 3))
        magnitude = g.abs().mean((0, 1, 3, 4))
        weight = params[n].detach().abs().mean((0, 2, 3))
        for c in range(g.shape[2]):
            print(f"| {n} | {c} | {weight[c]:.4f} | {magnitude[c]:.2e} | {consistency[c]:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
