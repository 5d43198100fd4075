"""Training: a network from a grid dataset, with checkpoints that resume exactly.

Every epoch writes `metrics.csv` / `metrics.json`, `last.pt`, and `best.pt` when the validation
loss (the training loss without a validation split) improves, all atomically. A checkpoint holds
the model config, weights, optimizer state, epoch, every RNG state, the history and the
dataset's metadata, so `resume` continues as if never stopped, and the same seed gives the same
weights. With WORLD_SIZE set (torchrun), training is data-parallel over gloo; rank 0 alone writes.
"""
import csv
import io
import json
import logging
import math
import os
import pickle
import random
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from .. import __version__, atomic
from ..errors import InputError
from ..grid.dataset import GridDataset
from ..grid.spec import GridSpec
from ..resources import check_memory
from . import losses
from .networks import build, check_config, parameter_count, shape_problem, training_memory

log = logging.getLogger(__name__)
CHECKPOINT_FORMAT = 2   # 2: plain containers and tensors only, loadable with weights_only=True
# Everything a training folder holds: what --overwrite may replace.
MODEL_FILES = atomic.Owned("training run", [r"(last|best)\.pt", r"metrics\.(csv|json)", r"loss\.(png|svg)"])


@dataclass
class TrainConfig:
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
    path = Path(path)
    if path.exists() and not (path.is_file() or path.is_dir()):   # a FIFO would block torch.load
        raise InputError("not a regular file", path)
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError("no such checkpoint", path) from None
    except IsADirectoryError:
        raise InputError("a folder, not a checkpoint file", path) from None
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
    problem = check_config(ck["network"]) or shape_problem(ck["network"], ck["model"])
    if problem:
        raise InputError(f"refused: {problem}", path)
    return ck


def _save(path, obj):
    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic.write_bytes(path, buf.getvalue())


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


