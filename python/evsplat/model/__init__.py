"""Gaussians in canonical space, the deformation MLP and adaptive density control."""
