"""gs2e.light: the light a virtual capture is made under.

A lighting *condition* (``light.conditions``: day, indoor, dim, night, a
dimming ramp, mains flicker, an HDR step) scales the trained radiance, in
linear light, by ``s(t) = E(t) / light.reference_lux``, ``E`` the scene's
illuminance in lux-equivalents. The render stage's frame camera and the event
stage both take the same :class:`gs2e.light.curve.LightCurve`, so frames and
events see one light. A run is ``<trajectory>@<condition>``; a trajectory
without a condition is rendered at the trained radiance, as before (``s = 1``,
no light applied, the same bytes).

Pure functions live in ``curve``; ``settings`` types the ``light`` section.
"""
