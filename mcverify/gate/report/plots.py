"""PNG plots for the report (matplotlib, Agg backend: no display needed).

A title holding a user's text (a check's name, a scene's) is drawn as plain text
(``parse_math=False``): matplotlib read ``$...$`` in it as mathtext, so a check named
``cost $\\frac$`` ended ``check --report`` with "unexpected ValueError" after the run,
writing neither the report nor ``--json``/``--junit``.

Figures are drawn on an Agg canvas of their own, without pyplot: a program that makes a
report keeps its own backend and figures (``matplotlib.use("Agg")`` here switched a
caller's interactive backend for the rest of the process, and ``plt.show()`` then showed
nothing). They are drawn in matplotlib's default style, whatever the caller's
``rcParams`` or ``matplotlibrc`` say: a report looks the same from every program, and a
caller's ``text.usetex = True`` made every plot a LaTeX run (without LaTeX installed,
``build_report`` raised "latex could not be found"; with it, a check name's ``$`` or
``_`` was read as TeX, which ``parse_math=False`` does not prevent)."""

from __future__ import annotations

import functools
import io

import numpy as np


def _default_style(plot):
    """``plot`` drawn (figure, artists and PNG) in matplotlib's default style, the
    caller's ``rcParams`` put back after it (``matplotlib.style.context``)."""
    @functools.wraps(plot)
    def drawn(*args, **kw):
        from matplotlib import style

        with style.context("default"):
            return plot(*args, **kw)

    return drawn


