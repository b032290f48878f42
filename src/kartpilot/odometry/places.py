"""Place recognition: a database of a reference drive's images, tagged with where they were taken.

Built once from a reference drive (positions from stereo VO, a survey, or the simulator's
truth), it answers "where was the image most like this one taken?" for a new image:

1. The image's VLAD vector (:mod:`kartpilot.perception.vlad`) from local features outside
   the near road. The ground closer than ``ignore_ground_heights`` camera heights is masked
   out: asphalt looks the same everywhere (so it matches everywhere) and it is where a
   slightly different line changes the image most. Above it, kerbs, boards, buildings and
   trees tell places apart.
2. The nearest database vectors, searched with a BallTree (scikit-learn).
3. Optionally, a geometric check: the query's features are matched to each of the best
   ``verify_candidates`` places (ratio test) and the essential matrix is fitted in RANSAC.
   The candidates are ranked by their inliers, and the best one must reach ``min_inliers``,
   so a wrong place that merely looks alike is rejected. The check also gives the rotation
   between the two views, hence the query's heading.
4. The position: the inlier-weighted (or, unchecked, similarity-weighted) mean of the top
   places that lie within ``consistent_m`` of the best, with a standard deviation from their
   spread and the database's spacing.
5. Across the track and in heading, a camera with a mount does much better: the database keeps a
   top view of the road ahead of each place (:mod:`kartpilot.perception.birdseye`), and the query's
   top view is registered on the best place's. That gives the query's offset across the track and its
   heading relative to the place to a few centimetres and a fraction of a degree, where the
   retrieval alone only says "near this place" (the reference drive's line).
6. Along the track one registration cannot be trusted: beyond its reach (about a metre), and on a
   straight, streaked road, it still finds a peak, at the wrong offset. So the query is registered on
   the places before and after the best one too; where two of them put it at the same point, the fix
   takes that position along the track with ``road_along_sigma_m``. Where none agree, the fix keeps the
   retrieval's position with the retrieval's spread as its uncertainty: it says it is ambiguous.

The database is written as one versioned NumPy archive (no pickles) and loads back
identically: the same arrays, the same BallTree, the same answers.
"""

from __future__ import annotations

import itertools
import json
import math
import time
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from kartpilot.calibration.lens import LensRemap, undistortion
from kartpilot.core.camera import PinholeCamera, camera_from_dict, camera_to_dict
from kartpilot.core.config import config_to_dict, merge_config
from kartpilot.core.errors import ConfigError, DataError, KartpilotError, PerceptionError
from kartpilot.core.files import parse_json, write_atomic
from kartpilot.core.geometry import Array, planar_pose
from kartpilot.core.types import Image
from kartpilot.odometry.mono_vo import beyond_ground_mask, has_mount, rotation_only
from kartpilot.perception.birdseye import (
    BirdseyeConfig,
    RoadRegistration,
    birdseye,
    planar_transform,
    register_birdseye,
    road_grids,
)
from kartpilot.perception.features import Features, create_detector, detect_features
from kartpilot.perception.vlad import Pca, VladConfig, fit_pca, project_pca, train_vocabulary, vlad_vector

__all__ = ["FORMAT", "FORMAT_VERSION", "PlaceDatabase", "PlaceFix", "PlacesConfig", "build_places",
           "load_places"]

FORMAT = "kartpilot-places"
FORMAT_VERSION = 2

F32 = NDArray[np.float32]
NO_PARALLAX_SHARE = 0.9  # a rotation alone explaining this share of the essential matrix's inliers: no parallax


