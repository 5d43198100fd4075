"""Training: a network from a grid dataset, with checkpoints that resume exactly.

Every epoch writes `metrics.csv` / `metrics.json`, `last.pt`, and `best.pt` when the validation
loss (the training loss without a validation split) improves, all atomically. A checkpoint holds
the model config, weights, optimizer state, epoch, every RNG state, the history and the
dataset's metadata, so `resume` continues as if never stopped, and the same seed gives the same
weights. Within an epoch, `mid-epoch.pt` keeps the same at most every `keep_every` seconds, with
the epoch's sample order and how far it got (its `position`), so that a stop within a long epoch
loses minutes, not the epoch; it is removed when the epoch's last.pt is written. With WORLD_SIZE
set (torchrun), training is data-parallel over gloo; rank 0 alone writes (epochs only: a
mid-epoch checkpoint would hold rank 0's share of the epoch's sums alone).
"""
import logging
import math
import os
import random
import time
from collections.abc import Callable
from contextlib import contextmanager, nullcontext
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from .. import __version__, output
from ..errors import InputError, OptionError
from ..grid.dataset import GridDataset
from ..grid.spec import GridSpec
from ..plugins import guest
from ..resources import check_memory
from . import losses
from .arch import NETWORKS
from .checkpoint import (CHECKPOINT_FORMAT, check_compatible, check_same_run, load_checkpoint, rng_state, save,
                         set_rng_state)
from .checkpoint_file import MODEL_FILES
from .config import TrainConfig, network_config, thesis_lr
from .networks import BUILTIN, build, check_config, check_network, parameter_count, training_memory
from .plots import plot_losses, write_metrics

log = logging.getLogger(__name__)

MID_EPOCH = "mid-epoch.pt"   # the checkpoint kept within an epoch (removed once its last.pt is written)
KEEP_EVERY = 300.0           # seconds between mid-epoch checkpoints at most (dc train --checkpoint-every)


class TrainingDiverged(InputError):
    """The loss became NaN or infinite: the run stops, its last good checkpoint kept."""


def _distributed():
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not torch.distributed.is_initialized():
        torch.distributed.init_process_group("gloo")
    rank = torch.distributed.get_rank() if world > 1 else 0
    return world, rank


def train(dataset: str | os.PathLike, out_dir: str | os.PathLike, cfg: TrainConfig | None = None, resume: bool = False,
          progress: Callable | None = None, threads: int = 1, device: str = "cpu", overwrite: bool = False,
          epochs: int | None = None, max_memory: float | None = None, given: dict = (), plots: bool = True,
          heartbeat: Callable | None = None, keep_every: float | None = KEEP_EVERY) -> list[dict]:
    """Train; returns the history (a list of per-epoch metric dicts).

    progress(row): called after each epoch with its metrics (and "epochs", the run's number of
    epochs); heartbeat(epoch, samples done, samples in the epoch): as an epoch's training pass
    begins (the samples a resumed one had done) and after each batch (a caller's sign of life
    within a long epoch).

    Everything is checked before the output folder is touched. With `overwrite`, the new run is
    built beside the old one and replaces it only when it finishes. `epochs` overrides the
    configuration's (or, with `resume`, the checkpoint's) number of epochs. max_memory: refuse a
    network and batch estimated to need more GB (default resources.DEFAULT_MAX_MEMORY_GB).
    threads: torch's threads, 1: the count changes the order of float sums (1 and 2 threads
    trained weights 1.3e-4 apart), and the same seed must give the same weights on any machine;
    more processes (torchrun) are the way to train on more cores. plots: draw loss.png/svg at the
    end (False: none; refused when resuming a run that has one, which would no longer match its
    metrics). keep_every: write mid-epoch.pt at most every this many seconds within an epoch (None:
    never; 0: after every batch), which `resume` continues from as if never stopped."""
    device = _device(threads, device)
    world, rank = _distributed()
    ds = GridDataset(dataset)
    out_dir = Path(out_dir)
    last = out_dir / "last.pt"
    ck = _resumed(last, ds, given, threads, dataset, plots) if resume else None
    cfg = TrainConfig(**ck["train_config"]) if ck is not None else (cfg or TrainConfig())
    if epochs is not None:
        cfg.epochs = epochs
    net_cfg = _check_run(cfg, ds, dataset, max_memory)
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
        if rank == 0:
            trainer.say_what_it_trains(fresh=ck is None)
        trainer.heartbeat = heartbeat if rank == 0 else None
        history = trainer.fit(work, progress, dataset_path=str(dataset), out_dir=out_dir, plots=plots,
                              keep_every=keep_every)
        if world > 1:
            torch.distributed.barrier()   # no rank leaves while rank 0 still writes
            torch.distributed.destroy_process_group()
        return history


