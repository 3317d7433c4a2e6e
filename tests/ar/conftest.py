"""Shared fixtures of the AR tests: the seed cantilever project at 640x360 and its short synthetic clip for the
live-server tests (physar.ar.live), rendered by the test-data renderer from a mesh finer than the model's."""
import shutil
import tomllib
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "ar" / "cantilever"
PLATEAUS = [[0, 0.42], [0.5, 0.42], [0.7, 0.2], [1.3, 0.2], [1.5, 0.42], [2.0, 0.42]]   # A -> B -> A: loops


@pytest.fixture(scope="session")
def live_clip(tmp_path_factory):
    """(project path, clip folder, frames): the cantilever project with the clip's 640x360 camera; a 2 s clip
    (60 frames) whose load dwells at 420 mm, moves to 200 mm, dwells and comes back (so a looped playback is
    continuous); the handheld camera of examples/ar/cantilever/scenario.toml."""
    from physar.ar.project import load_project
    from physar.ar.video import VideoReader
    from physar.synth.render import render_project
    from physar.synth.scenario import parse_scenario

    d = tmp_path_factory.mktemp("live_project")
    for f in ("project.toml", "rom.toml"):
        shutil.copy(EXAMPLE / f, d / f)
    shutil.copy(EXAMPLE.parents[1] / "camera_720p.toml", d / "camera.toml")
    text = (d / "project.toml").read_text().replace('"../../camera_720p.toml"', '"camera.toml"')
    (d / "project.toml").write_text(text)
    base = tomllib.loads((EXAMPLE / "scenario.toml").read_text())
    sc = parse_scenario({"seed": 3, "video": {"duration": 2.0}, "camera": base["camera"],
                         "texture": base["texture"], "schedule": {"s": {"keyframes": PLATEAUS}}})
    clip = d / "clip"
    render_project(load_project(d / "project.toml"), sc, clip, quick=True)   # half size: 640x360
    (d / "project.toml").write_text(text.replace('"camera.toml"', '"clip/camera.toml"'))
    frames = list(VideoReader(clip / "video.mp4"))
    return d / "project.toml", clip, frames
