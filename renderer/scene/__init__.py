"""Scenes: the scene-format schema, loading and validation (``docs/scene-format.md``).

``load_scene(dict)`` for documents from the HTTP API, ``load_scene_file(path)`` for the CLI; both
return a validated ``Scene`` or raise ``SceneError`` naming every problem by its JSON path.
"""

from renderer.scene.limits import Limits
from renderer.scene.load import SceneError, load_scene, load_scene_file
from renderer.scene.schema import Scene

__all__ = ["Limits", "Scene", "SceneError", "load_scene", "load_scene_file"]