@dataclass(frozen=True)
class PlacesConfig:
    """Attributes:
        vlad: the image descriptor (features, vocabulary, normalisation, PCA).
        spacing_m: keep a reference image every this many metres driven.
        ignore_ground_heights: features on the ground nearer than this many camera heights are not used
            (0: use the whole image).
        keep_features: the strongest features of each place kept for the geometric check.
        top_k: the places retrieved per query.
        verify: run the geometric check.
        verify_candidates: how many of the nearest places the check ranks.
        min_inliers: fewest essential-matrix inliers for a checked place to count.
        ratio: Lowe's ratio test in the check's matching.
        ransac_px: the essential matrix's RANSAC threshold.
        consistent_m: top places within this of the best one are averaged into the position.
        check_heading_sigma_rad: the heading's standard deviation from the check's rotation alone.
        register: keep a top view of the road per place and register queries on it (a camera with a mount).
        road: the top view and its registration.
        road_cross_track_sigma_m, road_heading_sigma_rad: a registered fix's standard deviations across the
            track and in heading (measured in the simulator: 99 % of the errors within 5 cm and 1.4 degrees).
        road_along_agree_m, road_along_sigma_m: along the track, the query is registered on the places before
            and after the best one in the drive too. Where two of the three put it within ``road_along_agree_m``
            of each other, the fix's position along the track is theirs, with ``road_along_sigma_m``. Where none
            agree (a streaked or repeating road, typically on a straight, matches at the wrong offset), the
            position along the track stays the retrieval's, with its wider ``sigma_m``: the fix says it is
            ambiguous instead of claiming the registration's precision.
    """

    vlad: VladConfig = field(default_factory=VladConfig)
    spacing_m: float = 1.0
    ignore_ground_heights: float = 8.0
    keep_features: int = 300
    top_k: int = 5
    verify: bool = True
    verify_candidates: int = 10
    min_inliers: int = 20
    ratio: float = 0.8
    ransac_px: float = 1.0
    consistent_m: float = 3.0
    check_heading_sigma_rad: float = 0.08
    register: bool = True
    road: BirdseyeConfig = field(default_factory=BirdseyeConfig)
    road_cross_track_sigma_m: float = 0.05
    road_heading_sigma_rad: float = 0.01
    road_along_agree_m: float = 0.2
    road_along_sigma_m: float = 0.1

    def __post_init__(self) -> None:
        if self.spacing_m <= 0:
            raise ConfigError(f"places.spacing_m must be positive, got {self.spacing_m}")
        if self.top_k < 1 or self.verify_candidates < 1:
            raise ConfigError("places.top_k and places.verify_candidates must be at least 1")
        if self.ignore_ground_heights < 0 or self.min_inliers < 5:
            raise ConfigError("places.ignore_ground_heights must not be negative and min_inliers at least 5")
        if not min(self.check_heading_sigma_rad, self.road_cross_track_sigma_m, self.road_heading_sigma_rad,
                   self.road_along_agree_m, self.road_along_sigma_m) > 0:  # NaN too
            raise ConfigError("places.check_heading_sigma_rad, road_cross_track_sigma_m, road_heading_sigma_rad, "
                              "road_along_agree_m and road_along_sigma_m must be positive")


@dataclass(frozen=True)
class PlaceFix:
    """Where an image was taken, by place recognition.

    Attributes:
        stamp_ns: the query image's time.
        accepted: False when the image gave no place (no features, or the check rejected every candidate).
        reason: why not, when not accepted.
        pose_world_cam: the camera's pose in the database's frame: the combined position, and the best
            place's orientation turned by the checked relative rotation (when the check ran).
        sigma_m: standard deviation of the position.
        place: the best place's index; ``candidates`` the retrieved ones, best first by VLAD distance;
            ``vlad_distances`` their distances.
        inliers: the best place's essential-matrix inliers (0 without the check).
        registered: the road's top view was registered on the best place's: the position across the track
            and the heading are the registration's, with ``cross_track_sigma_m`` and ``heading_sigma_rad``
            (across the track an unregistered fix has ``sigma_m``, and its heading ``heading_sigma_rad``
            from the check, or inf).
    """

    stamp_ns: int
    accepted: bool
    reason: str
    pose_world_cam: Array
    sigma_m: float
    place: int
    candidates: tuple[int, ...]
    vlad_distances: tuple[float, ...]
    inliers: int
    registered: bool = False
    cross_track_sigma_m: float = math.inf
    heading_sigma_rad: float = math.inf

    @property
    def position_m(self) -> Array:
        return self.pose_world_cam[:3, 3]


