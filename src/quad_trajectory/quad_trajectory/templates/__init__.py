"""Trajectory templates to copy (docs/plugins.md): a mission's `trajectory.generator: package.module:Class`."""
