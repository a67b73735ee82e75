"""gs2e.export: aligned event windows and exports for event-based 3D methods.

Conventions (the one place they are defined; every reader and writer in this
package checks them at its boundary with :mod:`gs2e.export.conventions`):

* **Polarity.** gs2e files store ``p`` in {0, 1}, 1 = ON (brightness
  increase), 0 = OFF. Exports convert to what each method reads: signed
  {-1, +1} (EventNeRF, IncEventGS, E2NeRF counts), {0, 1} (EvDeblurNeRF's
  events.h5, tonic-style structured arrays).
* **Time.** gs2e times are int64 microseconds. ``events.h5`` stores them
  relative to its ``t_offset`` (the trajectory's first frame); frames,
  windows and trajectories use absolute trajectory time (``t_us``, from the
  trajectory start). Each export states its unit and origin in its
  ``gs2e_export.json`` (e.g. EventNeRF: float seconds from the first exported
  frame).
* **Windows** are half-open ``[t0_us, t1_us)`` in absolute µs; the events of a
  window are ``events[i0:i1]`` of the trajectory's events.h5 (global indices).
  A window the simulation did not fully cover has ``covered = False`` and null
  indices: "not simulated", never "no events".
* **Poses** are camera-to-world 4x4, OpenCV axes (+x right, +y down,
  +z forward); intrinsics in pixels with pixel centres at +0.5 (COLMAP).

Modules: :mod:`~gs2e.export.windows` (the windows table of a trajectory),
:mod:`~gs2e.export.source` (one trajectory's products, read once),
one module per target format (:mod:`~gs2e.export.eventnerf`,
:mod:`~gs2e.export.e2nerf`, :mod:`~gs2e.export.evdeblurnerf`,
:mod:`~gs2e.export.inceventgs`, :mod:`~gs2e.export.event3dgs`) and
:mod:`~gs2e.export.run` (``gs2e export``).
"""
