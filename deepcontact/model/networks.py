"""The two networks: the thesis's CNN, faithfully, and a fully convolutional encoder-decoder.

`thesis` (thesis Table 5.1 and Appendix C): five stacks of convolutions 32-64-128-256-512 with
ReLU (3x3 in the first stacks, 2x2 later, as the appendix's code has them), 2x2 max pooling with
'same' padding between stacks, batch norm before the third and fifth stacks, dropout 0.1, then a
dense layer to every output node, He-normal initialisation. Like the thesis it ends in a ReLU, so
it cannot produce the negative half of the tangent impulses: kept for fidelity, documented, and
not a model to rely on (`final_relu=False` removes it).

`fcn`: a U-Net-like encoder-decoder with skip connections, `width` channels at the top, doubling
`depth` times, outputting the label image at grid resolution with signed values. Far fewer
weights; any grid size (padded to a multiple of 2^depth and cropped back).
"""
import warnings

import torch
from torch import nn
import torch.nn.functional as F

from ..plugins import PluginError, guest
from .arch import BUILTIN, NETWORKS

# PyTorch notes that 'same' padding with the appendix's 2x2 kernels copies the input; it is right.
warnings.filterwarnings("ignore", message="Using padding='same' with even kernel lengths")


def _he(module):
    # (none on torch's meta device, which has no values to draw: normal_ there imports
    # torch._dynamo, about 1 s of CPU in each checkpoint's load, a network's contestant's setup too)
    if isinstance(module, (nn.Conv2d, nn.Linear)) and not module.weight.is_meta:
        nn.init.kaiming_normal_(module.weight, nonlinearity="relu")
        nn.init.zeros_(module.bias)


class ThesisCNN(nn.Module):
    def __init__(self, in_channels, out_channels, height, width, dropout=0.1, final_relu=True):
        super().__init__()
        self.out_shape = (out_channels, height, width)

        def conv(cin, cout, k):
            return [nn.Conv2d(cin, cout, k, padding="same"), nn.ReLU()]

        def pool():
            return [nn.MaxPool2d(2, 2, ceil_mode=True)]   # Keras 'same' pooling: 61 -> 31 -> 16 -> 8 -> 4
        layers = (conv(in_channels, 32, 3) + conv(32, 32, 3) + [nn.Dropout(dropout)] + pool()
                  + conv(32, 64, 3) + conv(64, 64, 3) + conv(64, 64, 2) + [nn.Dropout(dropout)] + pool()
                  + [nn.BatchNorm2d(64)]
                  + conv(64, 128, 2) + conv(128, 128, 2) + conv(128, 128, 2) + [nn.Dropout(dropout)] + pool()
                  + conv(128, 256, 2) + conv(256, 256, 2) + conv(256, 256, 2) + [nn.Dropout(dropout)] + pool()
                  + [nn.BatchNorm2d(256)]
                  + conv(256, 512, 2) + conv(512, 512, 2) + conv(512, 512, 2) + [nn.Dropout(dropout)])
        self.features = nn.Sequential(*layers)
        h, w = height, width
        for _ in range(4):
            h, w = (h + 1) // 2, (w + 1) // 2
        self.dense = nn.Linear(512 * h * w, out_channels * height * width)
        self.final_relu = final_relu
        self.apply(_he)

    def forward(self, x):
        y = self.dense(torch.flatten(self.features(x), 1))
        if self.final_relu:
            y = F.relu(y)
        return y.view(x.shape[0], *self.out_shape)


