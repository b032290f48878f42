"""A live drive end to end without a kart: a video file stands in for the centre camera, python-can's
virtual bus for the kart's CAN, a thread of simulated ECUs answers, and the person is the web page,
driven over HTTP. The person arms autonomy, holds, then closes the page: the kart must stop."""

import json
import socket
import threading
import time
import urllib.request
from dataclasses import replace

import can
import cv2

from kartpilot.actuation.can_bus import CanConfig, decode, load_dbc, open_bus
from kartpilot.calibration.rig import Rig
from kartpilot.core.camera import CaptureSettings
from kartpilot.core.types import ActuatorCommand
from kartpilot.record.recording import RecordingReader
from kartpilot.runtime.config import StackConfig
from kartpilot.runtime.live_drive import LiveDriveSetup, run_live_drive
from kartpilot.runtime.simulate import run_simulation
from kartpilot.sim.simulator import SimConfig
from kartpilot.sim.vehicle import get_vehicle


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _post(url: str, body: dict) -> None:
    request = urllib.request.Request(url, json.dumps(body).encode(), {"Content-Type": "application/json"})
    urllib.request.urlopen(request, timeout=1.0).read()


def test_a_live_drive_arms_from_the_web_page_and_stops_when_the_page_goes_away(tmp_path):
    from kartpilot.sim.can_ecu import SimEcus

    # the camera: a short rendered drive as a video file
    sim_config = SimConfig(track="sdc-assen", vehicle="sdc-kart", cameras=("center",), camera_rate_hz=15.0,
                           max_time_s=4.0, seed=1)
    run_simulation(sim_config, "centerline", record_dir=tmp_path / "teach")
    frames = RecordingReader(tmp_path / "teach").frames("center")
    first = cv2.imread(str(frames[0][1]))
    video = cv2.VideoWriter(str(tmp_path / "center.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 15.0,
                            (first.shape[1], first.shape[0]))
    for _, path in frames:
        video.write(cv2.imread(str(path)))
    video.release()
    camera = RecordingReader(tmp_path / "teach").cameras["center"]  # the simulator's calibration
    rig = Rig({"center": camera}, None, {"center": CaptureSettings(str(tmp_path / "center.mp4"), fps=15.0)})

    # the kart's ECUs on the virtual bus
    channel = f"live-test-{time.monotonic_ns()}"
    ecu_bus = open_bus(CanConfig(channel=channel))

    class Wheels:
        def __init__(self) -> None:
            self.commands: list[ActuatorCommand] = []

        def send(self, command: ActuatorCommand) -> None:
            self.commands.append(command)

    wheels = Wheels()
    ecus = SimEcus(ecu_bus, wheels, time.monotonic_ns)
    stop = threading.Event()

    def ecu_loop():
        while not stop.is_set():
            ecus.step()
            time.sleep(0.01)

    threading.Thread(target=ecu_loop, daemon=True).start()

    # the person: arms autonomy from the page, holds for a second, then closes the page
    port = _free_port()
    url = f"http://127.0.0.1:{port}/"

    def person():
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            try:
                _post(url + "input", {"hold": True})
                break
            except OSError:
                time.sleep(0.05)
        _post(url + "request", {"request": "autonomous"})
        for _ in range(10):
            _post(url + "input", {"hold": True})
            time.sleep(0.1)

    threading.Thread(target=person, daemon=True).start()
    stack = replace(StackConfig(), can=CanConfig(channel=channel, status_timeout_s=0.2))
    setup = LiveDriveSetup(rig, "lanes", get_vehicle("sdc-kart").wheelbase_m, web_port=port,
                           record_dir=tmp_path / "live", duration_s=3.0)
    try:
        summary = run_live_drive(setup, stack)
    finally:
        stop.set()
    states = [(t["state"], t["reason"]) for t in summary["transitions"]]
    print(summary["ended"], states, summary["cameras"]["skew_ms"], summary["stage_ms"].get("policy"))
    assert states[0] == ("autonomous", "autonomous requested by the operator (web)")
    assert states[-1] == ("fault", "operator link lost (web)")
    assert any(c.throttle > 0 for c in wheels.commands)  # it drove while the person held
    assert wheels.commands[-1].brake == 1.0  # and stopped
    reader = RecordingReader(tmp_path / "live")
    assert reader.closed and len(reader.frames("center")) > 20
    assert {row["state"] for row in reader.outputs("supervisor")} >= {"autonomous", "fault"}
    db = load_dbc()
    sent = [decode(db, can.Message(arbitration_id=i, data=d)) for _, direction, i, d in reader.can_frames()
            if direction == "tx"]
    assert sent[-2][0] == "BrakeCommand" and sent[-2][1]["Brake"] == 1.0
    assert any(direction == "rx" for _, direction, _, _ in reader.can_frames())
    assert json.loads((tmp_path / "live" / "result.json").read_text())["final_state"] == "fault"
    ecu_bus.shutdown()
