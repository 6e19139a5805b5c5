"""The loss curve beside every training run (``loss.png``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.io.atomic import atomic_path


def plot_loss(log: dict[str, Any], path: Path) -> None:
    """Loss curve (log scale, raw and smoothed), validation loss, vertical lines at stage changes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per = log["per_step"]
    steps = np.asarray(per["step"], dtype=np.int64)
    loss = np.asarray(per["loss"], dtype=np.float64)
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    if steps.size:
        ax.plot(steps, loss, lw=0.6, alpha=0.35, color="C0", label="training loss")
        w = max(1, min(25, steps.size // 10))
        if steps.size >= w > 1:
            smooth = np.convolve(loss, np.ones(w) / w, mode="valid")
            ax.plot(steps[w - 1:], smooth, lw=1.5, color="C0", label=f"training loss ({w}-step mean)")
    val = log.get("validation", [])
    if val:
        ax.plot([v["step"] for v in val], [v["val_loss"] for v in val], "o-", ms=4, color="C3",
                label="validation loss (support, final radius)")
    for b, r in zip(log["schedule_boundaries"][1:], log["schedule"]["stages"][1:], strict=False):
        ax.axvline(b, color="0.5", ls="--", lw=0.8)
        ax.text(b, 0.99, f" r={r['radius_percent']:.3g}%", transform=ax.get_xaxis_transform(), va="top", fontsize=8)
    if np.all(loss[np.isfinite(loss)] > 0) and np.isfinite(loss).any():
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("relative L2 (encoded)")
    ax.set_title(f"{log['scene']} - preset {log['settings']['preset']}, batch {log['settings']['batch']}, "
                 f"lr {log['settings']['lr']:g}")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
