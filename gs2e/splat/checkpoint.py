"""Training checkpoints: one file per run, resumed only by the same config,
scene and seed, written atomically, removed after a successful run."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import torch

from gs2e.common.atomic import atomic_path, sweep_output
from gs2e.common.log import get_logger

log = get_logger("gs2e.splat")


def config_hash(cfg: dict, scene_dir: Path) -> str:
    """Short sha256 of the splat config and the scene folder."""
    return hashlib.sha256(json.dumps([cfg, str(scene_dir)], sort_keys=True).encode()).hexdigest()[:16]


class Checkpoint:
    """``<folder>/checkpoint.pt`` of the run identified by (config, scene, seed).

    The file holds a dict: the loop's state (see :func:`gs2e.splat.train.train`)
    and ``hash``, the run's identity.
    """

    def __init__(self, folder: str | Path, cfg: dict, scene_dir: Path, seed: int):
        self.folder = Path(folder)
        self.path = self.folder / "checkpoint.pt"
        self.key = config_hash(cfg, scene_dir) + f"-{seed}"

    def load(self) -> dict[str, Any] | None:
        """The saved state if it exists, can be read and belongs to this run,
        else None (a checkpoint is only a shortcut: training then starts from
        the beginning)."""
        if not self.path.exists():
            return None
        try:
            state = torch.load(self.path, weights_only=False)
            if not isinstance(state, dict):
                raise ValueError(f"a {type(state).__name__}, not a checkpoint")
        except Exception as exc:  # truncated or foreign file: torch raises several types
            log.warning("ignoring unreadable checkpoint %s (%s); training from the start", self.path,
                        " ".join(str(exc).split())[:200])
            return None
        if state.get("hash") != self.key:
            log.info("ignoring checkpoint %s (different config or seed)", self.path)
            return None
        return state

    def save(self, state: dict[str, Any]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.path) as tmp:
            torch.save({"hash": self.key, **state}, tmp)

    def remove(self) -> None:
        """Delete the checkpoint, any temporary of a write killed earlier, and
        the folder if that is then empty."""
        if self.path.exists():
            self.path.unlink()
        if self.folder.is_dir():
            sweep_output(self.path)
            try:
                self.folder.rmdir()
            except OSError:
                pass
