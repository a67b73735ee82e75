"""gs2e.demo: the built-in demo scene.

A small static, object-centric scene (two boxes, a sphere and a cylinder on a
tiled ground inside a cylindrical wall), textured with photographs bundled in
scikit-image and ray-cast with numpy from views on an orbit with known
cameras. ``gs2e demo-scene --out DIR`` writes it in the internal scene layout
(:mod:`gs2e.io.scene`, layout ``"demo"``): images/NNN.png, scene.json with
PINHOLE intrinsics and ground-truth camera-to-world poses (OpenCV axes, world
+z up) and points3d.npz with surface points and their colours.

Modules (import them directly; this package stays light for ``gs2e --help``):

- :mod:`gs2e.demo.textures` -- bundled photos -> texture atlas with bilinear lookup
- :mod:`gs2e.demo.geometry` -- analytic ray-primitive intersections
- :mod:`gs2e.demo.world`    -- world layout, orbit cameras, ``cast``, ``shade``,
  ``render_view``, ``sample_points``
- :mod:`gs2e.demo.io`       -- ``generate_demo_scene(out, cfg)``
- :mod:`gs2e.demo.cli`      -- the ``demo-scene`` subcommand
"""
