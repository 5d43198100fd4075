"""dc train: a CNN from a grid dataset."""
import time

import click

from deepcontact.model.arch import NETWORKS
from deepcontact.model.choices import LOSSES, OPTIMIZERS

from . import fenced_training, options, terminal, types


def torch_device(ctx, param, value):
    """A torch device that exists here and holds real tensors (not meta)."""
    try:
        import torch
    except ImportError:
        return value   # (the command says how to get torch, in its one line)
    try:
        device = torch.device(value)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as e:
        raise click.BadParameter(f"{value!r} is not a device available here ({options.one_line(e)})") from None
    if device.type == "meta":
        raise click.BadParameter("meta tensors hold no data: choose cpu or an accelerator")
    return value


class EpochLines:
    """What a training says as it goes (stderr; nothing with -q): a line an epoch with its
    metrics, the time an epoch takes and about how long is left (early stopping may end it
    sooner), and within an epoch a line every DC_PROGRESS_EVERY seconds on a clock from the
    epoch's start (an epoch on 2 cores can take an hour; its first batch minutes): the samples
    done of the epoch's, the rate, the time left in the epoch and in the run, validation included
    once one was timed. epochs: the run's epochs where known before its first epoch ends."""

    def __init__(self, quiet, epochs=None):
        self.quiet, self.epochs_done, self.epochs = quiet, 0, epochs
        self.start = self.last = time.monotonic()
        self.bar, self.bar_epoch = None, None
        self.trained, self.validation = None, None   # (when the pass ended; what followed it, timed)

    def epoch(self, row):
        self.epochs_done += 1
        self.last = time.monotonic()
        if self.trained is not None:   # (validation and checkpoints: after the pass, before this line)
            self.validation, self.trained = self.last - self.trained, None
        self.epochs = row["epochs"]
        self.close()   # (the epoch over: its bar says no more)
        if self.quiet:
            return
        left = self.each() * max(0, row["epochs"] - row["epoch"] - 1)
        click.echo(f"epoch {row['epoch'] + 1} of {row['epochs']}: loss {row['train_loss']:.4g}{_metrics(row)} "
                   f"({row['samples_per_second']:.0f} samples/s; {terminal.duration(self.each())} an epoch, about "
                   f"{terminal.duration(left)} left)", err=True)

    def each(self, projected=None):
        """An epoch's time: the mean of those this process finished, else this one's projected time."""
        return (self.last - self.start) / self.epochs_done if self.epochs_done else projected

    def within(self, epoch, done, total):
        """As an epoch's pass begins and after each batch (the trainer's heartbeat): the epoch's bar
        counts its samples, its clock says the lines. A later epoch's bar is dated from the last
        epoch's end; the process's first from its pass's start (before it: the set-up; in its count
        but not its rate, the part of the epoch a resumed run did)."""
        if done >= total:
            self.trained = time.monotonic()
        if self.quiet:
            return
        if self.bar is None or self.bar_epoch != epoch:
            self.close()
            first = self.epochs_done == 0
            of = f" of {self.epochs}" if self.epochs else ""
            self.bar = terminal.LineBar(total, "sample", f"train, epoch {epoch + 1}{of}",
                                        started=None if first else self.last, done=done if first else 0,
                                        then=lambda left: self.run_left(epoch, left))
            self.bar_epoch = epoch
        self.bar.update(done - self.bar.n)

    def run_left(self, epoch, left):
        """The clause on the run after this epoch's pass: about how long it has left, this epoch's
        validation and the later epochs included (each timed whole once one ended here), or "plus
        validation" until a validation was timed."""
        if not self.epochs:
            return ""
        after = self.epochs - epoch - 1
        projected = time.monotonic() - self.bar.started + left   # (this epoch's pass, as it goes)
        if self.validation is None:
            return f"; the run: about {terminal.duration(left + after * self.each(projected))} left plus validation"
        return (f"; the run: about {terminal.duration(left + self.validation + after * self.each(projected))} left, "
                f"validation included")

    def close(self):
        """The epoch's bar stopped (the epoch's own line follows)."""
        if self.bar is not None:
            self.bar.stop_clock()
            self.bar = None


