"""Scene input/output: the internal scene layout, images, and readers for the
source layouts (plain folder, COLMAP, MVImgNet, DL3DV, NeRF transforms.json)."""

from gs2e.io.scene import (Camera, Frame, Scene, read_scene, write_scene_json,
                           opengl_to_opencv, opencv_to_opengl, check_pose)

__all__ = ["Camera", "Frame", "Scene", "read_scene", "write_scene_json",
           "opengl_to_opencv", "opencv_to_opengl", "check_pose"]
