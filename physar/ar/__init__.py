"""AR layer (seed 000 §2.1, §5): synthetic scenes, video I/O, overlay and the frame loop."""
