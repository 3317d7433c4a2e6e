"""Reduced parametric models (seed 000 §2.2–§5): separated representation, intrusive and
non-intrusive PGD, POD baseline."""
from physar.rom.elastic import build_moving_load_pgd
from physar.rom.pgd import pgd_linear, pgd_linear_tensor
from physar.rom.separated import FORMAT_VERSION, ReducedModelError, SeparatedModel

__all__ = ["FORMAT_VERSION", "ReducedModelError", "SeparatedModel", "build_moving_load_pgd", "pgd_linear",
           "pgd_linear_tensor"]
