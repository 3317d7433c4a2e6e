"""Reduced parametric models (seed 000 §2.2–§4): separated representation, PGD."""
from physar.rom.pgd import pgd_linear
from physar.rom.separated import FORMAT_VERSION, SeparatedModel

__all__ = ["SeparatedModel", "pgd_linear", "FORMAT_VERSION"]
