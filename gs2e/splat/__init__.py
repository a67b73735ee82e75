"""gs2e.splat: CPU Gaussian splatting (differentiable rasterizer, trainer, official file formats).

Public API: :func:`gs2e.splat.rasterize.rasterize`, :class:`SplatCamera`,
:class:`NonFiniteError`.
"""

