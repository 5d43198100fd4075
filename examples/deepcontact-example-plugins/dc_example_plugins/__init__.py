"""Example deepcontact plug-ins (docs/api.md): a warm start, a network and a solver method to copy
and change."""
