"""The contact problem of a step and the project's PGS solver (Box2D-exact and beyond)."""
