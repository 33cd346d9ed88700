"""Integrations that run inside other programs: :mod:`~bezmotion.integrations.blender_curves`, a script for Blender (it imports neither jax nor bezmotion)."""
