"""One step drawn with matplotlib onto a figure that is reused frame after frame: static
geometry, bodies (circles with an orientation tick, polygons, edges; coloured by type or by
speed), contact points with their normal and friction impulses as arrows scaled and coloured by
magnitude, and a title.

The axes fill the whole picture and the picture has the window's aspect ratio, so a world point
(x, y) lands on pixel ((x - x0) / (x1 - x0) * width, (y1 - y) / (y1 - y0) * height): `pixel`
says it, and the tests sample pictures there."""
import io
from dataclasses import dataclass

import numpy as np


BACKGROUND = "#ffffff"
FILL = {0: "#9a9a9a", 1: "#a8c6e8", 2: "#f5c48a"}     # static, kinematic, dynamic (light: arrows show)
OUTLINE = "#3a3a3a"
NORMAL_MAP, FRICTION_MAP = "Reds", "Blues"   # darker for larger impulses
MIN_ASPECT = 0.5    # a picture around bodies is at least half as high as wide
TITLE_BAND = 0.08   # of its height, above the bodies: where the title and the legend go


@dataclass
class Window:
    x0: float
    y0: float
    x1: float
    y1: float

    @classmethod
    def around(cls, bounds, pad=0.04):
        """Around bounds (x0, y0, x1, y1) with a margin, a band on top for the title and the
        legend (the demo's title sat on the box's top wall), and at least MIN_ASPECT as high as
        wide, grown upwards (a fallen stack was a 640x78 picture with its legend cut off)."""
        x0, y0, x1, y1 = bounds
        w, h = max(x1 - x0, 1e-3), max(y1 - y0, 1e-3)
        x0, x1, y0, y1 = x0 - pad * w, x1 + pad * w, y0 - pad * h, y1 + pad * h
        y1 += TITLE_BAND * (y1 - y0)
        return cls(x0, y0, x1, max(y1, y0 + MIN_ASPECT * (x1 - x0)))

    def size(self, width):
        """(width, height) in pixels, even (video codecs want even sizes), the window's aspect."""
        height = width * (self.y1 - self.y0) / (self.x1 - self.x0)
        return 2 * max(8, round(width / 2)), 2 * max(8, round(height / 2))

    def pixel(self, x, y, size):
        w, h = size
        return (x - self.x0) / (self.x1 - self.x0) * w, (self.y1 - y) / (self.y1 - self.y0) * h


