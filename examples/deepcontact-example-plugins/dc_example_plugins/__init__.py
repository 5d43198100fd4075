"""Example deepcontact plug-ins (docs/api.md): a warm start to copy and change."""
