"""Test-data generators, apart from the product pipeline: a synthetic, handheld video of ANY AR project (its
object deformed by a finer finite-element model, its markers and dots, a textured wall, sensor noise and
occluders) with the truth of every frame, and the accuracy of a run against it."""
from physar.synth.render import ProjectRenderer, rasterize, render_project
from physar.synth.scenario import Resolved, Scenario, load_scenario
from physar.synth.score import score
from physar.synth.truth import FineTruth, refine_tets

__all__ = ["FineTruth", "ProjectRenderer", "Resolved", "Scenario", "load_scenario", "rasterize", "refine_tets",
           "render_project", "score"]