def train(dataset, out_dir, cfg: TrainConfig = None, resume=False, progress=None, threads=None, device="cpu",
          overwrite=False, epochs=None, max_memory=None):
    """Train; returns the history (a list of per-epoch metric dicts).

    Everything is checked before the output folder is touched. With `overwrite`, the new run is
    built beside the old one and replaces it only when it finishes. `epochs` overrides the
    configuration's (or, with `resume`, the checkpoint's) number of epochs. max_memory: refuse a
    network and batch estimated to need more GB (default resources.DEFAULT_MAX_MEMORY_GB)."""
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
    cfg = cfg or TrainConfig()
    if epochs is not None:
        cfg.epochs = epochs
    if cfg.loss not in losses.LOSSES:
        raise InputError(f"unknown loss {cfg.loss!r}; choose from {', '.join(losses.LOSSES)}")
    missing = [t for t in cfg.targets if t not in meta["labels"]]
    if missing or not cfg.targets:
        raise InputError(f"the dataset's labels are {', '.join(meta['labels'])}; no {', '.join(missing) or 'target'}",
                         dataset)
    target_idx = [meta["labels"].index(t) for t in cfg.targets]
    label_columns = [{"normal_impulse": 0, "tangent_impulse": 1}[t] for t in cfg.targets
                     if t in ("normal_impulse", "tangent_impulse")]
    if cfg.loss in ("contacts", "solver") and len(label_columns) != len(cfg.targets):
        raise InputError(f"the {cfg.loss} loss needs impulse targets (normal_impulse, tangent_impulse)")
    solver_loss = losses.SolverLoss(ds, sweeps=cfg.solver_sweeps) if cfg.loss == "solver" else None
    train_idx = ds.indices("train")
    val_idx = ds.indices("validation")
    if len(train_idx) == 0:
        raise InputError("the dataset has no training samples", dataset)
    net_cfg = network_config(cfg, meta, cfg.targets)
    problem = check_config(net_cfg)
    if problem:
        raise InputError(problem)
    check_memory(training_memory(net_cfg, cfg.batch_size, cfg.optimizer), max_memory,
                 f"training the {cfg.model} network with batches of {cfg.batch_size}")
    # Replacing an earlier run builds the new one beside it; otherwise training writes in place,
    # so that an interrupted run can be resumed from its last.pt.
    replace = overwrite and out_dir.is_dir() and any(out_dir.iterdir())

    def kept():
        """What a failed run leaves, said as it is."""
        if replace:
            return "the earlier run is left as it was"
        return f"the last good checkpoint is kept ({last})" if last.exists() else "no checkpoint was written"
    with _output_folder(out_dir, overwrite, replace, resume, rank) as work:
        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)
        random.seed(cfg.seed)
        torch.use_deterministic_algorithms(True, warn_only=True)
        model = build(net_cfg).to(device)
        if cfg.optimizer == "sgd":
            opt = torch.optim.SGD(model.parameters(), lr=thesis_lr(0), momentum=cfg.momentum, weight_decay=cfg.weight_decay)
        elif cfg.optimizer == "adam":
            opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        else:
            raise InputError(f"unknown optimizer {cfg.optimizer!r}; choose sgd or adam")
        history, best, bad_epochs, start = [], math.inf, 0, 0
        if ck is not None:
            model.load_state_dict(ck["model"])
            opt.load_state_dict(ck["optimizer"])  # (its tensors follow the parameters' device)
            _set_rng_state(ck["rng"])
            history, best, bad_epochs, start = ck["history"], ck["best"], ck["bad_epochs"], ck["epoch"] + 1
        net = model
        if world > 1:
            net = torch.nn.parallel.DistributedDataParallel(model)
        spec = GridSpec(**meta["grid"])
        inputs, labels = ds.arrays["inputs"], ds.arrays["labels"]

        def batch(indices):
            idx = np.sort(indices)   # reading a memory map in order
            x = torch.from_numpy(np.ascontiguousarray(inputs[idx])).to(device)
            y = torch.from_numpy(np.ascontiguousarray(labels[idx][:, target_idx])).to(device)
            for name, t in (("inputs", x), ("labels", y)):
                if not torch.isfinite(t).all():
                    k = int(idx[int(torch.nonzero(~torch.isfinite(t.flatten(1)).all(dim=1))[0])])
                    raise InputError(f"sample {k} holds a NaN or infinite value; {kept()}", ds.path / f"{name}.npy")
            return idx, x, y

        def loss_of(pred, y, idx):
            if cfg.loss == "masked":
                return losses.masked_mse(pred, y)
            if cfg.loss == "mse":
                return losses.mse(pred, y)
            if cfg.loss == "solver":
                return solver_loss(pred, idx, spec, label_columns)
            pos, imp = zip(*(ds.contacts(int(i)) for i in idx))
            return losses.contact_mse(pred, [torch.from_numpy(np.array(p)).to(device) for p in pos],
                                      [torch.from_numpy(np.array(q)).to(device) for q in imp], spec, label_columns)

        def save(name, epoch):
            _save(work / name, {
                "format": CHECKPOINT_FORMAT, "epoch": epoch,
                "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
                "optimizer": opt.state_dict(), "rng": _rng_state(), "history": history, "best": best,
                "bad_epochs": bad_epochs, "network": net_cfg, "train_config": asdict(cfg), "targets": cfg.targets,
                "dataset": {k: meta[k] for k in ("grid", "inputs", "labels", "samples", "sources", "split")},
                "dataset_path": str(dataset),
                "versions": {"deepcontact": __version__, "torch": str(torch.__version__), "numpy": str(np.__version__)},
            })

        if rank == 0 and not resume:
            params, _ = parameter_count(model)
            log.info("%s model: %s parameters; %d training and %d validation samples", cfg.model, f"{params:,}",
                     len(train_idx), len(val_idx))
        for epoch in range(start, cfg.epochs):
            lr = thesis_lr(epoch) if cfg.optimizer == "sgd" else cfg.lr
            for g in opt.param_groups:
                g["lr"] = lr
            gen = torch.Generator().manual_seed(cfg.seed * 100003 + epoch)
            order = train_idx[torch.randperm(len(train_idx), generator=gen).numpy()]
            net.train()
            t0 = time.perf_counter()
            total, seen = 0.0, 0
            for b0 in range(0, len(order), cfg.batch_size):
                chunk = order[b0:b0 + cfg.batch_size][rank::world]
                if len(chunk) == 0:
                    continue
                idx, x, y = batch(chunk)
                opt.zero_grad()
                loss = loss_of(net(x), y, idx)
                if not torch.isfinite(loss):
                    raise TrainingDiverged(f"the loss became {loss.item()} in epoch {epoch}; {kept()}", out_dir)
                loss.backward()
                opt.step()
                total += loss.item() * len(idx)
                seen += len(idx)
            seconds = time.perf_counter() - t0
            if world > 1:   # the epoch's loss over all ranks' samples
                sums = torch.tensor([total, float(seen)], dtype=torch.float64)
                torch.distributed.all_reduce(sums)
                total, seen = float(sums[0]), int(sums[1])
            row = {"epoch": epoch, "lr": lr, "train_loss": total / max(seen, 1), "seconds": seconds,
                   "samples_per_second": seen / max(seconds, 1e-9)}
            row.update(evaluate(model, ds, val_idx, target_idx, label_columns, spec, cfg, loss_of, batch)
                       if len(val_idx) else {})
            history.append(row)
            score = row.get("val_loss", row["train_loss"])
            improved = score < best
            if improved:
                best, bad_epochs = score, 0
            else:
                bad_epochs += 1
            if rank == 0:
                save("last.pt", epoch)
                if improved:
                    save("best.pt", epoch)
                write_metrics(work, history)
            if progress is not None and rank == 0:
                progress(row)
            if cfg.patience and bad_epochs >= cfg.patience:
                log.info("no improvement for %d epochs: stopping after epoch %d", bad_epochs, epoch)
                break
        if rank == 0 and history:
            plot_losses(history, work / "loss")
        if world > 1:
            torch.distributed.barrier()   # no rank leaves while rank 0 still writes
            torch.distributed.destroy_process_group()
        return history


