"""A ChArUco board lying on the ground as a camera of known pose sees it: the calibration tests' truth."""

from __future__ import annotations

import cv2
import numpy as np

from kartpilot.calibration.board import BoardConfig
from kartpilot.core.camera import PinholeCamera
from kartpilot.core.geometry import invert_pose


def render_board(camera: PinholeCamera, board_on_body: np.ndarray, board: BoardConfig,
                 px_per_square: int = 80) -> np.ndarray:
    """The board lying on the ground (its 4x4 pose on the body) as ``camera`` sees it, on grey asphalt (BGR)."""
    art = board.charuco_board().generateImage((board.columns * px_per_square, board.rows * px_per_square))
    metres_from_art = np.diag([board.square_m / px_per_square, board.square_m / px_per_square, 1.0])
    cam_board = invert_pose(camera.pose_body_cam_array) @ board_on_body
    to_image = camera.matrix @ np.column_stack([cam_board[:3, 0], cam_board[:3, 1], cam_board[:3, 3]])
    image = cv2.warpPerspective(art, to_image @ metres_from_art, camera.size_wh, borderValue=90)
    mask = cv2.warpPerspective(np.full_like(art, 255), to_image @ metres_from_art, camera.size_wh)
    out = np.where(mask > 0, image, np.full_like(image, 90))
    return cv2.cvtColor(out, cv2.COLOR_GRAY2BGR)


def board_on_ground(x_m: float, y_m: float, yaw_deg: float) -> np.ndarray:
    """A board lying face up: OpenCV's board frame has z into the board, so down."""
    yaw = np.radians(yaw_deg)
    pose = np.eye(4)
    pose[:3, :3] = np.array([[np.cos(yaw), np.sin(yaw), 0], [np.sin(yaw), -np.cos(yaw), 0], [0, 0, -1.0]])
    pose[:3, 3] = (x_m, y_m, 0.0)
    return pose