def _metrics(row):
    """' val_loss=… val_contact_rmse_normal=… (0 scores …, the grid's floor …)': each contact RMSE
    between what predicting 0 scores and the grid's floor."""
    def shown(k):
        zero = row.get(k.replace("val_contact_rmse_", "val_zero_rmse_"))
        floor = row.get(k.replace("val_contact_rmse_", "val_floor_rmse_"))
        bars = ([f"0 scores {zero:.4g}"] if zero is not None else []) + \
               ([f"the grid's floor {floor:.4g}"] if floor is not None else [])
        return f" {k}={row[k]:.4g}" + (f" ({', '.join(bars)})" if bars and k != "val_loss" else "")
    return "".join(shown(k) for k in sorted(row) if k.startswith("val") and not k.startswith(("val_zero", "val_floor")))


@click.command(cls=fenced_training.RawArgsCommand)
@click.argument("dataset", type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Folder for checkpoints (last.pt, best.pt), metrics and the loss plot.")
@click.option("--arch", "model", type=types.PluginName(NETWORKS), default="fcn", show_default=True,
              help="The network: thesis (the thesis's CNN, Table 5.1), fcn (a fully convolutional "
                   "encoder-decoder), an installed plug-in's name, or package.module:Name (docs/api.md).")
@options.deprecated_alias("--model", "--arch", "model")
@click.option("--targets", type=types.CommaList(), default="normal_impulse,tangent_impulse", show_default=True,
              help="Label channels to learn: both maps at once, or one (train one model per map).")
@click.option("--loss", type=types.choice(LOSSES), default="masked",
              show_default=True, help="masked: thesis eq. 5.2; contacts: error at the contact points; mse: all "
              "nodes; solver: the step's LCP residual at the predicted start.")
@click.option("--solver-sweeps", type=types.count(), default=0, show_default=True,
              help="[solver loss] Damped Jacobi sweeps before taking the residual.")
@click.option("--optimizer", type=types.choice(OPTIMIZERS), default="sgd", show_default=True,
              help="sgd follows the thesis schedule (5e-3, 2e-3 at 100, 1e-3 at 300, 2e-4 at 500).")
@click.option("--lr", type=types.Finite(min=0, min_open=True), default=1e-3, show_default=True,
              help="Adam's learning rate.")
@click.option("--weight-decay", type=types.Finite(min=0), default=5e-4, show_default=True, help="L2 on the weights.")
@click.option("--batch-size", type=types.count(min=1), default=200, show_default=True)
@click.option("--epochs", type=types.count(min=1),
              help="Epochs in all (default 1000; with --resume, the run's own unless given).")
@click.option("--patience", type=types.count(), default=0, show_default=True,
              help="Stop after this many epochs without improvement (0: never).")
@click.option("--seed", type=types.count(), default=0, show_default=True)
@click.option("--device", default="cpu", show_default=True, callback=torch_device,
              help="torch device, e.g. cuda when a GPU is present.")
@click.option("--width", "fcn_width", type=types.count(min=1, max=4096), default=16, show_default=True,
              help="[fcn] Channels at the top.")
@click.option("--depth", "fcn_depth", type=types.count(min=1, max=12), default=3, show_default=True,
              help="[fcn] Down-sampling levels.")
@click.option("--no-final-relu", is_flag=True, help="[thesis] Drop the thesis's last ReLU (signed output).")
@click.option("--resume", is_flag=True, help="Continue the run in OUTPUT exactly where it stopped: after its last "
              "whole epoch, or within the epoch from its mid-epoch.pt.")
@click.option("--checkpoint-every", type=types.Finite(min=0), default=5.0, show_default=True, metavar="MINUTES",
              help="Within an epoch, keep mid-epoch.pt (model, optimizer, RNG states, the epoch's sample order and "
                   "place) at most this often, so a stop loses minutes, not the epoch (0: after every batch).")
@options.plots("Draw loss.png/svg at the end; --no-plots writes the checkpoints and metrics alone.")
@options.threads
@options.max_memory
@options.overwrite
@options.verbosity
@options.unfenced
@options.command("train")
def train(dataset, out, model, targets, loss, optimizer, lr, weight_decay, batch_size, epochs, patience, seed,
          threads, device, fcn_width, fcn_depth, no_final_relu, solver_sweeps, resume, checkpoint_every, plots,
          max_memory, overwrite, verbose, quiet):
    """Train a network mapping the input images of DATASET to its impulse images.

    Writes OUTPUT/last.pt and best.pt (atomically, every epoch), metrics.csv and
    metrics.json, and loss.png/svg; within an epoch, mid-epoch.pt every
    --checkpoint-every minutes. The split is the dataset's, by simulation.
    Same seed, same weights; --resume continues exactly, from within an epoch
    too. Under torchrun (WORLD_SIZE set) it trains data-parallel and rank 0
    writes (whole epochs only).

    \b
    Examples:
      dc train data/thesis -o models/fcn --epochs 50 --patience 10
      dc train data/thesis -o models/thesis --arch thesis --epochs 1000
      dc train data/thesis -o models/normal --targets normal_impulse
      dc train data/thesis -o models/fcn --resume
      torchrun --nproc_per_node 2 -m deepcontact.cli.main train data/thesis -o models/ddp
    """
    from deepcontact.model.config import TrainConfig
    from deepcontact.model.train import train as run

    if overwrite and resume:
        raise click.UsageError("--resume and --overwrite contradict each other")
    if not resume:   # (with --resume, the run's own settings decide: train() compares what was given)
        options.refuse_inapplicable([
            ("no_final_relu", model == "thesis", "only applies to --arch thesis (the FCN has no final ReLU)"),
            ("fcn_width", model == "fcn", "only applies to --arch fcn"),
            ("fcn_depth", model == "fcn", "only applies to --arch fcn"),
            ("lr", optimizer == "adam", "only applies to --optimizer adam (SGD follows the thesis's schedule)"),
            ("solver_sweeps", loss == "solver", "only applies to --loss solver"),
        ])
    cfg = TrainConfig(model=model, targets=targets, loss=loss,
                      optimizer=optimizer, lr=lr, weight_decay=weight_decay, batch_size=batch_size, epochs=epochs or 1000,
                      patience=patience, seed=seed, final_relu=not no_final_relu, fcn_width=fcn_width,
                      fcn_depth=fcn_depth, solver_sweeps=solver_sweeps)

    lines = EpochLines(quiet, epochs if resume else cfg.epochs)
    fields = {"model": "model", "targets": "targets", "loss": "loss", "optimizer": "optimizer", "lr": "lr",
              "weight_decay": "weight_decay", "batch_size": "batch_size", "patience": "patience", "seed": "seed",
              "no_final_relu": "final_relu", "fcn_width": "fcn_width", "fcn_depth": "fcn_depth",
              "solver_sweeps": "solver_sweeps"}
    given = {field: getattr(cfg, field) for param, field in fields.items() if options.was_given(param)}
    if fenced_training.fenced(model):   # (a plug-in network's code never runs in this process)
        raise click.exceptions.Exit(fenced_training.run(click.get_current_context(), model, out, overwrite, resume,
                                                        device, max_memory))
    options.load_network(model if not resume or "model" in given else None)   # (the user's explicit choice)
    try:
        history = run(dataset, out, None if resume else cfg, resume=resume, progress=lines.epoch, threads=threads,
                      device=device, overwrite=overwrite, epochs=epochs if resume else None, max_memory=max_memory,
                      given=given, plots=plots, heartbeat=lines.within, keep_every=checkpoint_every * 60)
    finally:
        lines.close()
    import os
    if not quiet and history and os.environ.get("RANK", "0") == "0":
        shown = os.environ.get(fenced_training.INSIDE) or out   # (fenced: the user's folder, not the staged one)
        click.echo(f"{shown}: {len(history)} epochs; best.pt and last.pt written", err=True)