class _Describer:
    """The detector and mask for one camera: image -> features. Only the mask's bounding box is searched
    (the near road is most of the image's lower part)."""

    def __init__(self, camera: PinholeCamera, config: PlacesConfig) -> None:
        self.config = config
        self.detector, self.binary = create_detector(config.vlad.features)
        self.mask = beyond_ground_mask(camera, config.ignore_ground_heights)
        self.size_wh = camera.size_wh
        rows, cols = np.flatnonzero(self.mask.any(1)), np.flatnonzero(self.mask.any(0))
        if len(rows) < 16 or len(cols) < 16:
            raise ConfigError("places.ignore_ground_heights leaves (almost) nothing of the image to describe")
        self.box = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)

    def features(self, image: Image) -> Features:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        if gray.shape[1::-1] != self.size_wh:
            raise PerceptionError(f"a {gray.shape[1]}x{gray.shape[0]} image does not fit the place database's "
                                  f"{self.size_wh[0]}x{self.size_wh[1]} camera")
        r0, r1, c0, c1 = self.box
        found = detect_features(np.ascontiguousarray(gray[r0:r1, c0:c1]), self.detector, self.binary,
                                self.config.vlad.features)
        if len(found) == 0:
            return found
        points = found.points_px + np.array([c0, r0], np.float32)
        pixel = np.round(points).astype(int)
        keep = self.mask[np.clip(pixel[:, 1], 0, self.size_wh[1] - 1), np.clip(pixel[:, 0], 0, self.size_wh[0] - 1)]
        index = np.flatnonzero(keep > 0)
        # SIFT's descriptors are whole numbers in 0..255 (OpenCV saturates them to bytes): kept as bytes
        descriptors = found.descriptors[index] if self.binary else found.descriptors[index].astype(np.uint8)
        return Features(points[index], descriptors, found.responses[index], self.binary)


