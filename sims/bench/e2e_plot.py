"""The end-to-end benchmark's plot: viewer error p95 against bytes delivered per viewer-second, a point per
system (the median of its repetitions, the bars their range). Needs matplotlib (the `plot` extra); without it
the report is still written and the plot skipped with a note."""

from __future__ import annotations

from pathlib import Path

from sims.bench.report import pyplot


def plot(summary: dict, path: Path, progress) -> None:
    """Write the plot to `path` (log-scaled bytes: the systems lie over two orders of magnitude)."""
    plt = pyplot(progress)
    if plt is None:
        return
    fig, ax = plt.subplots(figsize=(7, 4.5))
    markers = "osD^v<>ph*"
    for k, (name, s) in enumerate(summary.items()):
        x, y = s["bytes_per_viewer_s"], s["error_p95_m"]
        if x is None or y is None:
            continue
        xs, ys = s.get("bytes_per_viewer_s_runs", [x]), s.get("error_p95_m_runs", [y])
        ours = name.startswith("entitynet")
        ax.errorbar([x], [y], xerr=[[x - min(xs)], [max(xs) - x]], yerr=[[y - min(ys)], [max(ys) - y]],
                    fmt=markers[k % len(markers)], color=("tab:blue", "tab:cyan", "tab:green", "tab:olive",
                                                          "tab:red", "tab:orange", "tab:purple")[k % 7],
                    capsize=3, markersize=8, label=name + ("" if ours and "periodic" not in name else " (1 Hz)"))
    ax.legend(fontsize=8, loc="best")
    ax.set_xscale("log")
    ax.set_xlabel("bytes delivered per viewer-second (log)")
    ax.set_ylabel("viewer position error p95 (m)")
    ax.set_title("bench e2e: the same world through each system")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    progress(f"plot written to {path}")
