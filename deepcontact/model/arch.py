"""The registry of networks (no torch imported until a network is built): built-ins and
plug-ins alike. A factory is called with in_channels, out_channels, height, width (the grid) and
those of the config's other keys it declares, and returns a torch.nn.Module mapping input images
(B, in_channels, height, width) to impulse images (B, out_channels, height, width)."""
from ..plugins import Registry

NETWORKS = Registry("network", "deepcontact.networks")


@NETWORKS.register("thesis")
def thesis(in_channels, out_channels, height, width, dropout=0.1, final_relu=True):
    """The thesis's CNN (Table 5.1, Appendix C)."""
    from .networks import ThesisCNN
    return ThesisCNN(in_channels, out_channels, height, width, dropout=dropout, final_relu=final_relu)


@NETWORKS.register("fcn")
def fcn(in_channels, out_channels, height=None, width=None, fcn_width=16, fcn_depth=3):
    """A fully convolutional encoder-decoder (any grid size: height and width are not needed)."""
    from .networks import FCN
    return FCN(in_channels, out_channels, width=fcn_width, depth=fcn_depth)


BUILTIN = tuple(NETWORKS.builtin())
