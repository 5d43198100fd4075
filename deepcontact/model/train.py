"""Training: a network from a grid dataset, with checkpoints that resume exactly.

Every epoch writes `metrics.csv` / `metrics.json`, `last.pt`, and `best.pt` when the validation
loss (the training loss without a validation split) improves, all atomically. A checkpoint holds
the model config, weights, optimizer state, epoch, every RNG state, the history and the
dataset's metadata, so `resume` continues as if never stopped, and the same seed gives the same
weights. With WORLD_SIZE set (torchrun), training is data-parallel over gloo; rank 0 alone writes.
"""
import io
import json
import logging
import math
import os
import pickle
import random
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..escape import CsvWriter
from .. import __version__, output
from .checkpoint_file import checkpoint_file
from ..errors import InputError
from ..grid.dataset import GridDataset
from ..grid.spec import GridSpec
from ..plugins import guest
from ..resources import check_memory
from . import losses
from .arch import NETWORKS
from .choices import OPTIMIZERS
from .networks import (CONFIG_LIMITS, build, check_config, check_network, parameter_count, shape_problem,
                       training_memory)

log = logging.getLogger(__name__)
CHECKPOINT_FORMAT = 2   # 2: plain containers and tensors only, loadable with weights_only=True
# Everything a training folder holds: what --overwrite may replace.
MODEL_FILES = output.Owned("training run", [r"(last|best)\.pt", r"metrics\.(csv|json)", r"loss\.(png|svg)"])


@dataclass
class TrainConfig:
    """Everything a training run is: the network (`model`, a registered name), targets, loss,
    optimizer and its settings, batches, epochs and seed; saved in every checkpoint."""

    model: str = "fcn"
    targets: list = field(default_factory=lambda: ["normal_impulse", "tangent_impulse"])
    loss: str = "masked"
    optimizer: str = "sgd"
    lr: float = 1e-3                 # Adam's rate; SGD follows the thesis schedule
    momentum: float = 0.9
    weight_decay: float = 5e-4       # L2 on the weights (the thesis's kernel regulariser)
    batch_size: int = 200
    epochs: int = 1000
    patience: int = 0                # stop after this many epochs without improvement (0: never)
    seed: int = 0
    dropout: float = 0.1
    final_relu: bool = True          # thesis model only: the thesis's last ReLU
    fcn_width: int = 16
    fcn_depth: int = 3
    solver_sweeps: int = 0           # solver loss: relaxation sweeps before the residual

    def __post_init__(self):
        """The same limits as dc train's options (OptionError naming the flag): a library caller
        cannot train a checkpoint that --resume would refuse."""
        from ..errors import OptionError
        for name, low, high, low_open in (("lr", 0.0, math.inf, True), ("momentum", 0.0, 1.0, False),
                                          ("weight_decay", 0.0, math.inf, False), ("dropout", 0.0, 1.0, False)):
            value = getattr(self, name)
            ok = (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                  and (value > low if low_open else value >= low) and value <= high and not (name == "dropout" and value == 1))
            if not ok:
                raise OptionError(f"{name.replace('_', ' ')} must be a finite number in "
                                  f"{'(' if low_open else '['}{low:g}, {high:g}{')' if name == 'dropout' or high == math.inf else ']'}"
                                  f", got {value!r}", "--" + name.replace("_", "-"))
        for name, low in (("batch_size", 1), ("epochs", 1), ("patience", 0), ("seed", 0), ("fcn_width", 1),
                          ("fcn_depth", 1), ("solver_sweeps", 0)):
            value = getattr(self, name)
            if type(value) is not int or not low <= value <= 2 ** 31 - 1:
                raise OptionError(f"{name.replace('_', ' ')} must be a whole number from {low} to {2 ** 31 - 1}, "
                                  f"got {value!r}", "--" + name.replace("_", "-"))


def thesis_lr(epoch):
    """The thesis's Algorithm 4. Its conditions overlap (epoch > 300 and 300 < epoch < 500); read
    as intended: 5e-3 until epoch 100, 2e-3 until 300, 1e-3 until 500, 2e-4 after."""
    if epoch < 100:
        return 5e-3
    if epoch < 300:
        return 2e-3
    if epoch < 500:
        return 1e-3
    return 2e-4


