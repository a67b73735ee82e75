"""Frames along trajectories: sharp and motion-blurred RGB, depth and alpha at
a dataset frame rate, and the linear-luminance signal events are simulated
from, rendered on demand with an adaptive time step."""
