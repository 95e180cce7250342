"""Synthetic scenes rendered with Mitsuba 3, with exactly known cameras."""

from synth.config import CometParams, SceneConfig, UavParams, preset
from synth.render import SceneResult, render_scene
from synth.scene import PinholeCamera, Scene, View, load_scene

__all__ = ["CometParams", "PinholeCamera", "Scene", "SceneConfig", "SceneResult", "UavParams", "View",
           "load_scene", "preset", "render_scene"]