def _subplots(rows: int, cols: int, figsize, **kw):
    """``(figure, axes)`` as ``plt.subplots`` makes them, on an Agg canvas outside
    pyplot's registry of figures (nothing to close, the backend untouched)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, cols, **kw)


def _null_formatter():
    from matplotlib.ticker import NullFormatter

    return NullFormatter()


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return buf.getvalue()


def _per_integrand(rows: list[dict], draw, xlabel: str) -> bytes:
    """One log-log panel per integrand; ``draw(ax, row, colour)`` plots one estimator's
    row, in the colour of that estimator in every panel (each panel coloured its own
    rows in turn, so one colour meant other estimators in other panels)."""
    names = list(dict.fromkeys(r["integrand"] for r in rows))
    colours = {e: f"C{i % 10}" for i, e in
               enumerate(dict.fromkeys(r["estimator"] for r in rows))}
    fig, axes = _subplots(1, len(names), (4.0 * len(names), 3.6), squeeze=False)
    for ax, name in zip(axes[0], names):
        mine = [r for r in rows if r["integrand"] == name]
        for r in mine:
            draw(ax, r, colours[r["estimator"]])
        if mine and "uniform" in {r["estimator"] for r in mine} and xlabel == "N":
            first = next(r for r in mine if r["estimator"] == "uniform")
            ns = np.asarray(first["ns"], dtype=float)
            ax.loglog(ns, first["rmse"][0] * (ns / ns[0]) ** -0.5, "k:", lw=1, label="N^-1/2")
        ax.xaxis.set_minor_formatter(_null_formatter())
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("RMSE")
        ax.legend(fontsize=6)
    return _png(fig)


@_default_style
def convergence(rows: list[dict]) -> bytes:
    """RMSE against N, log-log, one panel per integrand, fitted slope in the legend."""
    return _per_integrand(rows, lambda ax, r, c: ax.loglog(
        r["ns"], r["rmse"], "o-", ms=3, color=c,
        label=f"{r['estimator']}: {r['slope']:.2f} [{r['ci'][0]:.2f}, {r['ci'][1]:.2f}]"), "N")


@_default_style
def efficiency(rows: list[dict]) -> bytes:
    """RMSE against wall time per estimate (median), log-log, one panel per integrand."""
    return _per_integrand(rows, lambda ax, r, c: ax.loglog(
        r["seconds"], r["rmse"], "o-", ms=3, color=c,
        label=f"{r['estimator']}: 1/(MSE·t) = {r['efficiency'][-1]:.2g}"),
        "seconds per estimate (median)")


@_default_style
def histogram(result: dict) -> bytes | None:
    """Observed vs expected counts of a sampler check and their standardised difference
    ((O − E)/√E), over the domain's parameter cells: where a sampler and its pdf
    disagree."""
    h = result.get("artifacts", {}).get("histogram")
    if not h or "expected" not in h:
        return None
    obs, exp = np.asarray(h["observed"], float), np.asarray(h["expected"], float)
    z = np.where(exp > 0, (obs - exp) / np.sqrt(np.maximum(exp, 1e-300)),
                 np.where(obs > 0, np.inf, 0.0))
    fig, axes = _subplots(1, 3, (12, 3.4))
    if obs.ndim == 1:
        centres = 0.5 * (np.asarray(h["edges"][0][1:]) + np.asarray(h["edges"][0][:-1]))
        axes[0].step(centres, obs, where="mid")
        axes[1].step(centres, exp, where="mid", color="C1")
        axes[2].plot(centres, np.clip(z, -10, 10), ".", ms=2)
    else:
        for ax, img in zip(axes[:2], (obs, exp)):
            im = ax.imshow(img, aspect="auto", origin="lower", cmap="viridis")
            fig.colorbar(im, ax=ax)
        im = axes[2].imshow(np.clip(z, -6, 6), aspect="auto", origin="lower", cmap="RdBu_r",
                            vmin=-6, vmax=6)
        fig.colorbar(im, ax=axes[2])
    for ax, t in zip(axes, ("observed", "expected (pdf integrated per cell)",
                            "(O - E) / sqrt(E), clipped")):
        ax.set_title(t, fontsize=9)
    fig.suptitle(result["name"], fontsize=10, parse_math=False)
    return _png(fig)


def _tonemap(img: np.ndarray, scale: float) -> np.ndarray:
    """Linear RGB to display: exposure so the 99th percentile maps to 1, sRGB gamma."""
    x = np.clip(np.asarray(img, float) / scale, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


@_default_style
def render_panels(scene: str, a: dict) -> bytes:
    """Ours, Mitsuba (one exposure for both), |ours − Mitsuba| (max over channels), the
    pixel test's BH-adjusted p-map (−log10 p), the ΔE2000, ΔE ITP and HDR-FLIP maps, each with its
    colour bar."""
    ours, theirs = np.asarray(a["ours"], float), np.asarray(a["mitsuba"], float)
    scale = max(float(np.percentile(theirs, 99)), 1e-12)
    fig, axes = _subplots(1, 7, (23, 3.4))
    for ax, img, t in ((axes[0], ours, "ours"), (axes[1], theirs, "Mitsuba")):
        ax.imshow(_tonemap(img, scale), interpolation="nearest")
        ax.set_title(t, fontsize=9)
    diff = np.abs(ours - theirs).max(axis=2)
    maps = ((axes[2], diff, "|ours − Mitsuba| (max over RGB)", "magma", None),
            (axes[3], -np.log10(np.clip(np.asarray(a["p_map"], float), 1e-12, 1.0)),
             "pixel test: −log10 p (BH-adjusted)", "viridis", (0, 6)),
            (axes[4], a.get("delta_e"), "ΔE2000", "inferno", None),
            (axes[5], a.get("delta_itp"), "ΔE ITP (100 cd/m² white)", "inferno", None),
            (axes[6], a.get("flip"), "HDR-FLIP", "magma", (0, 1)))
    for ax, img, t, cmap, lim in maps:
        if img is None:
            ax.set_axis_off()
            continue
        kw = {"vmin": lim[0], "vmax": lim[1]} if lim else {}
        im = ax.imshow(np.asarray(img, float), cmap=cmap, interpolation="nearest", **kw)
        fig.colorbar(im, ax=ax, fraction=0.046)
        ax.set_title(t, fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(scene, fontsize=10, parse_math=False)
    return _png(fig)


@_default_style
def render_error(rows: list[dict]) -> bytes:
    """RMSE against spp and against seconds, ours and Mitsuba, one column per scene."""
    fig, axes = _subplots(2, len(rows), (3.6 * len(rows), 6.4), squeeze=False)
    for j, r in enumerate(rows):
        c = r["curve"]
        for i, x in enumerate(("spp", "seconds")):
            ax = axes[i, j]
            for who, style in (("ours", "o-"), ("mitsuba", "s--")):
                xs = c["spp"] if x == "spp" else c[f"{who}_seconds"]
                ax.loglog(xs, np.maximum(c[f"{who}_rmse"], 1e-12), style, ms=3, label=who)
            ax.xaxis.set_minor_formatter(_null_formatter())
            ax.set_xlabel(x)
            ax.set_ylabel("RMSE")
            ax.legend(fontsize=7)
            if i == 0:
                ax.set_title(r["scene"], fontsize=9, parse_math=False)
    return _png(fig)
