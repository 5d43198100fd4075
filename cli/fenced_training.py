"""dc train with a plug-in network (--arch pkg.mod:Net, or an installed one): the network's code
runs in every batch, so the whole training runs fenced (deepcontact/contest/job.py), as a study
does. This process keeps the output: it checks and locks it as every training run does, gives the
training a copy of what it resumes from in a folder of its own, and writes back what it wrote
(checkpoints, metrics, the loss plot: nothing else), in place or swapped in, by the rules of an
unfenced run; the user's stop ends the training at once and keeps its last whole epoch, as an
unfenced run does.

What comes back is the network's to make (its code runs in the process that writes it), so each
file is opened once through the staging folder's descriptor and checked on the opened file
(contest/returned.py: no link followed, no FIFO waited on, nothing sparse, nothing past its kind's
bound), and a checkpoint is loaded whole from the bytes read, and must continue the run's own,
before it takes the place of the user's (_Keeper)."""
import glob
import os
import re
import shutil
from contextlib import ExitStack
from pathlib import Path

import click

INSIDE = "DC_TRAIN_FENCED"   # set for the fenced training's own process: the user's output, for its lines
MID_EPOCH = "mid-epoch.pt"   # (model/train.py's, named here without importing torch)
# The most a file a training writes may hold, but a checkpoint (bounded by the training's own
# memory, --max-memory: it holds the weights and the optimizer's state, a part of what training
# needs): the metrics (metrics.json: 470 bytes an epoch, tests/conftest.py's model) and the plot.
FILE_LIMIT = 64 << 20


class RawArgsCommand(click.Command):
    """A click command that keeps the arguments it was given (ctx.meta["raw_args"]), to hand them on."""

    def parse_args(self, ctx, args):
        ctx.meta["raw_args"] = list(args)
        return super().parse_args(ctx, args)


def fenced(model):
    """Whether training with the network `model` runs fenced here."""
    from deepcontact.model.arch import BUILTIN
    from deepcontact.contest.fence import fenced as plugin_fenced
    return plugin_fenced(model not in BUILTIN)


class _Keeper:
    """Keeps the user's run up to date with what the fenced training hands back, each time it is
    called: each file a training run writes, changed since, read once from the staging folder
    (returned.Staging) and written whole in `work`; a checkpoint only where it loads from the bytes
    read and continues the run's own (checkpoint.succession_problem: its history its epochs', the
    same network, dataset and targets, an epoch not before the one it replaces). mid-epoch.pt is
    removed where the training removed it once last.pt holds its epoch; nothing else is ever
    removed. Anything else is a PluginError naming the network and the user's file, which is as
    it was. shown: the user's output; checkpoint_limit: the most bytes a checkpoint may hold."""

    def __init__(self, staging, work, shown, model, checkpoint_limit):
        from deepcontact.model.arch import NETWORKS
        NETWORKS.choose(model)   # (its checkpoints read here, its code never imported: model.networks)
        self.staging, self.work, self.shown, self.model = staging, Path(work), Path(shown), model
        self.who, self.checkpoint_limit = f"the training of the network {model!r}", checkpoint_limit
        self.seen = {}     # name: identity of the version in work (kept, or the copy the training was given)
        self.epochs = {}   # name: the epoch of the checkpoint in work (None: not one dc reads)
        self.run = None    # checkpoint.run_of the run's checkpoints

    def given(self):
        """What the staging folder holds now, as the training is given it (the run it resumes):
        not handed back unless it changes."""
        self.seen = {name: self.staging.identity(name) for name in self.staging.names()}

    def __call__(self):
        names = self._names()
        for name in names:
            identity = self.staging.identity(name)
            if identity is not None and self.seen.get(name) != identity:
                self._keep(name)
        self._forget(names)

    def _names(self):
        """The names in staging of what a training run writes (not its record, not a file being
        written); PluginError for any other."""
        from deepcontact import output
        from deepcontact.model.checkpoint_file import MODEL_FILES
        from deepcontact.plugins import PluginError
        found = []
        for name in self.staging.names():
            if name == output.RECORD or output.temporary_name(name):
                continue
            if not any(re.fullmatch(p, name) for p in MODEL_FILES.patterns):
                raise PluginError(f"{self.who} wrote {name!r}, which a training run never writes: not kept",
                                  self.shown)
            found.append(name)
        return found

    def _keep(self, name):
        from deepcontact import output
        from deepcontact.contest import returned
        limit = self.checkpoint_limit if name.endswith(".pt") else FILE_LIMIT
        try:
            data, identity = self.staging.read(name, limit)
        except FileNotFoundError:   # (gone since it was listed: the next call sees what took its place)
            return
        except returned.Refused as e:
            raise self._refused(name, f"as {e}") from None
        if name.endswith(".pt"):
            self.epochs[name] = self._checked_epoch(name, data)
        output.write_bytes(self.work / name, data)
        self.seen[name] = identity

    def _checked_epoch(self, name, data):
        """The epoch of the checkpoint `name` handed back as data; PluginError where it does not
        load, or does not continue the run's own."""
        from deepcontact.errors import InputError
        from deepcontact.model.checkpoint import load_checkpoint, run_of, succession_problem
        after = self._epoch_there(name)
        try:
            ck = load_checkpoint(self.shown / name, data=data)
        except InputError as e:
            raise self._refused(name, f"that does not load as a checkpoint ({e.message})") from None
        problem = (f"it is of another network ({ck['network'].get('model')!r})"
                   if ck["network"].get("model") != self.model else
                   succession_problem(ck, name == MID_EPOCH, self.run, after))
        if problem:
            raise self._refused(name, f"that does not continue the run: {problem}")
        self.run = self.run or run_of(ck)
        return ck["epoch"]

    def _epoch_there(self, name):
        """The epoch of the checkpoint `name` in work (read once: the user's, or the last kept),
        None where there is none dc reads; the first one read names the run (run_of)."""
        from deepcontact.errors import InputError
        from deepcontact.model.checkpoint import load_checkpoint, run_of
        if name not in self.epochs:
            self.epochs[name] = None
            try:
                ck = load_checkpoint(self.work / name) if (self.work / name).is_file() else None
            except InputError:   # (a damaged file of the user's: replaced by one that loads)
                ck = None
            if ck is not None:
                self.epochs[name], self.run = ck["epoch"], self.run or run_of(ck)
        return self.epochs[name]

    def _forget(self, names):
        """mid-epoch.pt removed from work where the training removed it and last.pt holds its epoch
        (a network that removes it otherwise leaves the user's)."""
        if MID_EPOCH not in self.seen or MID_EPOCH in names:
            return
        within, whole = self._epoch_there(MID_EPOCH), self._epoch_there("last.pt")
        if within is not None and whole is not None and whole >= within:
            (self.work / MID_EPOCH).unlink(missing_ok=True)
            self.epochs[MID_EPOCH] = None
        del self.seen[MID_EPOCH]

    def _refused(self, name, what):
        from deepcontact.plugins import PluginError
        there = "the run's own is as it was" if (self.work / name).exists() else "nothing of it was kept"
        return PluginError(f"{self.who} handed back {name} {what}: not kept ({there})", self.shown / name)


