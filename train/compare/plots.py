"""The comparison's PNG plots (matplotlib, Agg): accuracy vs blur and time per image.

`rows` are the comparison's per-data-set rows: name, object, kind, size (W, H), blur, and
`acc` / `ms` {method name: accuracy in [0, 1] / ms per image}; `names` the methods to draw.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def plot_accuracy(rows: list[dict[str, Any]], names: list[str], path: Path) -> None:
    """Accuracy vs blur level, one panel per (kind, size), one line per model / baseline."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = sorted({(r["object"], r["kind"], r["size"]) for r in rows})
    ncols = min(3, len(panels))
    nrows = -(-len(panels) // ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(3.6 * ncols, 3.0 * nrows), dpi=80, squeeze=False
    )
    for ax in axes.ravel()[len(panels) :]:
        ax.set_visible(False)
    handles = {}
    for ax, (obj, kind, size) in zip(axes.ravel(), panels, strict=False):
        sub = sorted(
            (r for r in rows if (r["object"], r["kind"], r["size"]) == (obj, kind, size)),
            key=lambda r: str(r["blur"]),
        )
        for k, name in enumerate(names):
            pts = [(r["blur"], 100 * r["acc"][name]) for r in sub if name in r["acc"]]
            if pts:
                xs, ys = [str(b) for b, _ in pts], [a for _, a in pts]
                (handles[name],) = ax.plot(xs, ys, marker="o", color=f"C{k}", label=name)
        ax.set_title(f"{obj}: {kind}, {size[0]}x{size[1]}", fontsize=9)
        ax.set_xlabel("blur level")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
    for row in axes:
        row[0].set_ylabel("accuracy %")
    axes[0][0].legend(handles.values(), handles.keys(), fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def plot_times(rows: list[dict[str, Any]], names: list[str], path: Path) -> None:
    """ms per image of each model and the baseline, per data set (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1.5 + 0.6 * len(rows), 3.4), dpi=80)
    width = 0.8 / max(len(names), 1)
    for k, name in enumerate(names):
        xs = [i + k * width for i, r in enumerate(rows) if name in r["ms"]]
        ys = [r["ms"][name] for r in rows if name in r["ms"]]
        ax.bar(xs, ys, width=width, label=name)
    ax.set_xticks(
        [i + 0.4 - width / 2 for i in range(len(rows))],
        [r["name"] for r in rows],
        rotation=60,
        ha="right",
        fontsize=7,
    )
    ax.set_yscale("log")
    ax.set_ylabel("ms / image")
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