def _device(threads, device):
    """The torch device, checked, with torch's threads set (one: see train)."""
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
    return device


def _resumed(last, ds, given, threads, dataset, plots):
    """The checkpoint --resume continues from, checked against the dataset and the options."""
    meta = ds.metadata
    ck = _latest(last, ds)
    try:
        TrainConfig(**ck["train_config"])
    except TypeError as e:
        raise InputError(f"refused: the training config does not fit this version ({e})", last) from None
    check_compatible(ck, meta, last)
    check_same_run(ck, meta, last, given, threads, dataset)
    if not plots and any((last.parent / f"loss.{ext}").exists() for ext in ("png", "svg")):
        raise OptionError("the run has a loss plot from before, which its new epochs would leave behind: "
                          "resume without --no-plots to redraw it", "--no-plots")
    return ck


def _latest(last, ds):
    """The checkpoint a run continues from: mid-epoch.pt where it is of the epoch after last.pt's
    (the run stopped within that epoch), else last.pt (a mid-epoch.pt of an epoch last.pt has
    finished is left over from a stop between the two writes, and ignored)."""
    mid = last.with_name(MID_EPOCH)
    done = load_checkpoint(last) if last.exists() or not mid.exists() else None   # (none there: it says so)
    within = load_checkpoint(mid) if mid.exists() else None
    if within is not None and within["epoch"] == (done["epoch"] + 1 if done is not None else 0):
        if "position" not in within:
            raise InputError("refused: a mid-epoch checkpoint without its 'position' in the epoch", mid)
        order = within["position"]["order"].numpy()
        if not np.array_equal(np.sort(order), np.sort(ds.indices("train"))):
            raise InputError("refused: its sample order is not an order of this dataset's training samples", mid)
        return within
    if done is None:
        raise InputError(f"no last.pt of epoch {within['epoch']} beside it, which it continues", mid)
    return done