@dataclass
class PlaceDatabase:
    """The reference drive's places. Built by :func:`build_places`, written by :meth:`save`, read by
    :func:`load_places`; :meth:`locate` answers queries."""

    camera_name: str
    camera: PinholeCamera
    config: PlacesConfig
    centres: F32
    pca: Pca | None
    vectors: F32
    poses_world_cam: Array
    stamps_ns: NDArray[np.int64]
    keypoints: list[F32]
    descriptors: list[NDArray[Any]]
    info: dict[str, Any]
    road_views: NDArray[np.uint8] | None = None  # (N, rows, columns): each place's top view of the road

    def __post_init__(self) -> None:
        count = len(self.vectors)
        if count == 0:
            raise DataError("a place database needs at least one place")
        if not (len(self.poses_world_cam) == len(self.stamps_ns) == len(self.keypoints) == len(self.descriptors)
                == count):
            raise DataError("a place database's arrays disagree in length")
        self._grids = road_grids(self.camera, self.config.road) if self.road_views is not None else None
        if self.road_views is not None and self._grids is not None and (  # (mypy: _grids is set with the views)
                len(self.road_views) != count or self.road_views.shape[1:] != self._grids[0].shape):
            raise DataError(f"a place database's road views {self.road_views.shape} do not fit its {count} places "
                            f"and road patch {self._grids[0].shape}")
        from sklearn.neighbors import BallTree  # here, not at import: scikit-learn takes most of a second to load

        self.tree = BallTree(self.vectors)
        self._describer = _Describer(self.camera, self.config)
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING if self._describer.binary else cv2.NORM_L2)
        self.timing_ms: dict[str, float] = {"features": 0.0, "retrieve": 0.0, "check": 0.0, "register": 0.0}
        self.queries = 0

    def __len__(self) -> int:
        return len(self.vectors)

    @property
    def positions_m(self) -> Array:
        return self.poses_world_cam[:, :3, 3]

    def vector(self, features: Features) -> F32:
        raw = vlad_vector(features.descriptors, self.centres, self.config.vlad.power_alpha)
        return project_pca(raw, self.pca) if self.pca is not None else raw

    def retrieve(self, vector: F32, k: int) -> tuple[NDArray[np.intp], Array]:
        """The ``k`` nearest places to a VLAD vector and their distances, nearest first."""
        distances, indices = self.tree.query(vector[None], k=min(k, len(self)))
        return indices[0], distances[0]

    def lens_for(self, camera: PinholeCamera, name: str) -> LensRemap | None:
        """How to take ``camera``'s lens out of a query image, as the database's images were built; a camera with
        other coefficients than those is refused (its images would not match the database's geometry)."""
        built = tuple(self.info.get("undistorted", ()))
        if built != tuple(camera.distortion):
            raise ConfigError(f"the place database was built from a camera with lens coefficients {list(built)}, the "
                              f"{name!r} camera has {list(camera.distortion)}: build it from this camera's drive")
        return undistortion(camera)

    def locate(self, image: Image, stamp_ns: int = 0) -> PlaceFix:
        """Where ``image`` was taken (see the module's description)."""
        cfg = self.config
        t0 = time.perf_counter()
        self.queries += 1
        features = self._describer.features(image)
        t1 = time.perf_counter()
        self.timing_ms["features"] += (t1 - t0) * 1e3
        nothing = np.full((4, 4), np.nan)
        if len(features) < 8:
            return PlaceFix(stamp_ns, False, f"{len(features)} features outside the near road", nothing, math.inf,
                            -1, (), (), 0)
        indices, distances = self.retrieve(self.vector(features), max(cfg.top_k, cfg.verify_candidates
                                                                       if cfg.verify else 0))
        candidates, vlad = tuple(int(i) for i in indices), tuple(float(d) for d in distances)
        t2 = time.perf_counter()
        self.timing_ms["retrieve"] += (t2 - t1) * 1e3
        if not cfg.verify:
            weights = 1.0 / np.maximum(distances[:cfg.top_k], 1e-6) ** 2
            return self._fix(image, stamp_ns, indices[:cfg.top_k], weights, None, candidates, vlad, 0)
        checked = [self._check(features, int(i)) for i in indices]
        self.timing_ms["check"] += (time.perf_counter() - t2) * 1e3
        inliers = np.array([c[0] for c in checked])
        order = np.argsort(-inliers, kind="stable")
        best = int(order[0])
        if inliers[best] < cfg.min_inliers:
            return PlaceFix(stamp_ns, False, f"the geometric check failed: at most {int(inliers[best])} "
                            f"inliers, {cfg.min_inliers} needed", nothing, math.inf, int(indices[best]),
                            candidates, vlad, int(inliers[best]))
        top = order[:cfg.top_k]
        top = top[inliers[top] >= cfg.min_inliers]
        return self._fix(image, stamp_ns, indices[top], inliers[top].astype(float), checked[best][1], candidates,
                         vlad, int(inliers[best]))

    def _matchable(self, descriptors: NDArray[Any]) -> NDArray[Any]:
        return descriptors if self._describer.binary else descriptors.astype(np.float32)

    def _check(self, features: Features, place: int) -> tuple[int, Array | None]:
        """Essential-matrix inliers between the query and a place, and the rotation from the query's camera
        frame to the place's (None when there is no model).

        The inliers are RANSAC's, before recoverPose's chirality test: two views a metre apart of
        things far away are almost a pure rotation, where that test keeps an arbitrary share of them. Where
        the inliers show no parallax at all (the kart at rest where a place was taken), the rotation is the one
        that turns the rays onto each other (:func:`rotation_only`): the essential matrix's is then arbitrary."""
        descriptors = self.descriptors[place]
        if len(descriptors) < 8:
            return 0, None
        pairs = self._matcher.knnMatch(*(self._matchable(d) for d in (features.descriptors, descriptors)), k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < self.config.ratio * p[1].distance]
        if len(good) < 8:
            return len(good) // 2, None  # ranks a near miss above nothing, never reaches min_inliers
        query = features.points_px[[m.queryIdx for m in good]]
        place_points = self.keypoints[place][[m.trainIdx for m in good]]
        k = self.camera.matrix
        # OpenCV's USAC (fixed seed): the same inliers as plain RANSAC here, eight times faster (0.7 ms)
        essential, mask = cv2.findEssentialMat(query, place_points, k, cv2.USAC_FAST, 0.999, self.config.ransac_px)
        if essential is None or essential.shape != (3, 3):
            return 0, None
        inliers = mask.ravel() > 0
        still, explained = rotation_only(query[inliers], place_points[inliers], k, self.config.ransac_px)
        if explained.mean() >= NO_PARALLAX_SHARE:
            return int(inliers.sum()), still  # no parallax: the essential matrix's rotation is arbitrary
        _, rotation, _, _ = cv2.recoverPose(essential, query, place_points, k, mask=mask.copy())
        return int(inliers.sum()), rotation

    def register(self, image: Image, place: int, yaw_guess_rad: float = 0.0) -> RoadRegistration | None:
        """The query body's planar pose relative to a place's, from the road's top views (None without them,
        or when the registration finds none)."""
        if self.road_views is None or self._grids is None:
            return None
        start = time.perf_counter()
        reference, query = self._grids
        found = register_birdseye(self.road_views[place], birdseye(image, query), reference, query, yaw_guess_rad,
                                  self.config.road)
        self.timing_ms["register"] += (time.perf_counter() - start) * 1e3
        return found

    def _fix(self, image: Image, stamp_ns: int, places: NDArray[np.intp], weights: Array, rotation: Array | None,
             candidates: tuple[int, ...], vlad: tuple[float, ...], inliers: int) -> PlaceFix:
        cfg = self.config
        best = int(places[0])
        positions = self.positions_m[places]
        near = np.linalg.norm(positions - positions[0], axis=1) <= self.config.consistent_m
        w = weights[near] / weights[near].sum()
        mean = (w[:, None] * positions[near]).sum(0)
        spread = float(np.sqrt((w * ((positions[near] - mean) ** 2).sum(1)).sum()))
        pose = self.poses_world_cam[best].copy()
        if rotation is not None:  # x_place = R x_query: the query camera's orientation is R_world_place @ R
            pose[:3, :3] = pose[:3, :3] @ rotation
        pose[:3, 3] = mean
        # the top places' spread itself, and half the spacing of the places: not the weighted mean's standard
        # error, since neighbouring places look alike together (on a straight, all of them along it)
        sigma = math.hypot(spread, cfg.spacing_m / 2)
        heading_sigma = cfg.check_heading_sigma_rad if rotation is not None else math.inf
        body_cam = self.camera.pose_body_cam_array
        turn = body_cam[:3, :3] @ rotation @ body_cam[:3, :3].T if rotation is not None else np.eye(3)
        road = self.register(image, best, math.atan2(turn[1, 0], turn[0, 0]))
        if road is None:
            return PlaceFix(stamp_ns, True, "", pose, sigma, best, candidates, vlad, inliers, False, sigma,
                            heading_sigma)
        # across the track and in heading the registration's pose; along it the two nearest places' agreed
        # registrations, or else the retrieval's: the query camera lies as far along the place's heading as the
        # places' mean
        world_body = self.poses_world_cam[best] @ np.linalg.inv(body_cam)
        along = float((np.linalg.inv(world_body) @ np.r_[mean, 1.0])[0])
        relative = np.eye(4)
        relative[:2, :2] = planar_transform(0.0, 0.0, road.yaw_rad)[:2, :2]
        # the camera's lever arm, turned, along the place's heading
        camera_along = float(relative[0, :2] @ body_cam[:2, 3])
        body_along = self._along_by_road(image, best, road)
        if body_along is None:
            body_along = along - camera_along
        else:
            sigma = cfg.road_along_sigma_m
        relative[:2, 3] = body_along, road.y_m
        return PlaceFix(stamp_ns, True, "", world_body @ relative @ body_cam, sigma, best, candidates, vlad, inliers,
                        True, cfg.road_cross_track_sigma_m, cfg.road_heading_sigma_rad)

    def _along_by_road(self, image: Image, best: int, road: RoadRegistration) -> float | None:
        """Where the query's body lies along the best place's heading (metres ahead of it), from its road
        registered on the best place (``road``) and on the places before and after it in the drive. A
        registration beyond its reach (about a metre) still finds a peak, typically at the place itself, so
        one registration alone cannot be trusted along the track; two places that put the query at the same
        point, within ``road_along_agree_m``, can. None when no two agree."""
        body_cam = self.camera.pose_body_cam_array
        to_best = body_cam @ np.linalg.inv(self.poses_world_cam[best])
        found = [road.x_m]
        for place in (best - 1, best + 1):
            if not 0 <= place < len(self.poses_world_cam):
                continue
            best_place = to_best @ self.poses_world_cam[place] @ np.linalg.inv(body_cam)  # in the best's body frame
            other = self.register(image, place, road.yaw_rad - math.atan2(best_place[1, 0], best_place[0, 0]))
            if other is not None:
                found.append(float((best_place @ planar_pose(other.x_m, other.y_m, other.yaw_rad))[0, 3]))
        pairs = [(abs(a - b), (a + b) / 2) for a, b in itertools.combinations(found, 2)]
        closest = min(pairs, default=(math.inf, 0.0))
        return closest[1] if closest[0] <= self.config.road_along_agree_m else None

    def save(self, path: str | Path) -> Path:
        """Write the database (atomically: a crash leaves the old file or none, never half of one)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        counts = np.array([len(k) for k in self.keypoints], np.int64)
        header = {"format": FORMAT, "version": FORMAT_VERSION, "camera_name": self.camera_name,
                  "camera": camera_to_dict(self.camera), "config": config_to_dict(self.config), "info": self.info}
        arrays: dict[str, Any] = {
            "header": np.array(json.dumps(header)), "centres": self.centres, "vectors": self.vectors,
            "poses_world_cam": self.poses_world_cam, "stamps_ns": self.stamps_ns, "feature_counts": counts,
            "keypoints": np.concatenate(self.keypoints).reshape(-1, 2),
            "descriptors": np.concatenate(self.descriptors).reshape(int(counts.sum()), -1)}
        if self.road_views is not None:
            arrays["road_views"] = self.road_views
        if self.pca is not None:
            arrays.update(pca_mean=self.pca.mean, pca_components=self.pca.components, pca_variances=self.pca.variances)
        return write_atomic(path, lambda handle: np.savez(handle, **arrays))


def load_places(path: str | Path) -> PlaceDatabase:
    """A database written by :meth:`PlaceDatabase.save`; anything else raises DataError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"no place database at {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise DataError(f"{path} is not a kartpilot place database (unreadable: {exc})") from exc
    try:
        header = parse_json(str(arrays["header"]), path)
    except (KeyError, DataError) as exc:
        raise DataError(f"{path} is not a kartpilot place database (no header)") from exc
    if header.get("format") != FORMAT:
        raise DataError(f"{path} is not a kartpilot place database (format {header.get('format')!r})")
    if header.get("version") != FORMAT_VERSION:
        raise DataError(f"{path} is a place database of version {header.get('version')}; this kartpilot reads "
                        f"version {FORMAT_VERSION}: build it again with `kartpilot places build`")
    try:
        config = merge_config(PlacesConfig(), header["config"], "places")
        counts = arrays["feature_counts"]
        spans = list(itertools.pairwise(np.r_[0, np.cumsum(counts)]))
        pca = (Pca(arrays["pca_mean"], arrays["pca_components"], arrays["pca_variances"])
               if "pca_mean" in arrays else None)
        return PlaceDatabase(
            header["camera_name"], camera_from_dict(header["camera_name"], header["camera"], f"in {path}"), config,
            arrays["centres"], pca, arrays["vectors"], arrays["poses_world_cam"], arrays["stamps_ns"],
            [arrays["keypoints"][a:b] for a, b in spans], [arrays["descriptors"][a:b] for a, b in spans],
            header["info"], arrays.get("road_views"))
    except KartpilotError as exc:
        raise DataError(f"{path}: {exc}") from exc
    except (KeyError, ValueError, TypeError) as exc:
        raise DataError(f"{path} is a damaged place database (missing or malformed {exc})") from exc


