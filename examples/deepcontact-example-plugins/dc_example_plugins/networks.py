"""A network as a plug-in: two convolutions, the smallest thing that maps input images to impulse
images on the grid.

The contract (docs/api.md, "Bring your own network"): a class (or function) called with
in_channels, out_channels, height, width (the grid) that returns a torch.nn.Module mapping a batch
of input images (B, in_channels, height, width) to impulse images (B, out_channels, height, width),
buildable on torch's meta device (plain torch layers are: its size is checked before it is
allocated). `dc train --arch` saves its name in the checkpoint; `dc evaluate --arch` must name it
again to load it, since a checkpoint never imports code by itself.
"""
from torch import nn


class TinyConv(nn.Sequential):
    """A 3x3 convolution to `hidden` channels, a ReLU, and a 1x1 convolution to the labels."""

    def __init__(self, in_channels, out_channels, height, width, hidden=8):
        super().__init__(nn.Conv2d(in_channels, hidden, 3, padding=1), nn.ReLU(),
                         nn.Conv2d(hidden, out_channels, 1))
