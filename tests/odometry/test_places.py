"""Place recognition: retrieval and the geometric check on synthetic places, the file format, bad input, and
the simulator's laps (Recall@1 and Recall@5 against the truth)."""

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
from tests.conftest import KART, GreyFrames, road_texture, road_view

from kartpilot.core.camera import PinholeCamera
from kartpilot.core.errors import DataError, PerceptionError
from kartpilot.odometry.places import FORMAT_VERSION, PlacesConfig, build_places, load_places
from kartpilot.perception.vlad import VladConfig

CAMERA = PinholeCamera(300.0, 300.0, 159.5, 119.5, 320, 240)  # level: the ground starts below row 120
CONFIG = PlacesConfig(vlad=VladConfig(words=16))


def _place_image(k: int) -> np.ndarray:
    """A distinct scene per place: rectangles and blobs of random grey levels on noise."""
    rng = np.random.default_rng(1000 + k)
    image = rng.normal(128, 20, (240, 320)).astype(np.float32)
    for _ in range(40):
        x, y = int(rng.integers(0, 300)), int(rng.integers(0, 150))
        w, h = (int(v) for v in rng.integers(8, 50, 2))
        cv2.rectangle(image, (x, y), (x + w, y + h), float(rng.uniform(0, 255)), -1)
    return np.clip(cv2.GaussianBlur(image, (3, 3), 0), 0, 255).astype(np.uint8)


