"""Checkpoints: what last.pt and best.pt hold, loaded without running code, checked before
anything is built from them, and matched against the dataset a run trains on."""
import io
import math
import pickle
import random
import warnings

import numpy as np
import torch

from .. import output
from ..errors import InputError, OptionError
from ..grid.spec import GridSpec
from .checkpoint_file import NOT_TORCH, checkpoint_file, torch_file
from .config import config_problem
from .networks import check_config, shape_problem

CHECKPOINT_FORMAT = 2   # 2: plain containers and tensors only, loadable with weights_only=True


def rng_state():
    """Every RNG's state (torch, numpy, Python) as plain containers and tensors."""
    # numpy's state holds an ndarray, which weights_only loading refuses: store it as a tensor.
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"torch": torch.get_rng_state(),
            "numpy": {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                      "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
            "python": random.getstate()}


def set_rng_state(state):
    """Restores rng_state's states."""
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state((n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"],
                         n["cached_gaussian"]))
    random.setstate(state["python"])


def load_checkpoint(path, data=None):
    """A checkpoint, loaded without running any code it might carry (weights_only). data: its
    bytes, read already (what a fenced training hands back, checked as it was read): loaded from
    them, never from path, which then only names it."""
    source = checkpoint_file(path) if data is None else _from_bytes(data, path)
    try:
        with warnings.catch_warnings():   # torch's own advice on weights_only is not for our users
            warnings.simplefilter("ignore")
            ck = torch.load(source, map_location="cpu", weights_only=True)
    except (FileNotFoundError, IsADirectoryError):   # (gone or replaced since the check)
        raise InputError("no such checkpoint", path) from None
    except pickle.UnpicklingError:
        raise InputError("refused: the checkpoint holds objects other than tensors and plain containers "
                         "(loading it could run code)", path) from None
    except Exception as e:  # torch raises many kinds for a damaged file
        raise InputError(f"not a readable checkpoint (truncated or damaged?): {type(e).__name__}", path) from None
    if not isinstance(ck, dict) or "model" not in ck:
        raise InputError("not a deepcontact checkpoint", path)
    if ck.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"checkpoint format {ck.get('format')!r}; this version reads format {CHECKPOINT_FORMAT}",
                         path)
    keys = ("epoch", "network", "train_config", "targets", "dataset", "history", "best", "bad_epochs", "rng",
            "optimizer")
    missing = [k for k in keys if k not in ck]
    if missing:
        raise InputError(f"not a complete deepcontact checkpoint: no {', '.join(missing)}", path)
    # Checked before anything is built from it: a tampered config could ask for terabytes.
    problem = (check_config(ck["network"]) or shape_problem(ck["network"], ck["model"])
               or checkpoint_problem(ck))
    if problem:
        raise InputError(f"refused: {problem}", path)
    return ck


def _from_bytes(data, path):
    if not torch_file(data[:4]):
        raise InputError(NOT_TORCH, path)
    return io.BytesIO(data)


def run_of(ck):
    """What every checkpoint of one run shares (a resumed run keeps them): its network's name,
    its dataset and its targets."""
    return {"network": ck["network"].get("model"), "dataset": ck["dataset"], "targets": ck["targets"]}


def succession_problem(ck, within, run=None, after=None):
    """Why the checkpoint ck cannot take the place of a run's own, or None. within: whether it
    is the one kept within an epoch (mid-epoch.pt, which alone has a position in it); its history
    must be a row for each epoch before it (a whole epoch's: and its own); run: run_of the run's
    checkpoints, which it must share; after: the epoch of the one it replaces, not to go back from."""
    if ("position" in ck) != within:
        return "no position within its epoch" if within else "a position within an epoch, in a whole epoch's"
    done = ck["epoch"] + (0 if within else 1)
    if [row["epoch"] for row in ck["history"]] != list(range(done)):
        return f"its history is not a row for each of its {done} epochs"
    if run is not None and run_of(ck) != run:
        return "it is of another run (another network, dataset or targets)"
    if after is not None and ck["epoch"] < after:
        return f"it is of epoch {ck['epoch'] + 1}, before the run's own (epoch {after + 1})"
    return None


def checkpoint_problem(ck):
    """What is wrong with a checkpoint's bookkeeping (types and ranges), or None: the first of
    _BOOKKEEPING's rules it breaks (each may read what the rules before it checked)."""
    for holds, problem in _BOOKKEEPING:
        if not holds(ck):
            return problem
    grid = _grid_problem(ck["dataset"].get("grid"))
    if grid:
        return grid
    problem = config_problem(ck["train_config"])
    return f"train_config: {problem}" if problem else None


