"""Rasterizer backends behind :func:`gs2e.splat.rasterize.rasterize`.

``cpu`` (the default) is gs2e's own numba rasterizer: bit-identical between
runs and thread counts, float32 or float64. ``gsplat`` hands the same
parameters to gsplat's CUDA rasterizer (``gsplat.rasterization``) when a CUDA
device and the gsplat package are present; it computes in float32 on the GPU
and returns CPU tensors of the input dtype, so callers do not change. It is
optional and never required: ``auto`` picks it when available, else ``cpu``.

Conventions mapped (both follow the official 3DGS code): quaternions (w,x,y,z)
unnormalised, scales = exp(log_scales), opacity = sigmoid(logits), colour =
max(SH + 0.5, 0), 0.3 px^2 low-pass added to the 2D covariance, pixel
centres at integer + 0.5, expected depth = accumulated z / alpha.
"""

from __future__ import annotations

import functools

import torch

from gs2e.common.errors import ConfigError, InputError

BACKENDS = ("cpu", "gsplat", "auto")


@functools.lru_cache(maxsize=None)
def gsplat_status() -> tuple[bool, str]:
    """(available, reason): whether the gsplat CUDA backend can run here."""
    if not torch.cuda.is_available():
        return False, "no CUDA device is visible to torch"
    try:
        import gsplat  # noqa: F401
    except ImportError as exc:  # optional dependency: pip install gsplat
        return False, f"the gsplat package is not installed ({exc})"
    return True, f"gsplat {getattr(gsplat, '__version__', '?')} on {torch.cuda.get_device_name(0)}"


def resolve_backend(name: str, key: str = "splat.backend") -> str:
    """The backend to use for config value ``name`` ('cpu', 'gsplat' or 'auto').

    Raises ConfigError naming ``key`` for an unknown name, or for 'gsplat'
    where it cannot run.
    """
    if name not in BACKENDS:
        raise ConfigError(f"config key '{key}': unknown backend {name!r}, expected one of {BACKENDS}")
    if name == "cpu":
        return "cpu"
    ok, why = gsplat_status()
    if name == "gsplat" and not ok:
        raise ConfigError(f"config key '{key}' is 'gsplat' but it cannot run here: {why} "
                          "(use 'cpu' or 'auto')")
    return "gsplat" if ok else "cpu"


def resolve_backend_for(name: str, window: str, key: str = "splat.backend") -> str:
    """:func:`resolve_backend` for a model of compositing ``window``: gsplat
    composites with the cut window only, so for another 'auto' means 'cpu'
    and 'gsplat' raises ConfigError naming ``key``."""
    if window == "cut":
        return resolve_backend(name, key)
    if name == "gsplat":
        raise ConfigError(f"config key '{key}': gsplat composites with the cut window only; the model's "
                          f"window is {window} (use 'cpu' or 'auto')")
    return resolve_backend("cpu" if name == "auto" else name, key)


def rasterize_gsplat(means, quats, log_scales, opacity_logits, sh, cam, background, sh_degree: int):
    """Same contract as :func:`gs2e.splat.rasterize.rasterize` (checked inputs),
    computed by gsplat on the first CUDA device.

    ``meta['grad2d']`` (N,2) float64 is filled during backward from the
    gradient of gsplat's 2D means (px), as the CPU backend does.
    """
    from gsplat import rasterization

    from gs2e.splat.finite import NonFiniteError, check_finite

    dev = torch.device("cuda")
    dt = means.dtype
    vm = cam.validate()

    def to_dev(x):
        return x.to(device=dev, dtype=torch.float32)

    K = torch.tensor([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]],
                     dtype=torch.float32, device=dev)
    colors, alphas, info = rasterization(
        to_dev(means), to_dev(quats), torch.exp(to_dev(log_scales)), torch.sigmoid(to_dev(opacity_logits)),
        to_dev(sh), torch.as_tensor(vm, dtype=torch.float32, device=dev)[None], K[None],
        int(cam.width), int(cam.height), near_plane=float(cam.near), far_plane=float(cam.far),
        eps2d=0.3, sh_degree=int(sh_degree), packed=False, tile_size=16,
        backgrounds=to_dev(background)[None], render_mode="RGB+ED", rasterize_mode="classic")
    image = colors[0, ..., :3].to(device="cpu", dtype=dt)
    depth = colors[0, ..., 3].to(device="cpu", dtype=dt)
    alpha = alphas[0, ..., 0].to(device="cpu", dtype=dt)
    radii = info["radii"][0]
    if radii.dim() == 2:  # newer gsplat: per-axis radii
        radii = radii.max(dim=-1).values
    means2d = info["means2d"]
    n = means.shape[0]
    meta = {"radii": radii.to("cpu", torch.int64), "means2d": means2d[0].detach().double().cpu(),
            "depths": info["depths"][0].detach().double().cpu(),
            "conics": info["conics"][0].detach().double().cpu(),
            "n_pairs": int(info["flatten_ids"].numel()),
            "grad2d": torch.zeros((n, 2), dtype=torch.float64)}
    if means2d.requires_grad:
        def keep_grad2d(g):
            check_finite("gradient of means2d", g[0])
            meta["grad2d"].copy_(g[0].detach().double().cpu())
        means2d.register_hook(keep_grad2d)
    for name, x in (("image", image), ("alpha", alpha)):
        if not bool(torch.isfinite(x).all()):
            raise NonFiniteError(f"gsplat backend produced a non-finite {name}")
    if depth.shape != (int(cam.height), int(cam.width)):
        raise InputError(f"gsplat backend returned depth of shape {tuple(depth.shape)}")
    return image, alpha, depth, meta
