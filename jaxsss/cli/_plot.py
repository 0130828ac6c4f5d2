"""Profile plots for the command line (matplotlib with the non-interactive Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxsss.cli._common import CLIError

# Line colours: the three RGB channels get their own colour; other channel counts use matplotlib's cycle.
_RGB = ("tab:red", "tab:green", "tab:blue")


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def channel_colours(n: int):
    return list(_RGB) if n == 3 else [None] * n


def plot_channels(ax, r, values, labels, *, linestyle="-", prefix=""):
    """One line per channel: ``values`` has shape ``(len(r), n_channels)``; non-positive values are not drawn."""
    values = np.asarray(values, dtype=np.float64).reshape(len(r), -1)
    for c, (label, colour) in enumerate(zip(labels, channel_colours(values.shape[1]))):
        y = np.where(values[:, c] > 0.0, values[:, c], np.nan)  # log axis: leave zeros (underflow) out
        marker = "o" if len(r) <= 30 else None  # show the sample points when there are few of them
        ax.plot(r, y, linestyle=linestyle, marker=marker, markersize=3, color=colour, label=f"{prefix}{label}")
    ax.set_yscale("log")
    if np.min(r) > 0.0 and np.max(r) / np.min(r) >= 100.0:
        ax.set_xscale("log")


def save(fig, path) -> Path:
    """Save ``fig`` as a PNG at ``path`` (creating the parent directory); close it; return the path."""
    plt = pyplot()
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
    except OSError as err:
        raise CLIError(f"cannot write the plot to {str(path)!r}: {err.strerror or err}") from None
    finally:
        plt.close(fig)
    return path
