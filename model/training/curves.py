"""The validation curve of a training run: a CSV that survives resumption and its PNG plot.

``val_history.csv`` holds one row per validation (step, training hours so far, PSNR, SSIM,
MSE, LPIPS); ``val_curve.png`` plots each metric against the step. Both are rewritten
atomically after every validation, so a killed run leaves the last complete curve.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from esim_lite.core.atomic import write_bytes

COLUMNS = ("step", "hours", "psnr", "ssim", "mse", "lpips")


class ValHistory:
    """Rows of validation metrics, loaded from ``path`` if it exists (a resumed run)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.rows: list[dict[str, float]] = []
        if self.path.is_file():
            with open(self.path, newline="") as f:
                self.rows = [{k: float(v) for k, v in r.items() if v not in ("", None)}
                             for r in csv.DictReader(f)]

    def add(self, step: int, hours: float, metrics: dict[str, float]) -> None:
        """Record one validation; a resumed run that repeats a step replaces that row."""
        self.rows = [r for r in self.rows if int(r["step"]) < step]
        self.rows.append({"step": float(step), "hours": hours,
                          **{k: float(v) for k, v in metrics.items() if k in COLUMNS}})

    def save(self) -> None:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, COLUMNS, lineterminator="\n")
        writer.writeheader()
        for r in self.rows:
            writer.writerow({k: (int(r[k]) if k == "step" else f"{r[k]:.6g}")
                             for k in COLUMNS if k in r})
        write_bytes(self.path, buf.getvalue().encode())

    def plot(self, png: str | Path, title: str = "validation") -> Path:
        """PSNR, SSIM and LPIPS against the step, one panel each."""
        import matplotlib

        matplotlib.use("Agg", force=True)
        from matplotlib import pyplot as plt

        png = Path(png)
        keys = [k for k in ("psnr", "ssim", "lpips") if any(k in r for r in self.rows)]
        fig, axes = plt.subplots(1, max(len(keys), 1), figsize=(4.2 * max(len(keys), 1), 3.2),
                                 squeeze=False)
        labels = {"psnr": "PSNR (dB), higher is better", "ssim": "SSIM, higher is better",
                  "lpips": "LPIPS, lower is better"}
        for ax, k in zip(axes[0], keys):
            pts = [(r["step"], r[k]) for r in self.rows if k in r]
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=".", lw=1)
            ax.set_xlabel("step")
            ax.set_title(labels[k], fontsize=9)
            ax.grid(alpha=0.3)
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110)
        plt.close(fig)
        write_bytes(png, buf.getvalue())
        return png
