"""A grid dataset's sample as panels: every input channel and label (the thesis's figures 3.x
and 5.x), and with a model its prediction and the prediction's error beside each label."""
import io

import numpy as np

from ..errors import InputError
from ..grid.dataset import GridDataset
from ..grid.spec import GridSpec


def sample_panels(dataset, index, model=None, panel_px=220, threads=1):
    """PNG bytes of sample `index` of a dataset folder; model: a checkpoint from dc train, run on
    `threads` torch threads."""
    data = GridDataset(dataset)
    if not 0 <= index < len(data):
        raise InputError(f"sample {index} is out of range: the dataset has {len(data)} samples (0 to {len(data) - 1})",
                         dataset)
    meta = data.metadata
    x = np.array(data.arrays["inputs"][index], np.float32)
    y = np.array(data.arrays["labels"][index], np.float32)
    pred = _predict(model, meta, x, dataset, threads) if model is not None else {}
    # a label and its prediction share one colour range, so that their colours compare
    ranges = {name: _range([y[c]] + ([pred[name]] if name in pred else [])) for c, name in enumerate(meta["labels"])}
    rows = [[(name, x[c], "viridis", None) for c, name in enumerate(meta["inputs"])],
            [(name, y[c], "magma", ranges[name]) for c, name in enumerate(meta["labels"])]]
    if pred:
        rows.append([(f"predicted {name}", pred[name], "magma", ranges[name]) for name in meta["labels"]
                     if name in pred])
        rows.append([(f"error of {name}", pred[name] - y[c], "coolwarm", None) for c, name in enumerate(meta["labels"])
                     if name in pred])
    simulation = int(data.arrays["simulation"][index])
    return _figure(rows, panel_px, f"{dataset} · sample {index} ({_split_of(meta, simulation)} simulation {simulation}, "
                                   f"step {int(data.arrays['step'][index])})", meta["grid"])


def _range(images):
    """(low, high) over the images, so that several panels share one colour scale."""
    low = min(float(np.min(i)) for i in images)
    high = max(float(np.max(i)) for i in images)
    return (low, high if high > low else low + 1.0)


def _split_of(meta, simulation):
    """Which split a simulation is in: a training sample looks better than a validation one."""
    for part in ("train", "validation"):
        if simulation in meta["split"].get(part, []):
            return part
    return "unsplit"


def _predict(model, meta, x, dataset, threads=1):
    from ..model.inference import Predictor   # (torch: only where a sample is drawn beside its model)
    p = Predictor(model, threads=threads)
    if list(p.inputs) != list(meta["inputs"]):
        raise InputError(f"the model reads channels {','.join(p.inputs)}, the dataset has "
                         f"{','.join(meta['inputs'])}", dataset)
    if p.spec != GridSpec.from_dict(meta["grid"]):   # (the rule dc train --resume and dc evaluate apply)
        raise InputError(f"the model was trained on another grid ({p.spec.nx} x {p.spec.ny} nodes, d = {p.spec.cell:g}, "
                         f"h = {p.spec.h:g} from {p.spec.x0:g},{p.spec.y0:g}): it cannot draw this dataset's sample",
                         model)
    return dict(zip(p.targets, p.images(x)))


def _figure(rows, panel_px, title, grid):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    cols = max(len(r) for r in rows)
    dpi = 100
    fig = Figure(figsize=(cols * panel_px / dpi, len(rows) * panel_px / dpi + 0.4), dpi=dpi)
    FigureCanvasAgg(fig)
    fig.suptitle(title, fontsize=9, parse_math=False)   # (names are the user's text, not math)
    spec = GridSpec.from_dict(grid)
    extent = (spec.x0, spec.x1, spec.y0, spec.y1)
    for r, row in enumerate(rows):
        for c, (name, image, cmap, limits) in enumerate(row):
            ax = fig.add_subplot(len(rows), cols, r * cols + c + 1)
            if cmap == "coolwarm":   # an error: symmetric about 0
                top = float(np.abs(image).max()) or 1.0
                limits = (-top, top)
            low, high = limits if limits is not None else (None, None)
            shown = ax.imshow(image, origin="lower", cmap=cmap, vmin=low, vmax=high, extent=extent)
            ax.set_title(name, fontsize=8, parse_math=False)
            ax.tick_params(labelsize=6)
            fig.colorbar(shown, ax=ax, shrink=0.75).ax.tick_params(labelsize=6)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()
