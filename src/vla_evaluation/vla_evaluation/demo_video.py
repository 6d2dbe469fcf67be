"""The demo's video and image strip: camera frames with the end-effector path drawn (OpenCV).

The path is the TCP (forward kinematics of the measured joint states) projected with the simulated
webcam's own camera model (`PandaSim.project`), so it lines up with what the camera saw.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

PATH_COLOR = (255, 200, 0)  # RGB
START_COLOR = (0, 160, 255)


def _projector(size: tuple[int, int]):
    from vla_sim.sim import PandaSim  # MuJoCo, an optional heavy dependency: only to draw the path

    sim = PandaSim(camera_width=size[0], camera_height=size[1], render=False)
    return sim.project


def annotate(frame: np.ndarray, path_px: np.ndarray, lines: Sequence[str], scale: float) -> np.ndarray:
    """A copy of an RGB frame with the path so far and caption lines drawn."""
    img = np.ascontiguousarray(frame.copy())
    if len(path_px) >= 2:
        pts = np.round(path_px * scale).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], False, PATH_COLOR, 2, cv2.LINE_AA)
        cv2.circle(img, tuple(int(v) for v in pts[0, 0]), 4, START_COLOR, -1, cv2.LINE_AA)
    y = 16
    for text in lines:
        cv2.putText(img, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
        y += 16
    return img


def write_video_and_strip(
    records, out_dir: Path, size: tuple[int, int] = (640, 480), fps: float = 8.0
) -> dict[str, Path]:
    """demo.mp4 (every kept frame of every episode) and strip.png (each episode's last frame)."""
    out_dir = Path(out_dir)
    project = _projector(size)
    video_path, strip_path = out_dir / "demo.mp4", out_dir / "strip.png"
    writer = None
    tiles = []
    for rec in records:
        r = rec.result
        if not rec.frames:
            continue
        path_t = np.asarray(rec.tcp_times)
        path_px = project(rec.tcp_path) if len(rec.tcp_path) else np.zeros((0, 2))
        h, w = rec.frames[0][1].shape[:2]
        scale = w / float(size[0])
        verdict = "success" if r.success else "failed"
        for t, frame in rec.frames:
            shown = path_px[path_t <= t]
            lines = [f"{r.task}  t = {t:4.1f} s", f"model: {r.model}  latched: {r.detected_class or '-'}"]
            img = annotate(frame, shown, lines, scale)
            if writer is None:
                writer = cv2.VideoWriter(str(video_path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
            writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        last = rec.frames[-1][1]
        caption = [r.task, f"{verdict}, error {r.final_state_error:.2f} rad"]
        tiles.append(annotate(last, path_px, caption, scale))
    files: dict[str, Path] = {}
    if writer is not None:
        writer.release()
        files["video"] = video_path
    if tiles:
        cols = min(4, len(tiles))
        rows = int(np.ceil(len(tiles) / cols))
        th, tw = tiles[0].shape[:2]
        sheet = np.full((rows * th, cols * tw, 3), 255, np.uint8)
        for i, tile in enumerate(tiles):
            rr, cc = divmod(i, cols)
            sheet[rr * th : (rr + 1) * th, cc * tw : (cc + 1) * tw] = tile[:th, :tw]
        cv2.imwrite(str(strip_path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
        files["strip"] = strip_path
    return files