class Painter:
    """Draws steps of one simulation. impulse_scale: metres of arrow per N s of impulse
    (None: from each step's own median; a run's pictures share its run's, frames.run_impulse_scale),
    drawn with a legend arrow; speed_max: the speed the colour map tops out at when
    colouring by speed (None: each step's largest)."""

    def __init__(self, shapes, window, width=640, contacts=True, color_by="type", impulse_scale=None,
                 speed_max=None, panels=1):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        self._spec = dict(shapes=shapes, window=window, width=width, contacts=contacts, color_by=color_by,
                          impulse_scale=impulse_scale, speed_max=speed_max, panels=panels)
        self.shapes, self.window, self.contacts, self.color_by = shapes, window, contacts, color_by
        self.impulse_scale, self.speed_max = impulse_scale, speed_max
        self.size = window.size(width)
        w, h = self.size
        self.dpi = 100
        self.fig = Figure(figsize=(panels * w / self.dpi, h / self.dpi), dpi=self.dpi, facecolor=BACKGROUND)
        self.canvas = FigureCanvasAgg(self.fig)
        self.axes = [self.fig.add_axes([k / panels, 0, 1 / panels, 1]) for k in range(panels)]
        for ax in self.axes:
            ax.set_xlim(window.x0, window.x1)
            ax.set_ylim(window.y0, window.y1)
            ax.set_axis_off()
            ax.set_facecolor(BACKGROUND)

    def spec(self):
        """The arguments that make a painter like this one (a worker process draws with its own)."""
        return dict(self._spec)

    def draw(self, bodies, contacts, title="", panel=0, progress=None):
        """Draws one step into a panel (replacing what it held)."""
        ax = self.axes[panel]
        for artist in list(ax.collections) + list(ax.texts) + list(ax.patches):
            artist.remove()
        self._bodies(ax, bodies)
        if self.contacts and len(contacts["position"]):
            self._contacts(ax, contacts)
        if self.contacts and self.impulse_scale:
            self._legend(ax)
        if title:
            size = min(9.0, max(5.0, self.size[0] / 70))   # small pictures, small print
            ax.text(0.01, 0.99, title, transform=ax.transAxes, va="top", ha="left", fontsize=size, family="monospace",
                    parse_math=False,   # (a scene name is the user's text, not math)
                    bbox=dict(facecolor="white", alpha=0.8, edgecolor="none", pad=2))
        if progress is not None:
            from matplotlib.patches import Rectangle
            ax.add_patch(Rectangle((0, 0), progress, 0.008, transform=ax.transAxes, color="#4e79a7", zorder=5))

    def rgb(self):
        """The picture as an (height, width, 3) uint8 array."""
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()

    def image_bytes(self, fmt):
        """The picture as PNG or SVG (no date inside: the same step gives the same bytes)."""
        import matplotlib
        buf = io.BytesIO()
        with matplotlib.rc_context({"svg.hashsalt": "deepcontact"}):
            self.fig.savefig(buf, format=fmt, dpi=self.dpi, facecolor=BACKGROUND,
                             metadata={"Date": None} if fmt == "svg" else None)
        return buf.getvalue()

    # --- pieces --------------------------------------------------------------------------

    def _fills(self, bodies, rows):
        kinds = bodies["type"][rows]
        if self.color_by == "speed":
            from matplotlib import colormaps
            speed = np.hypot(*bodies["velocity"][rows].T)
            top = self.speed_max or max(float(speed.max(initial=0.0)), 1e-6)
            colours = colormaps["viridis"](np.clip(speed / top, 0, 1))
            colours[kinds == 0] = (0.6, 0.6, 0.6, 1.0)
            return colours
        return [FILL.get(int(k), FILL[2]) for k in kinds]

    def _bodies(self, ax, bodies):
        from matplotlib.collections import EllipseCollection, LineCollection, PolyCollection
        p = self.shapes.placed(bodies)
        if len(p.edges):
            ax.add_collection(LineCollection(p.edges, colors=OUTLINE, linewidths=1.5))
        if p.polygons:
            ax.add_collection(PolyCollection(p.polygons, facecolors=self._fills(bodies, p.polygon_rows),
                                             edgecolors=OUTLINE, linewidths=0.5))
        if len(p.centres):
            d = 2 * p.radii
            ax.add_collection(EllipseCollection(d, d, np.zeros(len(d)), units="xy", offsets=p.centres,
                                                offset_transform=ax.transData,
                                                facecolors=self._fills(bodies, p.circle_rows),
                                                edgecolors=OUTLINE, linewidths=0.5))
            # the orientation: a tick from half the radius to the rim (the centre keeps its fill)
            angle = bodies["angle"].astype(np.float64)[p.circle_rows]
            u = np.stack([np.cos(angle), np.sin(angle)], 1) * p.radii[:, None]
            ax.add_collection(LineCollection(np.stack([p.centres + 0.5 * u, p.centres + u], 1), colors=OUTLINE,
                                             linewidths=0.8))

    def _legend(self, ax):
        """The arrow of a round impulse in the upper-right corner, labelled: what the arrows mean."""
        value = legend_impulse(self.impulse_scale, self.window)
        w, h = self.window.x1 - self.window.x0, self.window.y1 - self.window.y0
        length = value * self.impulse_scale
        x, y = self.window.x1 - 0.02 * w - length, self.window.y1 - 0.03 * h
        ax.quiver([x], [y], [length], [0], color="#b2182b", angles="xy", scale_units="xy",
                  scale=1, width=0.004, headwidth=3, headlength=4, zorder=6)
        size = min(8.0, max(5.0, self.size[0] / 80))
        ax.text(x - 0.01 * w, y, f"{value:g} N·s (normal red, friction blue)", va="center", ha="right",
                fontsize=size, parse_math=False, zorder=6, bbox=dict(facecolor="white", alpha=0.8, edgecolor="none", pad=1))

    def _contacts(self, ax, contacts):
        from matplotlib.colors import Normalize
        p = contacts["position"].astype(np.float64)
        n = contacts["normal"].astype(np.float64)
        t = np.stack([n[:, 1], -n[:, 0]], 1)   # Box2D's tangent: cross(normal, 1)
        ln = contacts["normal_impulse"].astype(np.float64)
        lt = contacts["tangent_impulse"].astype(np.float64)
        scale = self.impulse_scale or impulse_scale_for([ln], self.window)
        ax.scatter(p[:, 0], p[:, 1], s=3, c="#111111", linewidths=0, zorder=3)
        for values, direction, cmap in ((ln, n, NORMAL_MAP), (lt, t, FRICTION_MAP)):
            keep = np.abs(values) > 0
            if not np.any(keep):
                continue
            length = np.minimum(np.abs(values[keep]) * scale, (self.window.x1 - self.window.x0) * ARROW_LONGEST)
            v = direction[keep] * (np.sign(values[keep]) * length)[:, None]
            size = np.abs(values[keep])
            top = float(size.max())   # the palest shade is kept off white: the map starts at -top/3
            ax.quiver(p[keep, 0], p[keep, 1], v[:, 0], v[:, 1], size, cmap=cmap, norm=Normalize(-top / 3, top),
                      angles="xy", scale_units="xy", scale=1, width=0.003, headwidth=3, headlength=4, zorder=4)


ARROW_OF_MEDIAN = 1 / 30   # of the window's width: the arrow of the run's median normal impulse
ARROW_LONGEST = 1 / 8      # of the window's width: no arrow is drawn longer (its colour still tells)


def impulse_scale_for(normal_impulses, window):
    """Metres of arrow per N·s: the median of the nonzero normal impulses given draws as a
    thirtieth of the window's width. A median, not a maximum: a pile's landing impacts are a
    hundred times its resting impulses, and scaled by them a resting arrow is a pixel long."""
    values = np.concatenate([np.abs(np.asarray(v, np.float64)) for v in normal_impulses]) if normal_impulses else []
    values = np.asarray(values)[np.asarray(values) > 0]
    typical = float(np.median(values)) if len(values) else 0.0
    return (window.x1 - window.x0) * ARROW_OF_MEDIAN / typical if typical > 0 else 0.0


def legend_impulse(scale, window):
    """The round impulse (1, 2 or 5 times a power of ten, N·s) whose arrow is about a fifteenth of
    the window's width: the legend's arrow."""
    if not scale > 0:
        return 0.0
    target = (window.x1 - window.x0) / 15 / scale
    power = 10 ** np.floor(np.log10(target))
    return float(min((m * power for m in (1, 2, 5, 10)), key=lambda v: abs(np.log(v / target))))
