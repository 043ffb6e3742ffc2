"""The training curve: training loss (smoothed) and held-out validation RMSE against step.

Written by a training run (``RUN/curve.png``) and beside the bundled weights (``*_curve.png``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mi_svbrdf.io.figures import pyplot, save_figure


def plot_curve(log: list[dict[str, Any]], path: Path) -> None:
    """Training loss (smoothed) and validation metrics against step, written atomically."""
    plt = pyplot()
    train = [r for r in log if "loss" in r]
    val = [r for r in log if any(k.startswith("val_") for k in r)]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    if train:
        steps = np.array([r["step"] for r in train])
        loss = np.array([r["loss"] for r in train])
        k = max(1, len(loss) // 50)
        smooth = np.convolve(loss, np.ones(k) / k, mode="valid")
        axes[0].plot(steps, loss, alpha=0.3, label="loss")
        axes[0].plot(steps[k - 1:], smooth, label=f"mean of {k}")
        axes[0].set_xlabel("step"), axes[0].set_ylabel("training loss"), axes[0].legend()
    if val:
        keys = sorted({k for r in val for k in r if k.startswith("val_rmse_")})
        for key in keys:
            axes[1].plot([r["step"] for r in val if key in r], [r[key] for r in val if key in r], "o-",
                         label=key[4:])
        axes[1].set_xlabel("step"), axes[1].set_ylabel("held-out RMSE"), axes[1].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