class TrainingDiverged(InputError):
    pass


def _rng_state():
    # numpy's state holds an ndarray, which weights_only loading refuses: store it as a tensor.
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return {"torch": torch.get_rng_state(),
            "numpy": {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                      "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
            "python": random.getstate()}


def _set_rng_state(state):
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state((n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"],
                         n["cached_gaussian"]))
    random.setstate(state["python"])


def load_checkpoint(path):
    """A checkpoint, loaded without running any code it might carry (weights_only)."""
    import warnings
    path = checkpoint_file(path)
    try:
        with warnings.catch_warnings():   # torch's own advice on weights_only is not for our users
            warnings.simplefilter("ignore")
            ck = torch.load(path, map_location="cpu", weights_only=True)
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


def checkpoint_problem(ck):
    """What is wrong with a checkpoint's bookkeeping (types and ranges), or None."""
    def whole(v):
        return type(v) is int and 0 <= v < 2 ** 31

    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)
    if not whole(ck["epoch"]) or not whole(ck["bad_epochs"]):
        return "'epoch' and 'bad_epochs' must be whole numbers"
    if not number(ck["best"]) or math.isnan(ck["best"]):
        return "'best' must be a number"
    h = ck["history"]
    if not isinstance(h, list) or not all(isinstance(r, dict) and all(isinstance(k, str) and number(v)
                                                                      for k, v in r.items()) for r in h):
        return "'history' must be a list of rows of named numbers"
    if any(not whole(r.get("epoch")) for r in h):
        return "every 'history' row needs a whole-number epoch"
    d = ck["dataset"]
    if not isinstance(d, dict):
        return "'dataset' must be a dictionary"
    try:
        GridSpec.from_dict(d.get("grid"))
    except ValueError as e:
        return str(e)
    for key in ("inputs", "labels"):
        if not isinstance(d.get(key), list) or not d[key] or not all(isinstance(c, str) for c in d[key]):
            return f"the dataset's {key!r} must be a list of channel names"
    t = ck["targets"]
    if not isinstance(t, list) or not t or not all(isinstance(c, str) and c in d["labels"] for c in t):
        return "'targets' must name label channels of its dataset"
    cfg = ck["train_config"]
    if not isinstance(cfg, dict):
        return "'train_config' must be a dictionary"
    problem = config_problem(cfg)
    return f"train_config: {problem}" if problem else None


# The training options' ranges, as the CLI takes them: (low, high), inclusive; None: open.
_RANGES = {"batch_size": (1, 2 ** 31 - 1), "epochs": (1, 2 ** 31 - 1), "patience": (0, 2 ** 31 - 1),
           "seed": (0, 2 ** 31 - 1), "solver_sweeps": (0, 2 ** 31 - 1), "lr": (0, None), "weight_decay": (0, None),
           "momentum": (0, 1), "dropout": (0, 1),
           **{k: CONFIG_LIMITS[k] for k in ("fcn_width", "fcn_depth")}}   # (the network's own limits)
_CHOICES = {"optimizer": OPTIMIZERS}


def config_problem(cfg):
    """What is wrong with a training config read from a file (types, ranges, choices), or None."""
    defaults = asdict(TrainConfig())
    for k, v in cfg.items():
        if k not in defaults:
            return f"unknown setting {k!r}"
        want = type(defaults[k])
        if want is float:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                return f"{k!r} must be a finite number, not {v!r}"
        elif type(v) is not want:
            return f"{k!r} must be {want.__name__}, not {v!r}"
        lo, hi = _RANGES.get(k, (None, None))
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            return f"{k!r} must be from {lo} to {hi if hi is not None else 'any'}, not {v!r}"
        if k in _CHOICES and v not in _CHOICES[k]:
            return f"{k!r} must be one of {', '.join(_CHOICES[k])}, not {v!r}"
        if k == "model" and not NETWORKS.is_name(v):
            return f"'model' must name a network (thesis, fcn, or a plug-in), not {v!r}"
        if k == "targets" and (not v or not all(isinstance(t, str) for t in v)):
            return "'targets' must be a list of label channel names"
        if k == "loss" and v not in losses.LOSSES:
            return f"'loss' must be one of {', '.join(losses.LOSSES)}, not {v!r}"
    return None


