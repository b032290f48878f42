"""The figure of docs/simulator.md's texture filtering: the sdc-kart's centre camera on ``sdc-assen`` (240 route
samples, 12 m, after the start), the road from 5 to 25 m ahead enlarged twice, drawn by p3tinydisplay with each
texture sampled trilinearly (between two mipmap levels, as the renderer did until 2026-12-02) and bilinearly in the
nearest level (as it does now); and each filter's milliseconds per frame of the kart's three cameras over 30 poses
of the route (this machine, the figure's caption).

    python docs/figures/texture_filter.py docs/figures/texture-filter.jpg
"""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np

from kartpilot.core.vehicle import get_vehicle
from kartpilot.sim.render import Renderer
from kartpilot.sim.simulator import camera_poses_on_route
from kartpilot.sim.track import load_track


def _draw(minfilter: str) -> tuple[np.ndarray, float]:
    """The centre camera's image at the figure's pose, and milliseconds per frame of three cameras."""
    track = load_track("sdc-assen")
    vehicle = get_vehicle("sdc-kart")
    cams = {name: vehicle.camera(name) for name in ("center", "left", "right")}
    poses = [camera_poses_on_route(track, cams, sample) for sample in range(240, 840, 20)]
    with Renderer(track, cams) as renderer:
        sampler = getattr(renderer._core.SamplerState, minfilter)
        for texture in renderer.root.find_all_textures():
            texture.set_minfilter(sampler)
        first = renderer.render(poses[0])["center"]
        start = time.perf_counter()
        for pose in poses:
            renderer.render(pose)
        return first, 1000 * (time.perf_counter() - start) / len(poses)


def main(out: str) -> int:
    rows = []
    for minfilter, name in (("FT_linear_mipmap_linear", "trilinear (until 2026-12-02)"),
                            ("FT_linear_mipmap_nearest", "bilinear, nearest mipmap (now)")):
        image, ms = _draw(minfilter)
        crop = cv2.resize(image[180:300, 250:550], None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        cv2.putText(crop, f"{name}: {ms:.0f} ms/frame", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2,
                    cv2.LINE_AA)
        rows.append(crop)
        print(f"{name}: {ms:.1f} ms per frame of three cameras")
    cv2.imwrite(out, np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 90])
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