def _whole(v):
    return type(v) is int and 0 <= v < 2 ** 31


def _number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _names(v):
    return isinstance(v, list) and bool(v) and all(isinstance(c, str) for c in v)


def _rows_of_numbers(v):
    return isinstance(v, list) and all(isinstance(r, dict) and all(isinstance(k, str) and _number(x)
                                                                   for k, x in r.items()) for r in v)


def _position(v):
    """A mid-epoch checkpoint's place in its epoch: the epoch's sample order (whole numbers), the
    next sample, and the loss summed and samples seen and seconds taken so far."""
    return (isinstance(v, dict) and isinstance(v.get("order"), torch.Tensor) and v["order"].dtype == torch.int64
            and v["order"].dim() == 1 and _whole(v.get("next")) and v["next"] <= len(v["order"])
            and _whole(v.get("seen")) and _number(v.get("total")) and math.isfinite(v["total"])
            and _number(v.get("seconds")) and v["seconds"] >= 0)


def _grid_problem(grid):
    try:
        GridSpec.from_dict(grid)
    except ValueError as e:
        return str(e)
    return None


# (holds(checkpoint), what is wrong where it does not), in the order checked
_BOOKKEEPING = (
    (lambda ck: _whole(ck["epoch"]) and _whole(ck["bad_epochs"]), "'epoch' and 'bad_epochs' must be whole numbers"),
    (lambda ck: _number(ck["best"]) and not math.isnan(ck["best"]), "'best' must be a number"),
    (lambda ck: _rows_of_numbers(ck["history"]), "'history' must be a list of rows of named numbers"),
    (lambda ck: all(_whole(r.get("epoch")) for r in ck["history"]), "every 'history' row needs a whole-number epoch"),
    (lambda ck: isinstance(ck["dataset"], dict), "'dataset' must be a dictionary"),
    (lambda ck: _names(ck["dataset"].get("inputs")), "the dataset's 'inputs' must be a list of channel names"),
    (lambda ck: _names(ck["dataset"].get("labels")), "the dataset's 'labels' must be a list of channel names"),
    (lambda ck: _names(ck["targets"]) and set(ck["targets"]) <= set(ck["dataset"]["labels"]),
     "'targets' must name label channels of its dataset"),
    (lambda ck: isinstance(ck["train_config"], dict), "'train_config' must be a dictionary"),
    (lambda ck: "position" not in ck or _position(ck["position"]),
     "'position' must hold the epoch's sample order, the next sample, and the sums and seconds so far"),
)


def save(path, obj):
    """obj written with torch.save to path, atomically."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    output.write_bytes(path, buf.getvalue())


def check_compatible(ck, meta, path):
    """A checkpoint fits a dataset if the grid and input channels match exactly."""
    want = ck["dataset"]
    if want["grid"] != meta["grid"]:
        raise InputError(f"checkpoint grid {want['grid']} does not match the dataset's {meta['grid']}", path)
    if want["inputs"] != meta["inputs"]:
        raise InputError(f"checkpoint inputs {want['inputs']} do not match the dataset's {meta['inputs']}", path)
    missing = [t for t in ck["targets"] if t not in meta["labels"]]
    if missing:
        raise InputError(f"the dataset has no label channel {', '.join(missing)}", path)


def check_same_run(ck, meta, path, given, threads, dataset):
    """--resume continues the run in the checkpoint: on its own dataset, with its own settings."""
    for key in ("samples", "sources", "split", "labels"):
        if ck["dataset"].get(key) != meta.get(key):
            raise InputError(f"the run in {path} was trained on another dataset (its {key} differ from "
                             f"{dataset}'s): --resume continues a run on its own dataset", dataset)
    if given is not None:
        own = ck["train_config"]
        for name, value in dict(given).items():
            if name in own and own[name] != value:
                option = "--" + {"fcn_width": "width", "fcn_depth": "depth", "final_relu": "no-final-relu",
                                 "model": "arch"}.get(name, name).replace("_", "-")
                raise OptionError(f"--resume continues the run with its own settings: it has {name} = {own[name]!r}, "
                                  f"not {value!r} (leave the option out, or train a new run)", option)
    if "threads" in ck and ck["threads"] != (threads or 1):
        raise OptionError(f"the run was trained with --threads {ck['threads']}, and the count changes the arithmetic: "
                          f"resume with --threads {ck['threads']}", "--threads")