def _save(path, obj):
    buf = io.BytesIO()
    torch.save(obj, buf)
    output.write_bytes(path, buf.getvalue())


def _distributed():
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not torch.distributed.is_initialized():
        torch.distributed.init_process_group("gloo")
    rank = torch.distributed.get_rank() if world > 1 else 0
    return world, rank


def network_config(cfg: TrainConfig, meta, targets):
    spec = meta["grid"]
    return dict(model=cfg.model, in_channels=len(meta["inputs"]), out_channels=len(targets),
                height=spec["ny"], width=spec["nx"], dropout=cfg.dropout, final_relu=cfg.final_relu,
                fcn_width=cfg.fcn_width, fcn_depth=cfg.fcn_depth)


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
    from ..errors import OptionError
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


def train(dataset: str | os.PathLike, out_dir: str | os.PathLike, cfg: TrainConfig | None = None, resume: bool = False,
          progress: Callable | None = None, threads: int = 1, device: str = "cpu", overwrite: bool = False,
          epochs: int | None = None, max_memory: float | None = None, given: dict = (), plots: bool = True,
          heartbeat: Callable | None = None) -> list[dict]:
    """Train; returns the history (a list of per-epoch metric dicts).

    progress(row): called after each epoch with its metrics (and "epochs", the run's number of
    epochs); heartbeat(epoch, samples done, samples in the epoch): after each batch (a caller's
    sign of life within a long epoch).

    Everything is checked before the output folder is touched. With `overwrite`, the new run is
    built beside the old one and replaces it only when it finishes. `epochs` overrides the
    configuration's (or, with `resume`, the checkpoint's) number of epochs. max_memory: refuse a
    network and batch estimated to need more GB (default resources.DEFAULT_MAX_MEMORY_GB).
    threads: torch's threads, 1: the count changes the order of float sums (1 and 2 threads
    trained weights 1.3e-4 apart), and the same seed must give the same weights on any machine;
    more processes (torchrun) are the way to train on more cores. plots: draw loss.png/svg at the
    end (False: none; refused when resuming a run that has one, which would no longer match its
    metrics)."""
    from ..errors import OptionError
    if threads not in (None, 0, 1):
        raise OptionError(f"training runs on one thread (the count changes the arithmetic, so weights would not "
                          f"repeat exactly); got {threads} (use torchrun for more cores)", "--threads")
    if threads:
        torch.set_num_threads(threads)
    try:
        device = torch.device(device)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as e:
        raise InputError(f"device {device} is not available here: {e}") from None
    world, rank = _distributed()
    ds = GridDataset(dataset)
    meta = ds.metadata
    out_dir = Path(out_dir)
    last = out_dir / "last.pt"
    ck = None
    if resume:
        ck = load_checkpoint(last)
        try:
            cfg = TrainConfig(**ck["train_config"])
        except TypeError as e:
            raise InputError(f"refused: the training config does not fit this version ({e})", last) from None
        check_compatible(ck, meta, last)
        check_same_run(ck, meta, last, given, threads, dataset)
        if not plots and any((out_dir / f"loss.{ext}").exists() for ext in ("png", "svg")):
            raise OptionError("the run has a loss plot from before, which its new epochs would leave behind: "
                              "resume without --no-plots to redraw it", "--no-plots")
    cfg = cfg or TrainConfig()
    if epochs is not None:
        cfg.epochs = epochs
    if cfg.loss not in losses.LOSSES:
        raise InputError(f"unknown loss {cfg.loss!r}; choose from {', '.join(losses.LOSSES)}")
    missing = [t for t in cfg.targets if t not in meta["labels"]]
    if missing or not cfg.targets:
        raise InputError(f"the dataset's labels are {', '.join(meta['labels'])}; no {', '.join(missing) or 'target'}",
                         dataset)
    impulses = [t for t in cfg.targets if t in ("normal_impulse", "tangent_impulse")]
    if cfg.loss in ("contacts", "solver") and len(impulses) != len(cfg.targets):
        raise InputError(f"the {cfg.loss} loss needs impulse targets (normal_impulse, tangent_impulse)")
    if cfg.loss == "solver":
        ds.check_step_sources()
    if len(ds.indices("train")) == 0:
        raise InputError("the dataset has no training samples", dataset)
    net_cfg = network_config(cfg, meta, cfg.targets)
    problem = check_config(net_cfg)
    if problem:
        raise InputError(problem)
    need = training_memory(net_cfg, cfg.batch_size, cfg.optimizer)
    if cfg.loss == "solver":
        need += losses.SolverLoss.memory(ds, cfg.batch_size, cfg.solver_sweeps)
    check_memory(need, max_memory, f"training the {cfg.model} network with batches of {cfg.batch_size}"
                 + (f" and the solver loss ({cfg.solver_sweeps} sweeps)" if cfg.loss == "solver" else ""))
    # Replacing an earlier run builds the new one beside it; otherwise training writes in place,
    # so that an interrupted run can be resumed from its last.pt.
    replace = overwrite and out_dir.is_dir() and any(out_dir.iterdir())

    def kept():
        """What a failed run leaves, said as it is."""
        if replace:
            return "the earlier run is left as it was"
        return f"the last good checkpoint is kept ({last})" if last.exists() else "no checkpoint was written"
    with _output_folder(out_dir, overwrite, replace, resume, rank) as work:
        trainer = Trainer(ds, cfg, net_cfg, device, world=world, rank=rank, kept=kept)
        if ck is not None:
            trainer.resume_from(ck)
        if rank == 0 and not len(trainer.val_idx):
            log.warning("the dataset has no validation samples: best.pt is the epoch of the lowest training loss, "
                        "and nothing says whether the network generalises (dc rasterize --validation F)")
        if ck is None and rank == 0:
            params, _ = parameter_count(trainer.model)
            log.info("%s model: %s parameters; %d training and %d validation samples", cfg.model, f"{params:,}",
                     len(trainer.train_idx), len(trainer.val_idx))
        trainer.heartbeat = heartbeat if rank == 0 else None
        history = trainer.fit(work, progress, dataset_path=str(dataset), out_dir=out_dir, plots=plots)
        if world > 1:
            torch.distributed.barrier()   # no rank leaves while rank 0 still writes
            torch.distributed.destroy_process_group()
        return history