def build_places(images: Iterable[tuple[int, Image, Array]], camera: PinholeCamera, camera_name: str,
                 config: PlacesConfig | None = None, info: dict[str, Any] | None = None) -> PlaceDatabase:
    """A database from ``(stamp_ns, image, pose_world_cam)`` of a reference drive, keeping an image every
    ``spacing_m``. ``info`` says where the images and positions came from (kept in the file). A camera with
    lens distortion has its images undistorted first (:func:`kartpilot.calibration.lens.undistortion`): the
    database holds the pinhole camera, and ``info["undistorted"]`` the coefficients taken out, which a
    query's camera must have too."""
    config = config or PlacesConfig()
    lens = undistortion(camera)
    info = {**(info or {}), "undistorted": list(camera.distortion) if lens is not None else []}
    if lens is not None:
        camera = lens.pinhole
        images = ((stamp, lens(image), pose) for stamp, image, pose in images)
    describer = _Describer(camera, config)
    try:
        grids = road_grids(camera, config.road) if config.register and has_mount(camera) else None
    except ConfigError as exc:
        raise ConfigError(f"{exc} (or build without the road's top views: places.register: false)") from exc
    kept: list[tuple[int, Array, Features]] = []
    views: list[NDArray[np.uint8]] = []
    last: Array | None = None
    for stamp_ns, image, pose in images:
        position = np.asarray(pose, float)[:3, 3]
        if last is not None and np.linalg.norm(position - last) < config.spacing_m:
            continue
        features = describer.features(image)
        if len(features) < 8:
            continue  # a black or blank frame is no place
        kept.append((stamp_ns, np.asarray(pose, float), features))
        if grids is not None:
            views.append(birdseye(image, grids[0]))
        last = position
    if len(kept) < 2:
        raise DataError(f"{len(kept)} usable images {config.spacing_m:g} m apart: a place database needs a "
                        "drive with texture and motion")
    centres = train_vocabulary([f.descriptors for _, _, f in kept], config.vlad)
    raw = np.array([vlad_vector(f.descriptors, centres, config.vlad.power_alpha) for _, _, f in kept], np.float32)
    pca = fit_pca(raw, config.vlad.pca_dims, config.vlad.seed) if config.vlad.pca_dims else None
    vectors = project_pca(raw, pca) if pca is not None else raw
    strongest = [f.subset(np.argsort(-f.responses, kind="stable")[:config.keep_features]) for _, _, f in kept]
    return PlaceDatabase(camera_name, camera, config, centres, pca, np.ascontiguousarray(vectors, np.float32),
                         np.array([p for _, p, _ in kept]), np.array([s for s, _, _ in kept], np.int64),
                         [f.points_px.astype(np.float32) for f in strongest],
                         [f.descriptors for f in strongest], info, np.array(views) if views else None)
