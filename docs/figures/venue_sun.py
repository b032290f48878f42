"""The figure of docs/scenarios.md's sunny venue: a real frame of the SDC kart's centre camera at the venue (the
first of rdw-kart/lelystad-2024/frames, development data) beside the same camera rendered at the same place of
``lelystad`` (the lane's centre 65 m along, after the S-bend) under a clear morning sun, with roadside trees and
their hard shadows, through the real camera (``real_camera``: its exposure, noise, blur and MJPG).

    python docs/figures/venue_sun.py ../shared/data docs/figures/venue-real-and-sunny.jpg
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from kartpilot.sim.dynamics import VehicleState
from kartpilot.sim.render import RenderConfig
from kartpilot.sim.simulator import SimConfig, Simulator, real_camera


def main(data: str, out: str) -> int:
    real = cv2.imread(str(sorted((Path(data) / "rdw-kart" / "lelystad-2024" / "frames").glob("*.jpg"))[0]))
    sun = RenderConfig(sky="clear", time_of_day_h=9.0, sun_azimuth_deg=135.0, trees_spacing_m=10.0, shadows=True)
    config = SimConfig(track="lelystad", vehicle="sdc-kart", seed=2, cameras=("center",), render=sun,
                       effects=real_camera("sdc-kart"))
    with Simulator(config) as sim:
        route = sim.track.route
        i = route.index_at(65.0)
        x, y = route.xy_m[i]
        sim.state = VehicleState(x_m=float(x), y_m=float(y), yaw_rad=float(route.heading_rad[i]))
        frame = sim.read()
    assert frame is not None
    pair = np.hstack([real, frame.images["center"]])
    cv2.imwrite(out, cv2.resize(pair, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA),
                [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(*sys.argv[1:3]))