def _optimizer(cfg, model):
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(model.parameters(), lr=thesis_lr(0), momentum=cfg.momentum,
                               weight_decay=cfg.weight_decay)
    if cfg.optimizer == "adam":
        return torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    raise InputError(f"unknown optimizer {cfg.optimizer!r}; choose sgd or adam")


def _masked_loss(t, pred, y, idx):
    return losses.masked_mse(pred, y)


def _mse_loss(t, pred, y, idx):
    return losses.mse(pred, y)


def _solver_loss(t, pred, y, idx):
    return t.solver_loss(pred, idx, t.spec, t.label_columns)


def _contact_loss(t, pred, y, idx):
    pos, imp = zip(*(t.ds.contacts(int(i)) for i in idx))
    return losses.contact_mse(pred, [torch.from_numpy(np.array(p)).to(t.device) for p in pos],
                              [torch.from_numpy(np.array(q)).to(t.device) for q in imp], t.spec, t.label_columns)


# The losses by name (losses.LOSSES): each takes the trainer, the prediction, the labels and the samples.
LOSS_OF = {"masked": _masked_loss, "mse": _mse_loss, "solver": _solver_loss, "contacts": _contact_loss}


class Trainer:
    """One training run: the dataset, the network and its optimizer under one configuration.

    run_epoch trains one epoch, validate measures the validation simulations, checkpoint is
    what last.pt and best.pt hold, fit runs the epochs and writes them. The seeds are set before
    the network is built, so the same seed gives the same weights; resume_from restores every
    state a checkpoint holds, so a resumed run continues as if never stopped."""

    def __init__(self, ds, cfg, net_cfg, device, world=1, rank=0, kept=lambda: ""):
        self.ds, self.cfg, self.net_cfg, self.device = ds, cfg, net_cfg, device
        self.world, self.rank, self.kept = world, rank, kept
        labels = ds.metadata["labels"]
        self.target_idx = [labels.index(t) for t in cfg.targets]
        self.label_columns = [{"normal_impulse": 0, "tangent_impulse": 1}[t] for t in cfg.targets
                              if t in ("normal_impulse", "tangent_impulse")]
        self.solver_loss = losses.SolverLoss(ds, sweeps=cfg.solver_sweeps) if cfg.loss == "solver" else None
        self.train_idx, self.val_idx = ds.indices("train"), ds.indices("validation")
        self.spec = GridSpec(**ds.metadata["grid"])
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)
        random.seed(cfg.seed)
        torch.use_deterministic_algorithms(True, warn_only=True)
        self.model = build(net_cfg)
        check_network(self.model, net_cfg)   # (a plug-in held to the contract before the first batch)
        self.model = self.model.to(device)
        self.opt = _optimizer(cfg, self.model)
        self.net = torch.nn.parallel.DistributedDataParallel(self.model) if world > 1 else self.model
        self.history, self.best, self.bad_epochs, self.start = [], math.inf, 0, 0

    def resume_from(self, ck):
        self.model.load_state_dict(ck["model"])
        self.opt.load_state_dict(ck["optimizer"])  # (its tensors follow the parameters' device)
        _set_rng_state(ck["rng"])
        self.history, self.best, self.bad_epochs, self.start = ck["history"], ck["best"], ck["bad_epochs"], \
            ck["epoch"] + 1

    def batch(self, indices):
        """(sorted indices, inputs, labels) on the device; a NaN or inf in either is refused."""
        idx = np.sort(indices)   # reading a memory map in order
        x = torch.from_numpy(np.ascontiguousarray(self.ds.arrays["inputs"][idx])).to(self.device)
        y = torch.from_numpy(np.ascontiguousarray(self.ds.arrays["labels"][idx][:, self.target_idx])).to(self.device)
        for name, t in (("inputs", x), ("labels", y)):
            if not torch.isfinite(t).all():
                k = int(idx[int(torch.nonzero(~torch.isfinite(t.flatten(1)).all(dim=1))[0])])
                raise InputError(f"sample {k} holds a NaN or infinite value; {self.kept()}",
                                 self.ds.path / f"{name}.npy")
        return idx, x, y

    def loss(self, pred, y, idx):
        return LOSS_OF[self.cfg.loss](self, pred, y, idx)

    def run_epoch(self, epoch):
        """One pass over the training samples in this epoch's seeded order; the metrics row."""
        cfg = self.cfg
        lr = thesis_lr(epoch) if cfg.optimizer == "sgd" else cfg.lr
        for g in self.opt.param_groups:
            g["lr"] = lr
        gen = torch.Generator().manual_seed(cfg.seed * 100003 + epoch)
        order = self.train_idx[torch.randperm(len(self.train_idx), generator=gen).numpy()]
        self.net.train()
        t0 = time.perf_counter()
        total, seen = 0.0, 0
        for b0 in range(0, len(order), cfg.batch_size):
            chunk = order[b0:b0 + cfg.batch_size][self.rank::self.world]
            if len(chunk) == 0:
                continue
            idx, x, y = self.batch(chunk)
            self.opt.zero_grad()
            loss = self.loss(self.net(x), y, idx)
            if not torch.isfinite(loss):
                raise TrainingDiverged(f"the loss became {loss.item()} in epoch {epoch}; {self.kept()}")
            loss.backward()
            self.opt.step()
            total += loss.item() * len(idx)
            seen += len(idx)
            if getattr(self, "heartbeat", None) is not None:
                self.heartbeat(epoch, min(b0 + cfg.batch_size, len(order)), len(order))
        seconds = time.perf_counter() - t0
        if self.world > 1:   # the epoch's loss over all ranks' samples
            sums = torch.tensor([total, float(seen)], dtype=torch.float64)
            torch.distributed.all_reduce(sums)
            total, seen = float(sums[0]), int(sums[1])
        return {"epoch": epoch, "lr": lr, "train_loss": total / max(seen, 1), "seconds": seconds,
                "samples_per_second": seen / max(seconds, 1e-9)}

    @torch.no_grad()
    def validate(self):
        """Validation loss and the RMSE at the contact points, per target, beside two yardsticks:
        predicting 0 (val_zero_rmse_*: a network must beat it to have learned anything) and the
        grid's floor (val_floor_rmse_*: the label image itself read back at the contacts, the best
        any grid-predicting network can score)."""
        self.model.eval()
        total, seen = 0.0, 0
        sq = np.zeros(len(self.label_columns))
        floor = None if hasattr(self, "_floor") else np.zeros(len(self.label_columns))
        count = 0
        spec = self.spec
        for b0 in range(0, len(self.val_idx), self.cfg.batch_size):
            ids, x, y = self.batch(self.val_idx[b0:b0 + self.cfg.batch_size])
            pred = self.model(x)
            total += self.loss(pred, y, ids).item() * len(ids)
            seen += len(ids)
            if self.label_columns:
                scale = spec.impulse_scale
                for k, i in enumerate(ids):
                    pos, imp = self.ds.contacts(int(i))
                    if len(pos) == 0:
                        continue
                    pos = torch.from_numpy(np.array(pos)).to(pred.device)
                    truth = np.array(imp)[:, self.label_columns].T
                    at = losses.bilinear_torch(pred[k], spec, pos).cpu().numpy() * scale
                    sq += ((at - truth) ** 2).sum(axis=1)
                    if floor is not None:   # the label image itself read back: a perfect network's score
                        exact = losses.bilinear_torch(y[k], spec, pos).cpu().numpy() * scale
                        floor += ((exact - truth) ** 2).sum(axis=1)
                    count += len(pos)
        out = {"val_loss": total / max(seen, 1)}
        names = {0: "normal", 1: "tangent"}
        if floor is not None:
            self._floor = {f"val_floor_rmse_{names[col]}": float(math.sqrt(floor[j] / max(count, 1)))
                           for j, col in enumerate(self.label_columns)}
        for j, col in enumerate(self.label_columns):
            out[f"val_contact_rmse_{names[col]}"] = float(math.sqrt(sq[j] / max(count, 1)))
        out.update(self.zero_baseline())
        out.update(self._floor)
        return out

    def zero_baseline(self):
        """The contact-point RMSE of predicting 0 on the validation samples, per target: what a
        network must beat to have learned anything (computed once)."""
        if not hasattr(self, "_zero"):
            names = {0: "normal", 1: "tangent"}
            sq, count = np.zeros(len(self.label_columns)), 0
            for i in self.val_idx:
                _, imp = self.ds.contacts(int(i))
                if len(imp):
                    sq += (np.array(imp)[:, self.label_columns] ** 2).sum(axis=0)
                    count += len(imp)
            self._zero = {f"val_zero_rmse_{names[col]}": float(math.sqrt(sq[j] / max(count, 1)))
                          for j, col in enumerate(self.label_columns)}
        return self._zero

    def checkpoint(self, epoch, dataset_path):
        """Everything a run needs to continue exactly: plain containers and tensors only."""
        meta = self.ds.metadata
        return {
            "format": CHECKPOINT_FORMAT, "epoch": epoch,
            "model": {k: v.detach().cpu() for k, v in self.model.state_dict().items()},
            "optimizer": self.opt.state_dict(), "rng": _rng_state(), "history": self.history, "best": self.best,
            "bad_epochs": self.bad_epochs, "network": self.net_cfg, "train_config": asdict(self.cfg),
            "targets": self.cfg.targets,
            "dataset": {k: meta[k] for k in ("grid", "inputs", "labels", "samples", "sources", "split")},
            "dataset_path": dataset_path, "threads": torch.get_num_threads(),
            "versions": {"deepcontact": __version__, "torch": str(torch.__version__), "numpy": str(np.__version__)},
            # where the network comes from: built-in, or a plug-in's target, distribution and version
            # (a record only: a checkpoint never imports code by itself)
            "network_origin": NETWORKS.origin(self.cfg.model),
        }

    def fit(self, work, progress=None, dataset_path="", out_dir=None, plots=True):
        """The remaining epochs, writing last.pt (every epoch), best.pt (on improvement) and the
        metrics into work (rank 0), and at the end the loss plot (unless not plots); early stopping
        after `patience` epochs without improvement."""
        cfg = self.cfg
        # a plug-in network's code runs in every batch (forward and backward): what leaves it is
        # one line naming it (plugins.guest)
        from contextlib import nullcontext
        from .networks import BUILTIN
        guarded = (lambda: nullcontext()) if cfg.model in BUILTIN else (lambda: guest(f"the network {cfg.model!r}"))
        for epoch in range(self.start, cfg.epochs):
            try:
                with guarded():
                    row = self.run_epoch(epoch)
            except TrainingDiverged as e:
                raise TrainingDiverged(e.message, out_dir) from None
            with guarded():
                row.update(self.validate() if len(self.val_idx) else {})
            self.history.append(row)
            score = row.get("val_loss", row["train_loss"])
            improved = score < self.best
            if improved:
                self.best, self.bad_epochs = score, 0
            else:
                self.bad_epochs += 1
            if self.rank == 0:
                _save(work / "last.pt", self.checkpoint(epoch, dataset_path))
                if improved:
                    _save(work / "best.pt", self.checkpoint(epoch, dataset_path))
                write_metrics(work, self.history)
                if progress is not None:
                    progress({**row, "epochs": cfg.epochs})
            if cfg.patience and self.bad_epochs >= cfg.patience:
                log.info("no improvement for %d epochs: stopping after epoch %d", self.bad_epochs, epoch)
                break
        if self.rank == 0 and self.history and plots:
            plot_losses(self.history, work / "loss")
        return self.history


