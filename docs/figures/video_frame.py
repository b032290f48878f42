"""One frame of a drive's video as a figure (the docs' picture of the lane pipeline).

    kartpilot sim --track sdc-assen --vehicle sdc-kart --driver lanes --speed-mode 15 --rate 30 --video lap.mp4
    python docs/figures/video_frame.py lap.mp4 600 docs/figures/demo-lanes.png
"""

import sys

import cv2


def main() -> None:
    video, index, target = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    capture = cv2.VideoCapture(video)
    capture.set(cv2.CAP_PROP_POS_FRAMES, index)
    ok, image = capture.read()
    if not ok:
        raise SystemExit(f"{video} has no frame {index}")
    cv2.imwrite(target, image)


if __name__ == "__main__":
    main()
