"""The registry of networks (no torch imported until a network is built): built-ins and
plug-ins alike. A factory is called with in_channels, out_channels, height, width (the grid) and
those of the config's other keys it declares, and returns a torch.nn.Module mapping input images
(B, in_channels, height, width) to impulse images (B, out_channels, height, width)."""
from ..plugins import Registry

NETWORKS = Registry("network", "deepcontact.networks")


# The built-ins, named by their place: the registry imports no torch until one is built.
NETWORKS.register("thesis", "deepcontact.model.networks:thesis")
NETWORKS.register("fcn", "deepcontact.model.networks:fcn")


BUILTIN = tuple(NETWORKS.builtin())
