"""The kart's web page in a real browser: headless Chromium (Debian's package, which .ci/run installs)
driven by Selenium, against the page served by WebServer and a supervisor stepping in a thread."""

import json
import shutil
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

from kartpilot.core.types import ActuatorCommand
from kartpilot.runtime.supervisor import Supervisor
from kartpilot.runtime.webui import WebConfig, WebOperator, WebServer

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


def _wait(condition, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return False


def test_the_operator_side_without_a_browser():
    clock = {"ns": 0}
    web = WebOperator(WebConfig(link_timeout_s=0.5), clock=lambda: clock["ns"])
    assert not web(0).connected  # no page has connected yet
    web.on_input({"steer": 1.0, "throttle": 1.0, "hold": True})
    state = web(0)
    assert state.connected and state.hold and state.manual.steer_rad == pytest.approx(0.3)
    web.on_estop()
    assert web(0).estop
    web.on_request("rearm")
    assert not web(0).estop
    clock["ns"] = 600_000_000
    lost = web(0)
    assert not lost.connected and lost.manual.brake == 1.0 and not lost.hold
    with pytest.raises(ValueError, match="unknown request"):
        web.on_request("launch")


def test_requests_clicked_within_one_loop_step_all_reach_the_supervisor():
    # a re-arm and a manual clicked quickly used to share one slot: the manual overwrote the re-arm, and the
    # supervisor, still in fault, ignored it (seen in CI's browser test)
    web = WebOperator(WebConfig(link_timeout_s=0.5), clock=lambda: 0)
    supervisor = Supervisor()
    web.on_request("manual")
    supervisor.step(1, [], web(1), ActuatorCommand(1, 0.0, 0.5, 0.0))
    web.on_estop()
    supervisor.step(2, [], web(2), ActuatorCommand(2, 0.0, 0.5, 0.0))
    assert supervisor.state == "fault"
    web.on_request("rearm")
    web.on_request("manual")
    for k in (3, 4):
        supervisor.step(k, [], web(k), ActuatorCommand(k, 0.0, 0.5, 0.0))
    assert supervisor.state == "manual"
    assert web(5).request == ""


@pytest.fixture
def served():
    web = WebOperator(WebConfig(host="127.0.0.1", port=0, link_timeout_s=0.5))
    server = WebServer(web).start()
    supervisor = Supervisor()
    log: list[ActuatorCommand] = []
    stop = threading.Event()
    image = np.full((120, 160, 3), 80, np.uint8)

    def loop():  # the kart's control loop, at 20 Hz
        k = 0
        while not stop.is_set():
            k += 1
            operator = web(k)
            log.append(supervisor.step(k, [], operator, ActuatorCommand(k, 0.0, 0.5, 0.0)))
            web.publish(supervisor.state, supervisor.reason, image)
            time.sleep(0.05)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    yield web, server, supervisor, log
    stop.set()
    thread.join()
    server.close()


def test_the_page_serves_state_and_camera_over_http(served):
    web, server, _, _ = served
    assert _wait(lambda: web.jpeg() is not None)
    with urllib.request.urlopen(server.url + "camera.jpg") as reply:
        assert reply.headers["Content-Type"] == "image/jpeg" and reply.read(2) == b"\xff\xd8"
    with urllib.request.urlopen(server.url + "state") as reply:
        assert b'"state": "disarmed"' in reply.read()


@pytest.mark.skipif(not (CHROMIUM and CHROMEDRIVER), reason="Chromium and chromedriver not installed "
                    "(Debian: apt-get install chromium chromium-driver; .ci/run does)")
def test_arming_driving_and_the_emergency_stop_from_a_real_browser(served):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    web, server, supervisor, log = served
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"):
        options.add_argument(flag)
    browser = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        browser.get(server.pairing_url)  # the operator's browser pairs
        assert _wait(lambda: web.view()["link_age_s"] is not None)  # the page posts its heartbeat
        browser.find_element(By.ID, "manual").click()
        assert _wait(lambda: supervisor.state == "manual")
        body = browser.find_element(By.TAG_NAME, "body")
        webdriver.ActionChains(browser).key_down(Keys.ARROW_UP).key_down(Keys.ARROW_LEFT).perform()
        assert _wait(lambda: log[-1].throttle > 0 and log[-1].steer_rad > 0)  # the person drives
        webdriver.ActionChains(browser).key_up(Keys.ARROW_UP).key_up(Keys.ARROW_LEFT).perform()
        assert _wait(lambda: browser.find_element(By.ID, "state").text.lower() == "manual")
        browser.find_element(By.ID, "estop").click()
        assert _wait(lambda: supervisor.state == "fault")
        assert supervisor.reason == "emergency stop (web)" and log[-1].brake == 1.0
        assert _wait(lambda: browser.find_element(By.ID, "state").text.lower() == "fault")
        assert "emergency stop" in browser.find_element(By.ID, "reason").text
        browser.find_element(By.ID, "rearm").click()
        assert _wait(lambda: supervisor.state == "disarmed")
        browser.find_element(By.ID, "manual").click()
        assert _wait(lambda: supervisor.state == "manual")
        body.send_keys(Keys.ESCAPE)  # the keyboard's emergency stop
        assert _wait(lambda: supervisor.state == "fault")
        browser.find_element(By.ID, "rearm").click()
        browser.find_element(By.ID, "manual").click()
        assert _wait(lambda: supervisor.state == "manual")
        browser.get("about:blank")  # the phone leaves the page: the link is lost
        assert _wait(lambda: supervisor.state == "fault", timeout_s=3.0)
        assert "operator link lost (web)" in supervisor.reason
    finally:
        browser.quit()


def _post(url: str, body: dict, cookie: str | None = None) -> int:
    request = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json",
                                              **({"Cookie": cookie} if cookie else {})})
    try:
        with urllib.request.urlopen(request) as reply:
            return reply.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_only_the_paired_operator_drives_and_anyone_may_stop(served):
    """The issue's attack: a second browser on the hotspot cleared the operator's emergency stop, asked for
    autonomy and drove. Now it is refused; the pairing code works once; a NaN steer is refused too."""
    web, server, supervisor, log = served
    with urllib.request.urlopen(server.pairing_url) as reply:  # the operator's phone
        cookie = reply.headers["Set-Cookie"].split(";")[0]
    with urllib.request.urlopen(server.pairing_url) as reply:  # the code is spent
        assert reply.headers["Set-Cookie"] is None
    assert _post(server.url + "input", {"steer": 0.0}, cookie) == 200
    assert _post(server.url + "request", {"request": "manual"}, cookie) == 200
    assert _wait(lambda: supervisor.state == "manual")
    # a bystander may stop the kart
    assert _post(server.url + "estop", {}) == 200
    assert _wait(lambda: supervisor.state == "fault")
    # but not re-arm it, ask for autonomy or drive: refused and counted
    for path, body in (("request", {"request": "rearm"}), ("request", {"request": "autonomous"}),
                       ("input", {"steer": 1.0, "throttle": 1.0})):
        assert _post(server.url + path, body) == 403
        assert _post(server.url + path, body, "kartpilot_session=guessed") == 403
    assert web.refused == 6
    time.sleep(0.2)
    assert supervisor.state == "fault" and log[-1].brake == 1.0
    # a NaN control from the operator is refused, not used
    assert _post(server.url + "input", {"steer": float("nan")}, cookie) == 400
    with urllib.request.urlopen(urllib.request.Request(server.url + "state", headers={"Cookie": cookie})) as reply:
        assert json.loads(reply.read())["operator"] is True
    with urllib.request.urlopen(server.url + "state") as reply:
        assert json.loads(reply.read())["operator"] is False