def _keep_last(keeper, code, record, ordered):
    """The keeper's last call, after the training ended; a refusal says how it ended where that
    was not in order (a crash, a signal)."""
    from deepcontact.contest import job
    from deepcontact.plugins import PluginError
    try:
        keeper()
    except PluginError as e:
        if ordered:
            raise
        raise PluginError(f"{e.message}; it ended its process ({job.how(code, record)})", e.path) from None


def run(ctx, model, out, overwrite, resume, device, max_memory=None):
    """Runs the training fenced; returns its exit status. max_memory: the training's --max-memory
    (GB), which bounds a checkpoint it hands back."""
    from deepcontact import output, protocol
    from deepcontact.contest import job, result, returned
    from deepcontact.errors import InputError
    from deepcontact.model.checkpoint_file import MODEL_FILES
    from deepcontact.resources import DEFAULT_MAX_MEMORY_GB
    if os.environ.get("WORLD_SIZE") or os.environ.get("RANK"):
        raise InputError("a plug-in network trains in a sandbox of its own, where torchrun's processes cannot reach "
                         "one another: train it in one process (without torchrun)")
    out = Path(out)
    replace = overwrite and out.is_dir() and any(out.iterdir())
    who = f"the training of the network {model!r}"
    with ExitStack() as stack:
        private = Path(stack.enter_context(output.private_folder("train")))
        work = Path(stack.enter_context(output.output_folder(
            out, MODEL_FILES, overwrite, command="train", in_place=not replace, existing_ok=resume,
            hint="use --resume to continue a run there or --overwrite to replace it")))
        staged = private / "run"
        staged.mkdir()
        if resume and out.is_dir():   # (a copy: the user's files are not the training's to change)
            for entry in os.listdir(out):
                if os.path.isfile(out / entry) and not os.path.islink(out / entry):
                    shutil.copyfile(out / entry, staged / entry)
        keeper = _Keeper(stack.enter_context(returned.Staging(staged)), work, out, model,
                         int((max_memory or DEFAULT_MAX_MEMORY_GB) * 2 ** 30))
        keeper.given()
        args = list(ctx.meta["raw_args"])
        where, prefix, _, _ = job.output_argument(args)   # (-o is required: it is there)
        args[where] = prefix + str(staged)
        devices = [] if device == "cpu" else sorted(glob.glob("/dev/nvidia*") + glob.glob("/dev/dri/*"))
        # kept in place as it is written (an unfenced run keeps each whole epoch as it ends: a stop
        # or a failure leaves the last one), or swapped in once it has finished (replacing a run)
        code = job.run(["train", *args], [private], private, {INSIDE: str(out)}, protocol.command_line, devices,
                       poll=None if replace else keeper, who=who, profile="training")
        record = job.ended(private)
        ordered = result.ended_in_order(record, code)
        if not replace or ordered and code == 0:
            _keep_last(keeper, code, record, ordered)
        job.refuse_unordered(code, record, who)
        if code != 0:
            raise click.exceptions.Exit(code)   # (its own line said why; an earlier run replaced is as it was)
    return 0
