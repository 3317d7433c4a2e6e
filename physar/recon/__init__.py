"""Physics-based reconstruction of a human and a soft object from one video (seed 002, PhysHO §4-§5).

Synthetic scenes (:mod:`physar.recon.synth`), a user's video imported (:mod:`physar.recon.importer`), metrics
(:mod:`physar.recon.metrics`), and the training pipeline with its baselines (:mod:`physar.recon.train`).
"""

# Public API: these submodules (imported on use, not with the package: train needs PyTorch).
__all__ = ["canonical", "flow", "importer", "io", "metrics", "synth", "train"]
