"""Scenes: find, read and validate a scene file, and build the model and routine it asks for."""

from pulsejet_sim.scene.loader import (
    available_scenes,
    DEFAULT_SCENE,
    is_project_scene_name,
    load_scene,
    load_scene_data,
    merge,
    resolve_scene_path,
    Scene,
    scene_from_dict,
    scene_from_stored,
    SceneError,
)

__all__ = [
    'available_scenes', 'DEFAULT_SCENE', 'is_project_scene_name', 'load_scene', 'load_scene_data',
    'merge', 'resolve_scene_path', 'Scene', 'scene_from_dict', 'scene_from_stored', 'SceneError',
]
