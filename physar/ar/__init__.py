"""AR layer (seed 000 §2.1, §5): the AR project file, frame sources, the one frame loop, the overlay, reports."""

# Public API: these submodules (imported on use, not with the package).
__all__ = ["project", "project_pipeline", "runner", "sources", "surface", "video"]
