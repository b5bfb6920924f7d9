"""Pictures of a tracking run: per scene, ADD-S error and alpha over time for every method."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from chpf.atomic import atomic_write_bytes
from chpf.tracking.runlog import log_arrays, read_log


def plot_scenes(logs: dict[str, Path], out_dir: Path, title: str = "") -> list[Path]:
    """One PNG per scene (``out_dir/scene_XXXXXX.png``) from the methods' frame logs; returns
    the written paths. The error panel is left out when no frame has ground truth."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = {m: log_arrays(read_log(p)) for m, p in logs.items() if Path(p).is_file()}
    scenes = sorted({int(s) for d in data.values() for s in d["scene_id"]})
    written = []
    for sid in scenes:
        has_err = any(np.isfinite(d["err_adds"][d["scene_id"] == sid]).any() for d in data.values())
        rows = 2 if has_err else 1
        fig, axes = plt.subplots(rows, 1, figsize=(9, 3.2 * rows), sharex=True, squeeze=False)
        ax_err = axes[0, 0] if has_err else None
        ax_alpha = axes[-1, 0]
        for method, d in data.items():
            sel = d["scene_id"] == sid
            order = np.argsort(d["im_id"][sel])
            x = d["im_id"][sel][order]
            if ax_err is not None:
                ax_err.plot(x, 100.0 * d["err_adds"][sel][order], label=method, lw=1.3)
            ax_alpha.plot(x, d["alpha"][sel][order], label=method, lw=1.3)
        if ax_err is not None:
            ax_err.set_ylabel("ADD-S error (cm)")
            ax_err.set_ylim(bottom=0.0)
            ax_err.grid(alpha=0.3)
            ax_err.legend(fontsize=8, ncol=4)
        ax_alpha.set_ylabel("alpha (reinvigorated)")
        ax_alpha.set_ylim(-0.05, 1.05)
        ax_alpha.set_xlabel("image id")
        ax_alpha.grid(alpha=0.3)
        if ax_err is None:
            ax_alpha.legend(fontsize=8, ncol=4)
        fig.suptitle(f"{title} scene {sid}".strip())
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110)
        plt.close(fig)
        path = Path(out_dir) / f"scene_{sid:06d}.png"
        atomic_write_bytes(path, buf.getvalue())
        written.append(path)
    return written