class _Block(nn.Sequential):
    def __init__(self, cin, cout):
        super().__init__(nn.Conv2d(cin, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ReLU(),
                         nn.Conv2d(cout, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ReLU())


class FCN(nn.Module):
    def __init__(self, in_channels, out_channels, width=16, depth=3):
        super().__init__()
        self.depth = depth
        chans = [width * 2 ** i for i in range(depth + 1)]
        self.down = nn.ModuleList([_Block(in_channels, chans[0])] +
                                  [_Block(chans[i], chans[i + 1]) for i in range(depth)])
        self.up = nn.ModuleList([nn.ConvTranspose2d(chans[i + 1], chans[i], 2, stride=2) for i in reversed(range(depth))])
        self.merge = nn.ModuleList([_Block(2 * chans[i], chans[i]) for i in reversed(range(depth))])
        self.head = nn.Conv2d(chans[0], out_channels, 1)
        self.apply(_he)

    def forward(self, x):
        h, w = x.shape[-2:]
        m = 2 ** self.depth
        x = F.pad(x, (0, (-w) % m, 0, (-h) % m))
        skips = []
        for i, block in enumerate(self.down):
            x = block(x)
            if i < self.depth:
                skips.append(x)
                x = F.max_pool2d(x, 2)
        for up, merge in zip(self.up, self.merge):
            x = merge(torch.cat([up(x), skips.pop()], dim=1))
        return self.head(x)[..., :h, :w]


# --- The registry: built-ins and plug-ins alike ------------------------------------------------
# A network factory is called with in_channels, out_channels, height, width (the grid) and those
# of the config's other keys it declares; it returns a torch.nn.Module mapping a batch of input
# images (B, in_channels, height, width) to impulse images (B, out_channels, height, width).

# (the registry lives in model/arch.py, which imports no torch: the CLI reads its names)


def require_named(name):
    """PluginError unless the network `name` (read from a checkpoint) is a built-in or the user
    named it (--arch): a name read from a checkpoint never imports code by itself."""
    if not NETWORKS.chosen(name):
        raise PluginError(f"the network {name!r} is a plug-in: name it with --arch {name} to load it")


def _factory(name):
    require_named(name)
    factory = NETWORKS.resolved(name)
    return factory if factory is not None else NETWORKS.load(name)   # (chosen, loaded where it runs)


def build(config):
    """A network from its config dict (stored in checkpoints): a built-in, or a plug-in loaded by
    the user's explicit choice (NETWORKS.load)."""
    import inspect
    name = config["model"]
    factory = _factory(name)
    grid = {k: config[k] for k in ("in_channels", "out_channels", "height", "width") if k in config}
    try:
        wanted = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        wanted = {}
    extra = {k: v for k, v in config.items() if k in wanted and k not in grid and k != "model"}
    if name in BUILTIN:
        return factory(**grid, **extra)
    with guest(f"the network {name!r}", "could not be built:"):
        model = factory(**grid, **extra)
    if not isinstance(model, nn.Module):   # (a function given where the factory goes, say: it ran as the factory)
        raise PluginError(f"the network {name!r} is a factory returning {type(model).__name__}, not a "
                          "torch.nn.Module: register a class or a function that builds the network "
                          "(docs/api.md, \"Bring your own network\")")
    return model


def check_network(model, config, name=None):
    """A plug-in network held to the contract: one zero batch in, impulse images of the grid's
    shape out, finite; else one line naming it."""
    if config["model"] in BUILTIN:
        return
    c, h, w = config["in_channels"], config["height"], config["width"]
    want = (1, config["out_channels"], h, w)
    with guest(f"the network {config['model']!r}", f"failed on a batch of shape (1, {c}, {h}, {w}):"), \
            torch.no_grad():
        was = model.training
        model.eval()
        out = model(torch.zeros(1, c, h, w))
        model.train(was)
    if not isinstance(out, torch.Tensor) or tuple(out.shape) != want:
        raise PluginError(f"the network {config['model']!r} maps (1, {c}, {h}, {w}) to "
                          f"{tuple(getattr(out, 'shape', ())) or type(out).__name__}; it must give {want}")
    if not torch.isfinite(out).all():
        raise PluginError(f"the network {config['model']!r} gives non-finite values for a zero input")


def parameter_count(model):
    """Weights as Keras counts them: parameters plus batch-norm running statistics."""
    params = sum(p.numel() for p in model.parameters())
    stats = sum(b.numel() for name, b in model.named_buffers() if name.endswith(("running_mean", "running_var")))
    return params, params + stats


# What a network config may ask for: beyond these a config is a mistake or tampering (a width of
# 10**6 would ask for terabytes before anything could say so).
CONFIG_LIMITS = {"in_channels": (1, 64), "out_channels": (1, 64), "height": (1, 4096), "width": (1, 4096),
                 "fcn_width": (1, 4096), "fcn_depth": (1, 12)}


def check_config(config):
    """Why a network config cannot be built, or None."""
    if not isinstance(config, dict) or not isinstance(config.get("model"), str):
        return "the network config names no network"
    if not NETWORKS.chosen(config["model"]):
        return (f"the network {config['model']!r} is a plug-in: name it with --arch {config['model']} to load it "
                "(a checkpoint never imports code by itself)")
    for key, (low, high) in CONFIG_LIMITS.items():
        value = config.get(key, low if key.startswith("fcn") else None)
        if type(value) is not int or not low <= value <= high:
            return f"network {key} must be a whole number from {low} to {high}, got {value!r}"
    dropout = config.get("dropout", 0.1)
    if not isinstance(dropout, (int, float)) or isinstance(dropout, bool) or not 0 <= dropout < 1:
        return f"network dropout must be in [0, 1), got {dropout!r}"
    if not isinstance(config.get("final_relu", True), bool):
        return "network final_relu must be true or false"
    return None


def on_meta(config):
    """The network built on torch's meta device: shapes and counts, no memory (a plug-in must
    allow it, as networks of plain torch layers do)."""
    with guest(f"the network {config['model']!r}", "cannot be built on torch's meta device (needed to check its "
                                                      "size before allocating it):"), torch.device("meta"):
        return build(config)


def shape_problem(config, state):
    """Why a state dict does not fit the network config (names or tensor shapes), or None. A
    plug-in network chosen but not loaded here (dc evaluate's judge: its code runs only in the
    contestants' sandboxes) is checked where it is built, when its weights are loaded."""
    if NETWORKS.resolved(config["model"]) is None:
        return None
    want = on_meta(config).state_dict()
    if not isinstance(state, dict) or set(state) != set(want):
        missing = sorted(set(want) - set(state)) if isinstance(state, dict) else []
        return f"its weights do not belong to this network ({'missing ' + missing[0] if missing else 'other names'})"
    for name, tensor in want.items():
        got = state[name]
        if not isinstance(got, torch.Tensor) or tuple(got.shape) != tuple(tensor.shape):
            return f"weight {name} has shape {tuple(getattr(got, 'shape', ()))}, the network needs {tuple(tensor.shape)}"
        if got.dtype != tensor.dtype:
            return f"weight {name} is {got.dtype}, the network needs {tensor.dtype}"
    return None


def training_memory(config, batch_size, optimizer="adam"):
    """Bytes training needs, estimated on the meta device: the weights, their gradients and the
    optimizer's state (two moments for Adam, one momentum for SGD), and every module's output for
    one batch kept for the backward pass (twice: the output and its gradient)."""
    model = on_meta(config)
    params = sum(p.numel() * p.element_size() for p in model.parameters())
    activations = 0

    def count(module, inputs, output):
        nonlocal activations
        if isinstance(output, torch.Tensor) and not list(module.children()):
            activations += output.numel() * output.element_size()
    hooks = [m.register_forward_hook(count) for m in model.modules()]
    x = torch.empty(batch_size, config["in_channels"], config["height"], config["width"], device="meta")
    with guest(f"the network {config['model']!r}", "cannot run on torch's meta device (needed to estimate its "
                                                   "memory before allocating it; no .item() there):"):
        model(x)
    for h in hooks:
        h.remove()
    return params * (2 + (2 if optimizer == "adam" else 1)) + 2 * activations


def thesis(in_channels, out_channels, height, width, dropout=0.1, final_relu=True):
    """The thesis's CNN (Table 5.1, Appendix C): the built-in network "thesis"."""
    return ThesisCNN(in_channels, out_channels, height, width, dropout=dropout, final_relu=final_relu)


def fcn(in_channels, out_channels, height=None, width=None, fcn_width=16, fcn_depth=3):
    """A fully convolutional encoder-decoder (any grid size: height and width are not needed): the
    built-in network "fcn"."""
    return FCN(in_channels, out_channels, width=fcn_width, depth=fcn_depth)
