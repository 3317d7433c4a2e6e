"""Reduced parametric models (seed 000 §2.2–§5): separated representation, intrusive and
non-intrusive PGD, POD baseline."""
from physar.rom.pgd import pgd_linear, pgd_linear_tensor
from physar.rom.separated import FORMAT_VERSION, ReducedModelError, SeparatedModel

__all__ = ["FORMAT_VERSION", "ReducedModelError", "SeparatedModel", "pgd_linear", "pgd_linear_tensor"]
