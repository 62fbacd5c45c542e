"""Plotting helpers of the beam-reference chapter (thin wrappers over matplotlib)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Sequence

import matplotlib.ticker
import numpy as np

from softpend.fidelity.validation import FreeVibration

if TYPE_CHECKING:  # annotations only: importing the comparison module brings in its progress bars
    from softpend.fidelity.prb_vs_beam import ConvergenceRow


def plot_free_vibration(ax_time, ax_spectrum, run: FreeVibration) -> None:
    """Tip signal of a free-vibration run and its spectrum, with the fitted and theoretical frequencies."""
    ax_time.plot(run.time_s, run.tip_x_m * 1e3, lw=0.8)
    ax_time.set_xlabel("time [s]")
    ax_time.set(ylabel="tip $e_x$ [mm]", title=f"{run.plant}, resolution {run.resolution}: free vibration")
    x = (run.tip_x_m - run.tip_x_m.mean()) * np.hanning(len(run.tip_x_m))
    n_fft = 8 * len(x)
    spectrum = np.abs(np.fft.rfft(x, n_fft))
    freq = np.fft.rfftfreq(n_fft, run.time_s[1] - run.time_s[0])
    keep = freq < 2.5 * run.theory_hz.max()
    ax_spectrum.semilogy(freq[keep], spectrum[keep] / spectrum[keep].max(), lw=0.8, label="spectrum of $e_x$")
    for k, (f, f_th) in enumerate(zip(run.frequencies_hz, run.theory_hz)):
        ax_spectrum.axvline(f, color="C1", ls="-", lw=1, label="fitted" if k == 0 else None)
        ax_spectrum.axvline(f_th, color="k", ls=":", lw=1, label="Euler-Bernoulli" if k == 0 else None)
    ax_spectrum.set(xlabel="frequency [Hz]", ylabel="normalised magnitude")
    ax_spectrum.legend(fontsize=8)


def plot_convergence(axes: Sequence[Any], rows: Sequence[ConvergenceRow], recommended: int | None = None) -> None:
    """Errors against resolution (frequencies, sag, tip trajectory), one panel each, beam and PRB together."""
    panels = [
        ("f1_error_pct", "first frequency error [%]"),
        ("f2_error_pct", "second frequency error [%]"),
        ("sag_small_error_pct", "small-deflection sag error [%]"),
        ("sag_large_vs_beam_pct", "large-deflection sag vs beam [%]"),
        ("tip_rms_over_l", "tip trajectory RMS vs beam [L]"),
    ]
    for ax, (key, label) in zip(axes, panels):
        for plant, marker in (("beam", "s"), ("prb", "o")):
            sel = [r for r in rows if r.plant == plant and math.isfinite(getattr(r, key))]
            if not sel:
                continue
            n = [r.resolution for r in sel]
            v = [max(abs(getattr(r, key)), 1e-4) for r in sel]
            ax.loglog(n, v, marker=marker, label="beam (elements)" if plant == "beam" else "PRB (links)")
        if key.endswith("pct"):
            ax.axhline(2.0, color="k", ls=":", lw=1, label="2 %")
        if recommended is not None:
            ax.axvline(recommended, color="C2", ls="--", lw=1, label=f"recommended n = {recommended}")
        resolutions = sorted({r.resolution for r in rows})
        ax.set_xticks(resolutions)
        ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set(xlabel="n (links or elements)", ylabel=label)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)


def plot_transfer_matrix(
    ax, rows: Sequence[dict[str, Any]], plant: str, metric: str = "success_rate", vmax: float | None = None
) -> Any:
    """Heat map of one transfer metric (controllers x perturbations) on one plant; the image, for a colour bar."""
    from softpend.study.transfer import transfer_matrix

    controllers, labels, values = transfer_matrix(rows, plant, metric)
    shown = np.where(np.isfinite(values), values, np.nan)
    vmax = vmax if vmax is not None else np.nanmax(shown[np.isfinite(shown)], initial=1.0)
    cmap = "RdYlGn" if metric == "success_rate" else "RdYlGn_r"
    image = ax.imshow(shown, cmap=cmap, vmin=0.0, vmax=vmax, aspect="auto")
    for (i, j), v in np.ndenumerate(values):
        text = "inf" if math.isinf(v) else ("-" if math.isnan(v) else f"{v:.2g}")
        ax.text(j, i, text, ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(labels)), labels, rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(controllers)), controllers, fontsize=8)
    ax.set_title(f"{metric} on the {plant} plant", fontsize=9)
    return image


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[str], digits: int = 3) -> str:
    """A Markdown table of the given columns (floats to ``digits`` significant digits)."""

    def fmt(value: Any) -> str:
        if isinstance(value, float):
            return "inf" if math.isinf(value) else ("nan" if math.isnan(value) else f"{value:.{digits}g}")
        return str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(row.get(c)) for c in columns) + " |" for row in rows]
    return "\n".join(lines)
