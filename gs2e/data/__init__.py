"""gs2e.data: a torch ``Dataset`` over a gs2e results tree.

One item per frame window (between consecutive frames, or over a blurred
frame's exposure) of every selected scene x trajectory whose events were
simulated::

    from torch.utils.data import DataLoader
    from gs2e.data import EventWindowDataset, collate_windows

    ds = EventWindowDataset("results", representation="voxel", n_bins=5)
    for batch in DataLoader(ds, batch_size=4, num_workers=2, collate_fn=collate_windows):
        batch["events"]  # (B, 5, H, W) voxel grids; batch["rgb"], ["c2w"], ["K"], ...

Conventions are those of :mod:`gs2e.export`: events.h5 polarity 1 = ON /
0 = OFF (voxel grids add +1 / -1; raw arrays keep 0/1 in tonic's field
layout x, y, t, p with t int64 absolute microseconds), poses camera-to-world
with OpenCV axes, intrinsics in pixels with pixel centres at +0.5.
"""

from gs2e.data.dataset import EventWindowDataset, collate_windows

__all__ = ["EventWindowDataset", "collate_windows"]