def _pose(x_m: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x_m
    return pose


def _query(k: int, rng: np.random.Generator) -> np.ndarray:
    """Place ``k`` seen again: shifted a few pixels, with new sensor noise."""
    shift = np.float32([[1, 0, rng.uniform(-4, 4)], [0, 1, rng.uniform(-2, 2)]])
    moved = cv2.warpAffine(_place_image(k), shift, (320, 240), borderMode=cv2.BORDER_REFLECT)
    return np.clip(moved + rng.normal(0, 3, moved.shape), 0, 255).astype(np.uint8)


def _assert_same_fix(a, b) -> None:
    assert np.array_equal(a.pose_world_cam, b.pose_world_cam)
    assert replace(a, pose_world_cam=None) == replace(b, pose_world_cam=None)


@pytest.fixture(scope="module")
def database():
    return build_places(((k * 10**8, _place_image(k), _pose(k * 1.5)) for k in range(20)), CAMERA, "center",
                        CONFIG, {"positions": "test"})


def test_each_place_is_found_again_and_its_position_given(database):
    rng = np.random.default_rng(5)
    for k in range(20):
        fix = database.locate(_query(k, rng), stamp_ns=k)
        assert fix.accepted, fix.reason
        assert fix.place == k
        assert fix.inliers >= CONFIG.min_inliers
        assert abs(fix.position_m[0] - 1.5 * k) < 1.0
        assert fix.sigma_m >= CONFIG.spacing_m / 2


def test_the_geometric_check_rejects_a_place_that_was_never_seen(database):
    stranger = _place_image(999)
    assert not database.locate(stranger).accepted
    unchecked = replace(database, config=replace(CONFIG, verify=False))
    assert unchecked.locate(stranger).accepted  # retrieval alone always answers something


def test_a_black_frame_gives_no_place_and_says_why(database):
    fix = database.locate(np.zeros((240, 320), np.uint8))
    assert not fix.accepted and "features" in fix.reason


def test_an_image_of_another_size_is_an_error_naming_both(database):
    with pytest.raises(PerceptionError, match=r"640x480.*320x240"):
        database.locate(np.zeros((480, 640), np.uint8))


def test_the_file_loads_back_identically(database, tmp_path):
    path = database.save(tmp_path / "places.db")
    loaded = load_places(path)
    assert loaded.config == database.config and loaded.camera == database.camera and loaded.info == database.info
    for name in ("centres", "vectors", "poses_world_cam", "stamps_ns"):
        assert np.array_equal(getattr(loaded, name), getattr(database, name)), name
    assert all(np.array_equal(a, b) for a, b in zip(loaded.descriptors, database.descriptors, strict=True))
    query = _query(7, np.random.default_rng(3))
    _assert_same_fix(loaded.locate(query), database.locate(query))


def test_pca_databases_load_back_too(tmp_path):
    config = replace(CONFIG, vlad=replace(CONFIG.vlad, pca_dims=8))
    database = build_places(((k, _place_image(k), _pose(k)) for k in range(12)), CAMERA, "center", config)
    assert database.vectors.shape == (12, 8)
    loaded = load_places(database.save(tmp_path / "p.db"))
    query = _query(4, np.random.default_rng(4))
    _assert_same_fix(loaded.locate(query), database.locate(query))
    assert database.locate(query).place == 4


def test_damaged_or_foreign_files_are_clear_errors(database, tmp_path):
    with pytest.raises(DataError, match="no place database"):
        load_places(tmp_path / "missing.db")
    garbage = tmp_path / "garbage.db"
    garbage.write_bytes(b"not a database")
    with pytest.raises(DataError, match="not a kartpilot place database"):
        load_places(garbage)
    foreign = tmp_path / "foreign.db"
    with foreign.open("wb") as f:
        np.savez(f, header=np.array('{"format": "something else"}'))
    with pytest.raises(DataError, match="format 'something else'"):
        load_places(foreign)
    path = database.save(tmp_path / "places.db")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["header"] = np.array(str(arrays["header"]).replace(f'"version": {FORMAT_VERSION}', '"version": 99'))
    newer = tmp_path / "newer.db"
    with newer.open("wb") as f:
        np.savez(f, **arrays)
    with pytest.raises(DataError, match="version 99"):
        load_places(newer)
    del arrays["vectors"]
    arrays["header"] = np.array(str(arrays["header"]).replace('"version": 99', f'"version": {FORMAT_VERSION}'))
    with (tmp_path / "cut.db").open("wb") as f:
        np.savez(f, **arrays)
    with pytest.raises(DataError, match="damaged"):
        load_places(tmp_path / "cut.db")


def test_a_drive_without_texture_builds_no_database():
    black = ((k, np.zeros((240, 320), np.uint8), _pose(k)) for k in range(10))
    with pytest.raises(DataError, match="usable images"):
        build_places(black, CAMERA, "center", CONFIG)


def _sim_drive(seed: int, speed_mps: float, time_of_day_h: float = 13.0, offset_m: float = 0.0,
               seconds: float = 24.0, rate_hz: float = 10.0) -> list:
    """A drive's centre-camera frames, grey, with their true poses (drawn as they come, not recorded)."""
    from kartpilot.runtime.simulate import run_simulation
    from kartpilot.sim.drivers import CenterlineDriverConfig
    from kartpilot.sim.render import RenderConfig
    from kartpilot.sim.simulator import SimConfig, perfect_camera

    config = SimConfig(track="sdc-assen", vehicle="sdc-kart-steep", cameras=("center",), camera_rate_hz=rate_hz,
                       max_time_s=seconds, seed=seed, effects=perfect_camera(),
                       render=RenderConfig(time_of_day_h=time_of_day_h, scenery_spacing_m=15.0))
    frames = GreyFrames("center")
    run = run_simulation(config, "centerline", driver_config=CenterlineDriverConfig(speed_mps=speed_mps,
                                                                                    edge_offset_m=offset_m),
                         taps=(frames,))
    return list(frames.posed(run.ground_truth))


@pytest.mark.slow
def test_simulated_laps_recall_at_1_within_2_m():
    """The database from one drive of the SDC kart's centre camera on sdc-assen (with roadside buildings; the camera
    mounted steep, 12 degrees down: sdc-kart-steep), queried by a second drive on the same line and light (at another
    speed, so the images fall between the database's), and by one on a line 0.4 m to the left at dusk, a query
    every 0.2 s (the first query drive's camera runs at 5 Hz: the frames between were never asked; the frames are taken
    as the drives draw them, not recorded and read back). The acceptance
    asks Recall@1 >= 90 % on the same line and light; the other drive is reported, with a bound that only catches a
    broken pipeline. The fixes registered on the road are good across the track and in heading on both.

    Through the perfect camera, as the bounds were set: through the real one (2026-11-28) the dusk drive's Recall@1
    was 0.81 and its fixes' p90 errors 0.17 m across and 2.5 deg, over these bounds (issue 53's real camera)."""
    from kartpilot.core.vehicle import get_vehicle
    from kartpilot.eval.places import evaluate_places

    database = build_places(_sim_drive(seed=1, speed_mps=5.0), get_vehicle("sdc-kart-steep").camera("center"),
                            "center")
    results = {}
    same_drive = _sim_drive(2, 4.5, rate_hz=5.0)
    other_drive = _sim_drive(3, 4.5, 18.5, 0.4)
    for name, queries in (("same line and light", same_drive[3:]), ("0.4 m left, dusk", other_drive[5::2])):
        results[name] = evaluate_places(database, queries, radius_m=2.0)
        print(f"\n{name}, {len(database)} places\n{results[name].table()}")
    same, other = results["same line and light"], results["0.4 m left, dusk"]
    assert same.recall_at_1 >= 0.9 and same.checked_recall_at_1 >= 0.9
    assert same.median_error_m < 1.0
    assert other.checked_recall_at_1 >= 0.75 and other.recall_at_5 >= 0.85
    # the road's top view puts the kart across the track to centimetres, on the other line and light too
    assert same.registered >= 0.9 and other.registered >= 0.7
    assert max(same.p90_cross_track_error_m, other.p90_cross_track_error_m) < 0.1
    assert max(same.p90_heading_error_deg, other.p90_heading_error_deg) < 1.0


def test_a_mounted_camera_s_fix_takes_the_offset_across_the_track_and_the_heading_from_the_road(tmp_path):
    texture = road_texture(8)
    mount = KART.pose_body_cam_array

    def body(x_m: float, y_m: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
        c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
        pose = np.eye(4)
        pose[:2, :2], pose[:2, 3] = [[c, -s], [s, c]], (x_m, y_m)
        return pose

    database = build_places(((k, road_view(texture, body(k), 0.01), body(k) @ mount) for k in range(12)), KART,
                            "center", replace(CONFIG, min_inliers=12))
    assert database.road_views is not None and len(database.road_views) == len(database)
    query = road_view(texture, body(5.3, 0.35, 2.0), 0.01)
    fix = database.locate(query)
    assert fix.accepted and fix.registered, fix.reason
    found = fix.pose_world_cam @ np.linalg.inv(mount)
    yaw_deg = math.degrees(math.atan2(found[1, 0], found[0, 0]))
    print(f"fix: x {found[0, 3]:.3f} y {found[1, 3]:.3f} m, yaw {yaw_deg:.2f} deg (true 5.3, 0.35, 2.0)")
    assert found[1, 3] == pytest.approx(0.35, abs=0.03) and fix.cross_track_sigma_m < 0.1
    assert yaw_deg == pytest.approx(2.0, abs=0.3)
    assert found[0, 3] == pytest.approx(5.3, abs=2 * fix.sigma_m)
    _assert_same_fix(load_places(database.save(tmp_path / "road.db")).locate(query), fix)


def test_a_place_seen_again_from_where_it_was_taken_keeps_its_heading(database):
    """No parallax between the query and the place (a kart at rest on the spot where the place was taken): the
    essential matrix's rotation is then arbitrary (54 degrees on a simulated start line), so the check takes
    the rotation alone that turns the rays onto each other."""
    rng = np.random.default_rng(11)
    for k in (0, 7, 13):
        image = np.clip(_place_image(k) + rng.normal(0, 2, (240, 320)), 0, 255).astype(np.uint8)
        fix = database.locate(image)
        assert fix.accepted and fix.place == k
        turned = math.degrees(math.acos(np.clip((np.trace(fix.pose_world_cam[:3, :3]) - 1) / 2, -1, 1)))
        print(f"place {k}: heading off by {turned:.3f} deg")
        assert turned < 0.2
