"""Write a rendered scene as a MOTChallenge sequence folder, atomically."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from gldt_core.io.mot import write_mot
from gldt_core.io.mot_folder import write_seqinfo
from gldt_core.sim.render import SceneRenderer


def write_mot_sequence(renderer: SceneRenderer, out: Path, *, jpeg_quality: int = 95, overwrite: bool = False) -> str:
    """Render every frame into ``out/img1/%06d.jpg`` with ``gt/gt.txt`` and ``seqinfo.ini``.

    Written into a temporary sibling folder and renamed when complete, so an interrupted run
    never leaves a sequence whose images and ground truth disagree.
    """
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:
        raise ValueError(f"{out} exists and is not empty (use --force to replace it)")
    parent = out.parent
    if not parent.is_dir():
        raise FileNotFoundError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"output folder {parent} is not writable")
    spec = renderer.spec
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=parent))
    except OSError as error:
        raise ValueError(f"output folder {parent} is not writable ({error.strerror})") from None
    try:
        (staging / "img1").mkdir()
        tables = []
        for frame in range(len(renderer)):
            image, rows = renderer.render_with_truth(frame)
            path = staging / "img1" / f"{frame + 1:06d}.jpg"
            if not cv2.imwrite(str(path), image, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]):
                raise OSError(f"cannot write {path}")
            tables.append(rows)
        gt = np.concatenate(tables) if tables else np.zeros((0, 10))
        write_mot(staging / "gt" / "gt.txt", gt)
        name = spec.name or f"synth-{spec.seed:06d}"
        write_seqinfo(staging / "seqinfo.ini", name, spec.fps, spec.frames, spec.size)
        if out.exists():
            shutil.rmtree(out)
        os.replace(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return f"{out} ({spec.frames} frames, {len(gt)} gt rows)"
