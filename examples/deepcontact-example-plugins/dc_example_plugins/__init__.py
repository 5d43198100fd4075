"""Example deepcontact plug-ins (docs/api.md): a warm start and a network to copy and change."""
