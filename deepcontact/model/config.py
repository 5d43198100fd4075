"""A training run's configuration (TrainConfig), its checks, and the learning rate schedule."""
import math
from dataclasses import asdict, dataclass, field

from ..errors import OptionError
from . import losses
from .arch import NETWORKS
from .choices import OPTIMIZERS
from .networks import CONFIG_LIMITS


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
        for name, low, high, low_open in (("lr", 0.0, math.inf, True), ("momentum", 0.0, 1.0, False),
                                          ("weight_decay", 0.0, math.inf, False), ("dropout", 0.0, 1.0, False)):
            value = getattr(self, name)
            if not _in_range(name, value, low, high, low_open):
                raise OptionError(f"{name.replace('_', ' ')} must be a finite number in "
                                  f"{'(' if low_open else '['}{low:g}, {high:g}{')' if name == 'dropout' or high == math.inf else ']'}"
                                  f", got {value!r}", "--" + name.replace("_", "-"))
        for name, low in (("batch_size", 1), ("epochs", 1), ("patience", 0), ("seed", 0), ("fcn_width", 1),
                          ("fcn_depth", 1), ("solver_sweeps", 0)):
            value = getattr(self, name)
            if type(value) is not int or not low <= value <= 2 ** 31 - 1:
                raise OptionError(f"{name.replace('_', ' ')} must be a whole number from {low} to {2 ** 31 - 1}, "
                                  f"got {value!r}", "--" + name.replace("_", "-"))
        self._check_choices()

    def _check_choices(self):
        """The named settings, as a config file's are held (config_problem): refused here, not at the
        first use of a name that names nothing (a list of numbers as targets, a number as loss)."""
        if isinstance(self.targets, tuple):
            self.targets = list(self.targets)
        for name, flag in (("model", "--arch"), ("targets", "--targets"), ("loss", "--loss"),
                           ("optimizer", "--optimizer"), ("final_relu", "--no-final-relu")):
            value = getattr(self, name)
            problem = _kind_problem(name, value, bool if name == "final_relu" else list if name == "targets" else str)
            problem = problem or _value_problem(name, value)
            if problem:
                raise OptionError(problem, flag)


def _in_range(name, value, low, high, low_open):
    """Whether a real setting is a finite number in its range (a dropout of 1 drops everything)."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            and (value > low if low_open else value >= low) and value <= high and not (name == "dropout" and value == 1))


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
        problem = _kind_problem(k, v, type(defaults[k])) or _value_problem(k, v)
        if problem:
            return problem
    return None


def _kind_problem(k, v, want):
    """A setting's value of the wrong kind, said, or None."""
    if want is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return f"{k!r} must be a finite number, not {v!r}"
    elif type(v) is not want:
        return f"{k!r} must be {want.__name__}, not {v!r}"
    return None


def _value_problem(k, v):
    """A setting's value outside its range or its choices, said, or None."""
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


def network_config(cfg: TrainConfig, meta, targets):
    """The network's config for a dataset's metadata and the targets it predicts."""
    spec = meta["grid"]
    return dict(model=cfg.model, in_channels=len(meta["inputs"]), out_channels=len(targets),
                height=spec["ny"], width=spec["nx"], dropout=cfg.dropout, final_relu=cfg.final_relu,
                fcn_width=cfg.fcn_width, fcn_depth=cfg.fcn_depth)