@contextmanager
def _output_folder(out_dir, overwrite, replace, resume, rank):
    """Where this run writes: beside the old run when replacing it (swapped in at the end), or
    the folder itself, which a run that fails before writing anything leaves as it found it.
    Rank 0 alone writes, under the output's lock."""
    if rank != 0:
        yield out_dir
        return
    with atomic.output_folder(out_dir, MODEL_FILES, overwrite, command="train", in_place=not replace,
                              existing_ok=resume, hint="use --resume to continue a run there or --overwrite to "
                              "replace it") as work:
        yield work


@torch.no_grad()
def evaluate(model, ds, idx, target_idx, label_columns, spec, cfg, loss_of, batch):
    """Validation loss and the RMSE at the contact points, per target."""
    model.eval()
    total, seen = 0.0, 0
    sq = np.zeros(len(label_columns))
    count = 0
    for b0 in range(0, len(idx), cfg.batch_size):
        ids, x, y = batch(idx[b0:b0 + cfg.batch_size])
        pred = model(x)
        total += loss_of(pred, y, ids).item() * len(ids)
        seen += len(ids)
        if label_columns:
            scale = 1.0 if spec.renormalize else spec.cell ** 2
            for k, i in enumerate(ids):
                pos, imp = ds.contacts(int(i))
                if len(pos) == 0:
                    continue
                at = losses.bilinear_torch(pred[k], spec, torch.from_numpy(np.array(pos)).to(pred.device))
                at = at.cpu().numpy() * scale
                sq += ((at - np.array(imp)[:, label_columns].T) ** 2).sum(axis=1)
                count += len(pos)
    out = {"val_loss": total / max(seen, 1)}
    names = {0: "normal", 1: "tangent"}
    for j, col in enumerate(label_columns):
        out[f"val_contact_rmse_{names[col]}"] = float(math.sqrt(sq[j] / max(count, 1)))
    return out


def write_metrics(out_dir, history):
    keys = sorted({k for row in history for k in row}, key=lambda k: (k != "epoch", k))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys)
    w.writeheader()
    w.writerows(history)
    atomic.write_text(out_dir / "metrics.csv", buf.getvalue())
    atomic.write_text(out_dir / "metrics.json", json.dumps(history, indent=1) + "\n")


def plot_losses(history, stem):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    epochs = [r["epoch"] for r in history]
    ax.plot(epochs, [r["train_loss"] for r in history], label="training")
    if "val_loss" in history[0]:
        ax.plot(epochs, [r["val_loss"] for r in history], label="validation")
    if any(r["train_loss"] > 0 for r in history):   # (a log axis needs a positive value)
        ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("loss")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(f"{stem}.png", dpi=110)
    fig.savefig(f"{stem}.svg")
    plt.close(fig)
