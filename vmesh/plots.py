"""Pictures: quality histograms (Pillow, no screen needed; matplotlib axes on request).

The run's histogram is drawn with Pillow: importing matplotlib and laying out a figure
cost ~0.7 s of a run that should take ~2 s (docs/speed.md). :func:`plot_quality_axes`
draws the same histogram into a matplotlib ``Axes`` for figures of one's own.
"""

from __future__ import annotations

import numpy as np

from .io.atomic import atomic_path

_SIZE = (720, 432)  # pixels (6 x 3.6 inches at 120 dpi)
_BOX = (78, 38, 700, 376)  # plot area: left, top, right, bottom
_BAR, _MIN, _MEAN, _INK, _GRID = (59, 117, 175), (192, 57, 43), (39, 174, 96), (34, 34, 34), (225, 225, 225)


def quality_histogram(sj: np.ndarray, path, title: str = "", bins: int = 50) -> None:
    """Histogram of scaled Jacobians (like the paper's Fig. 10) on a log count axis, with
    min/mean marked, written as a PNG."""
    from PIL import Image, ImageDraw

    sj = np.asarray(sj, float)
    lo = min(0.0, float(sj.min())) if len(sj) else 0.0
    counts, edges = np.histogram(sj, bins=np.linspace(lo, 1.0, bins + 1))
    top = max(1, int(counts.max()) if len(counts) else 1)
    decades = np.arange(0, int(np.ceil(np.log10(top * 1.5))) + 1)
    img = Image.new("RGB", _SIZE, "white")
    draw = ImageDraw.Draw(img)
    font, small = _font(12), _font(11)
    x0, y0, x1, y1 = _BOX

    def x_of(v):
        return x0 + (np.asarray(v, float) - lo) / (1.0 - lo) * (x1 - x0)

    def y_of(c):  # log axis from 0.5 (empty bins stay flat) to the top decade
        span = np.log10(10.0 ** decades[-1]) - np.log10(0.5)
        return y1 - (np.log10(np.maximum(c, 0.5)) - np.log10(0.5)) / span * (y1 - y0)

    for k in decades:
        y = float(y_of(10.0**k))
        draw.line([(x0, y), (x1, y)], fill=_GRID)
        _text(draw, (x0 - 6, y), f"{10 ** int(k)}", small, anchor="rm")
    for a, b, c in zip(x_of(edges[:-1]), x_of(edges[1:]), counts):
        if c > 0:
            draw.rectangle([float(a), float(y_of(c)), float(b) - 1, y1], fill=_BAR)
    for v in np.round(np.arange(np.ceil(lo * 5) / 5, 1.0001, 0.2), 1) + 0.0:  # + 0.0: no "-0.0"
        x = float(x_of(v))
        draw.line([(x, y1), (x, y1 + 4)], fill=_INK)
        _text(draw, (x, y1 + 7), f"{v:.1f}", small, anchor="ma")
    if len(sj):
        for v, colour in ((sj.min(), _MIN), (sj.mean(), _MEAN)):
            _dashed(draw, float(x_of(v)), y0, y1, colour)
        _text(draw, (x0 + 8, y0 + 6), f"min {sj.min():.3f}\nmean {sj.mean():.3f}\nn = {len(sj)}", small, anchor="la")
    draw.rectangle([x0, y0, x1, y1], outline=_INK)
    _text(draw, ((x0 + x1) / 2, y1 + 26), "scaled Jacobian", font, anchor="ma")
    label = Image.new("RGB", (80, 18), "white")
    _text(ImageDraw.Draw(label), (40, 9), "elements", font, anchor="mm")
    img.paste(label.rotate(90, expand=True), (8, (y0 + y1) // 2 - 40))
    if title:
        _text(draw, ((x0 + x1) / 2, 12), title, font, anchor="ma")
    with atomic_path(path) as tmp:
        img.save(tmp, format="png")


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def _text(draw, xy, text, font, anchor):
    try:
        draw.multiline_text(xy, text, fill=_INK, font=font, anchor=anchor)
    except ValueError:  # bitmap fonts take no anchor
        draw.multiline_text(xy, text, fill=_INK, font=font)


def _dashed(draw, x, y0, y1, colour, dash=6):
    for y in range(int(y0), int(y1), 2 * dash):
        draw.line([(x, y), (x, min(y + dash, y1))], fill=colour, width=1)


def plot_quality_axes(ax, sj, bins=50, label=None):
    """The quality histogram in a matplotlib ``Axes`` (log counts, min and mean marked)."""
    sj = np.asarray(sj)
    ax.hist(sj, bins=np.linspace(min(0.0, sj.min() if len(sj) else 0), 1, bins + 1), color="#3b75af", edgecolor="white", linewidth=0.3, label=label)
    ax.set_yscale("log")
    ax.set_xlabel("scaled Jacobian")
    ax.set_ylabel("elements")
    if len(sj):
        ax.axvline(sj.min(), color="#c0392b", lw=1, ls="--")
        ax.axvline(sj.mean(), color="#27ae60", lw=1, ls="--")
        ax.text(0.02, 0.95, f"min {sj.min():.3f}\nmean {sj.mean():.3f}\nn = {len(sj)}", transform=ax.transAxes, va="top", fontsize=8)