def _check_run(cfg, ds, dataset, max_memory):
    """What a run asks for, checked against its dataset and the memory it may take, before the
    output folder is touched; the network's config."""
    meta = ds.metadata
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
    return net_cfg


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
        self.position = None                  # where the first epoch run continues (a mid-epoch checkpoint's)
        self.keep, self.keep_every = None, KEEP_EVERY   # keep(epoch, position): writes a mid-epoch checkpoint

    def say_what_it_trains(self, fresh):
        """The log lines a run starts with: an empty validation split warned of, and (fresh) the
        network's size and the samples."""
        if not len(self.val_idx):
            log.warning("the dataset has no validation samples: best.pt is the epoch of the lowest training loss, "
                        "and nothing says whether the network generalises (dc rasterize --validation F)")
        if fresh:
            params, _ = parameter_count(self.model)
            log.info("%s model: %s parameters; %d training and %d validation samples", self.cfg.model, f"{params:,}",
                     len(self.train_idx), len(self.val_idx))

    def resume_from(self, ck):
        """Every state the checkpoint ck holds, restored: after its epoch, or within it (a
        mid-epoch checkpoint's position)."""
        self.model.load_state_dict(ck["model"])
        self.opt.load_state_dict(ck["optimizer"])  # (its tensors follow the parameters' device)
        set_rng_state(ck["rng"])
        self.history, self.best, self.bad_epochs = ck["history"], ck["best"], ck["bad_epochs"]
        self.position = ck.get("position")
        self.start = ck["epoch"] if self.position is not None else ck["epoch"] + 1

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

    def run_epoch(self, epoch, position=None):
        """One pass over the training samples in this epoch's seeded order, or the rest of it from
        `position` (a mid-epoch checkpoint's: its order, next sample and sums so far); the
        metrics row. Keeps a mid-epoch checkpoint (keep) at most every keep_every seconds."""
        cfg = self.cfg
        lr = thesis_lr(epoch) if cfg.optimizer == "sgd" else cfg.lr
        for g in self.opt.param_groups:
            g["lr"] = lr
        if position is None:
            gen = torch.Generator().manual_seed(cfg.seed * 100003 + epoch)
            order = self.train_idx[torch.randperm(len(self.train_idx), generator=gen).numpy()]
            position = {"next": 0, "total": 0.0, "seen": 0, "seconds": 0.0}
        else:
            order = position["order"].numpy()
        self.net.train()
        t0 = time.perf_counter() - position["seconds"]
        total, seen = position["total"], position["seen"]
        self.kept_at = time.monotonic()
        if getattr(self, "heartbeat", None) is not None:   # (the epoch begun: its bar's clock runs from here)
            self.heartbeat(epoch, position["next"], len(order))
        for b0 in range(position["next"], len(order), cfg.batch_size):
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
            if b0 + cfg.batch_size < len(order):
                self.keep_within(epoch, {"order": order, "next": b0 + cfg.batch_size, "total": total, "seen": seen,
                                         "seconds": time.perf_counter() - t0})
            if getattr(self, "heartbeat", None) is not None:
                self.heartbeat(epoch, min(b0 + cfg.batch_size, len(order)), len(order))
        seconds = time.perf_counter() - t0
        if self.world > 1:   # the epoch's loss over all ranks' samples
            sums = torch.tensor([total, float(seen)], dtype=torch.float64)
            torch.distributed.all_reduce(sums)
            total, seen = float(sums[0]), int(sums[1])
        return {"epoch": epoch, "lr": lr, "train_loss": total / max(seen, 1), "seconds": seconds,
                "samples_per_second": seen / max(seconds, 1e-9)}

    def keep_within(self, epoch, position):
        """A mid-epoch checkpoint at `position` (keep), if keep_every seconds have passed since the
        last one (or the epoch's start)."""
        if self.keep is not None and time.monotonic() - self.kept_at >= self.keep_every:
            self.keep(epoch, {**position, "order": torch.from_numpy(np.asarray(position["order"], dtype=np.int64))})
            self.kept_at = time.monotonic()

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
            "optimizer": self.opt.state_dict(), "rng": rng_state(), "history": self.history, "best": self.best,
            "bad_epochs": self.bad_epochs, "network": self.net_cfg, "train_config": asdict(self.cfg),
            "targets": self.cfg.targets,
            "dataset": {k: meta[k] for k in ("grid", "inputs", "labels", "samples", "sources", "split")},
            "dataset_path": dataset_path, "threads": torch.get_num_threads(),
            "versions": {"deepcontact": __version__, "torch": str(torch.__version__), "numpy": str(np.__version__)},
            # where the network comes from: built-in, or a plug-in's target, distribution and version
            # (a record only: a checkpoint never imports code by itself)
            "network_origin": NETWORKS.origin(self.cfg.model),
        }

    def fit(self, work, progress=None, dataset_path="", out_dir=None, plots=True, keep_every=KEEP_EVERY):
        """The remaining epochs, writing last.pt (every epoch), best.pt (on improvement) and the
        metrics into work (rank 0), and at the end the loss plot (unless not plots); early stopping
        after `patience` epochs without improvement. keep_every: seconds between mid-epoch
        checkpoints at most (None: none), in one process only (see the module's note)."""
        cfg = self.cfg
        if keep_every is not None and self.world == 1:
            self.keep_every = keep_every
            self.keep = lambda epoch, position: save(work / MID_EPOCH, {**self.checkpoint(epoch, dataset_path),
                                                                      "position": position})
        # a plug-in network's code runs in every batch (forward and backward): what leaves it is
        # one line naming it (plugins.guest)
        guarded = (lambda: nullcontext()) if cfg.model in BUILTIN else (lambda: guest(f"the network {cfg.model!r}"))
        for epoch in range(self.start, cfg.epochs):
            try:
                with guarded():
                    row = self.run_epoch(epoch, self.position if epoch == self.start else None)
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
                save(work / "last.pt", self.checkpoint(epoch, dataset_path))
                if improved:
                    save(work / "best.pt", self.checkpoint(epoch, dataset_path))
                (work / MID_EPOCH).unlink(missing_ok=True)   # (the epoch it was within is whole in last.pt)
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