@contextmanager
def _output_folder(out_dir, overwrite, replace, resume, rank):
    """Where this run writes: beside the old run when replacing it (swapped in at the end), or
    the folder itself, which a run that fails before writing anything leaves as it found it.
    Rank 0 alone writes, under the output's lock."""
    if rank != 0:
        yield out_dir
        return
    with output.output_folder(out_dir, MODEL_FILES, overwrite, command="train", in_place=not replace,
                              existing_ok=resume, hint="use --resume to continue a run there or --overwrite to "
                              "replace it") as work:
        yield work


def write_metrics(out_dir, history):
    keys = sorted({k for row in history for k in row}, key=lambda k: (k != "epoch", k))
    buf = io.StringIO()
    w = CsvWriter(buf)
    w.writerow(keys)
    w.writerows([row.get(k, "") for k in keys] for row in history)
    output.write_text(out_dir / "metrics.csv", buf.getvalue())
    output.write_text(out_dir / "metrics.json", json.dumps(history, indent=1) + "\n")


def plot_losses(history, stem):
    """loss.png: the training and validation loss per epoch; beside it, where validation ran, the
    RMSE at the contact points per target against predicting 0 and the grid's floor."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    from ..plotstyle import readable_log_ticks
    rmse = [k[len("val_contact_rmse_"):] for k in history[0] if k.startswith("val_contact_rmse_")]
    fig, axes = plt.subplots(1, 2 if rmse else 1, figsize=(11 if rmse else 6, 4), squeeze=False)
    ax = axes[0][0]
    epochs = [r["epoch"] for r in history]
    ax.plot(epochs, [r["train_loss"] for r in history], label="training", marker="o", ms=3)
    if "val_loss" in history[0]:
        ax.plot(epochs, [r["val_loss"] for r in history], label="validation", marker="s", ms=3, ls="--")
    if any(r["train_loss"] > 0 for r in history):   # (a log axis needs a positive value)
        ax.set_yscale("log")
        readable_log_ticks(ax.yaxis)
    ax.set_ylabel("loss")
    ax.set_title("Loss")
    if rmse:
        ax = axes[0][1]
        for i, target in enumerate(rmse):
            colour = f"C{i + 2}"
            ax.plot(epochs, [r[f"val_contact_rmse_{target}"] for r in history], color=colour, marker="o", ms=3,
                    label=f"{target}: the network")
            for key, ls, what in (("zero", "--", "predicting 0"), ("floor", ":", "the grid's floor")):
                value = history[-1].get(f"val_{key}_rmse_{target}")
                if value is not None:
                    ax.axhline(value, color=colour, ls=ls, lw=1, label=f"{target}: {what}")
        ax.set_ylabel("validation RMSE at the contacts (N·s)")
        ax.set_title("Against predicting 0")
    for ax in axes[0]:
        ax.set_xlabel("epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))   # (epochs are whole)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    # through bytes and an atomic write: training writes in place, and an interrupted run must
    # not leave half a picture
    output.write_bytes(f"{stem}.png", output.figure_bytes(fig, "png", dpi=110))
    output.write_bytes(f"{stem}.svg", output.figure_bytes(fig, "svg"))
    plt.close(fig)
