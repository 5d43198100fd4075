"""Example deepcontact plug-ins (docs/api.md): a warm start, a network, a solver method and an
engine to copy and change."""
