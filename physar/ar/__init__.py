"""AR layer (seed 000 §2.1, §5): synthetic scenes, video I/O, overlay and the frame loop."""

# Public API: these submodules (imported on use, not with the package). The scene modules (scene, foam,
# seal) are synthetic test scenes, not API.
__all__ = ["demo", "overlay", "pipeline", "project", "project_pipeline", "runner", "sources", "surface", "video"]
